"""Circle and segment fits (pure): buoys and walls of known geometry, seeded manual noise.

The geometric circle fit is checked against a second formulation, scipy's
``least_squares`` on the same residuals; the shapes against the geometry they were cast from.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares
from support.lidar_scene import Circle, Wall, cast

from enbarr_core.perception.fitting import (
    CircleFit, fit_circle, fit_cluster, fit_segment, FitSettings, kasa, refine_circle, SegmentFit,
    split)

SETTINGS = FitSettings(min_radius=0.05, max_radius=1.0, min_segment_length=0.4,
                       circle_ratio=0.8, split_distance=0.1)
ORIGIN = np.zeros(2)


def points_of(ranges: np.ndarray) -> np.ndarray:
    theta = -math.pi + np.arange(len(ranges)) * (2.0 * math.pi / len(ranges))
    ok = np.isfinite(ranges)
    return np.column_stack((ranges[ok] * np.cos(theta[ok]), ranges[ok] * np.sin(theta[ok])))


def half_arc(cx: float, cy: float, r: float, n: int, sigma: float, seed: int) -> np.ndarray:
    """n points on the half of the circle facing the origin, radial noise sigma [m]."""
    facing = math.atan2(-cy, -cx)
    a = facing + np.linspace(-0.5 * math.pi, 0.5 * math.pi, n)
    rr = r + sigma * np.random.default_rng(seed).standard_normal(n)
    return np.column_stack((cx + rr * np.cos(a), cy + rr * np.sin(a)))


@pytest.mark.parametrize('seed', range(5))
def test_a_noisy_half_arc_gives_centre_and_radius_within_5_cm(seed):
    # 1 % of 3.2 m, the manual's noise there: 5 cm is about three standard deviations
    pts = half_arc(3.0, 1.0, 0.5, 12, 0.03, seed)
    fit = fit_circle(pts, ORIGIN, 0.03, 0.05, 1.0)
    assert not fit.fallback
    assert math.dist((fit.x, fit.y), (3.0, 1.0)) < 0.05
    assert abs(fit.radius - 0.5) < 0.05
    # the covariance is honest: the error is within 4 of its standard deviations
    assert abs(fit.x - 3.0) < 4.0 * math.sqrt(fit.cov[0])
    assert abs(fit.y - 1.0) < 4.0 * math.sqrt(fit.cov[2])


@pytest.mark.parametrize('seed', range(4))
def test_kasa_is_the_algebraic_least_squares_circle(seed):
    # Kasa (1976): x^2 + y^2 + D x + E y + F = 0 in least squares, solved here by numpy's
    # lstsq on the uncentred system: the same circle, however the fit sums it
    rng = np.random.default_rng(seed)
    pts = half_arc(*rng.uniform(-6.0, 6.0, 2), rng.uniform(0.1, 1.0), 15, 0.03, seed)
    a = np.column_stack((pts, np.ones(len(pts))))
    (d, e, f), *_ = np.linalg.lstsq(a, -(pts * pts).sum(axis=1), rcond=None)
    cx, cy = -0.5 * d, -0.5 * e
    ours = kasa(pts)
    assert ours == pytest.approx((cx, cy, math.sqrt(cx * cx + cy * cy - f)), abs=1e-9)
    # and exact points give their circle back exactly
    exact = half_arc(1.5, -2.5, 0.35, 7, 0.0, seed)
    assert kasa(exact) == pytest.approx((1.5, -2.5, 0.35), abs=1e-12)


@pytest.mark.parametrize('seed', range(5))
def test_the_geometric_fit_is_scipys_least_squares(seed):
    pts = half_arc(-2.0, 4.0, 0.4, 9, 0.04, seed)
    start = kasa(pts)
    assert start is not None
    ours = refine_circle(pts, *start)
    assert ours is not None

    def residuals(p: np.ndarray) -> np.ndarray:
        return np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) - p[2]

    ref = least_squares(residuals, start, method='lm', xtol=1e-12, ftol=1e-12).x
    assert ours[:3] == pytest.approx(tuple(ref), abs=1e-4)
    assert ours[4] == pytest.approx(float(residuals(ref) @ residuals(ref)), rel=1e-6)


def test_the_fit_corrects_kasas_bias_on_a_short_arc():
    # a 70 degree arc: Kasa's algebraic fit is biased small, the geometric one is not
    ours, theirs = [], []
    for seed in range(40):
        a = math.pi + np.linspace(-0.6, 0.6, 10)
        pts = np.column_stack((4.0 + 0.6 * np.cos(a), 0.6 * np.sin(a)))
        pts += 0.02 * np.random.default_rng(seed).standard_normal(pts.shape)
        ours.append(fit_circle(pts, ORIGIN, 0.02, 0.05, 1.0).radius)
        k = kasa(pts)
        assert k is not None
        theirs.append(k[2])
    # the bias the refinement is for; ours within two standard errors of its mean (0.02 m)
    assert np.mean(theirs) < 0.6 - 0.05
    assert abs(np.mean(ours) - 0.6) < 0.04


@pytest.mark.parametrize('n', [1, 2, 3])
def test_two_or_three_points_give_a_circle_behind_them_at_least_min_radius(n):
    pts = half_arc(5.0, 0.0, 0.1, 7, 0.0, 0)[2:2 + n]
    fit = fit_circle(pts, ORIGIN, 0.1, 0.15, 1.0)
    assert fit.radius >= 0.15
    # the centre is further from the sensor than every point: behind the visible arc
    assert math.hypot(fit.x, fit.y) > np.hypot(pts[:, 0], pts[:, 1]).max()
    # and not far off the true centre (5, 0): within the radius held
    assert math.dist((fit.x, fit.y), (5.0, 0.0)) < 0.2
    # its covariance is at least as large as the noise
    assert fit.cov[0] >= 0.1 ** 2 * 0.5 and fit.cov[2] >= 0.1 ** 2 * 0.5


def test_a_straight_cluster_never_fits_a_circle_in_front_of_it():
    pts = np.column_stack((np.full(8, 3.0), np.linspace(-0.2, 0.2, 8)))
    pts[:, 0] += 0.005 * np.random.default_rng(1).standard_normal(8)
    fit = fit_circle(pts, ORIGIN, 0.03, 0.05, 1.0)
    assert fit.x > 3.0


def test_a_scanned_buoy_is_one_circle():
    pts = points_of(cast(0.0, 0.0, 0.0, [Circle(2.5, -1.0, 0.3)], seed=4))
    shapes = fit_cluster(pts, ORIGIN, 0.027, SETTINGS)
    assert len(shapes) == 1 and isinstance(shapes[0], CircleFit)
    assert math.dist((shapes[0].x, shapes[0].y), (2.5, -1.0)) < 0.08
    assert abs(shapes[0].radius - 0.3) < 0.08


def test_a_scanned_wall_is_one_segment_with_its_ends():
    # the wall x = 3 from y = -1 to y = 2.5; its ends are seen within one ray spacing
    pts = points_of(cast(0.0, 0.0, 0.0, [], [Wall(3.0, -1.0, 3.0, 2.5)], seed=5))
    shapes = fit_cluster(pts, ORIGIN, 0.03, SETTINGS)
    assert len(shapes) == 1 and isinstance(shapes[0], SegmentFit)
    ends = sorted([(shapes[0].x1, shapes[0].y1), (shapes[0].x2, shapes[0].y2)],
                  key=lambda p: p[1])
    spacing = math.hypot(3.0, 2.5) * math.radians(1.0)
    assert ends[0] == pytest.approx((3.0, -1.0), abs=spacing + 0.05)
    assert ends[1] == pytest.approx((3.0, 2.5), abs=spacing + 0.05)


@pytest.mark.parametrize('length', [0.5, 1.0, 1.8])
def test_a_short_straight_piece_of_wall_stays_a_segment(length):
    pts = points_of(cast(0.0, 0.0, 0.0, [], [Wall(2.0, 0.0, 2.0, length)], seed=9))
    shapes = fit_cluster(pts, ORIGIN, 0.02, SETTINGS)
    assert shapes and all(isinstance(s, SegmentFit) for s in shapes)


def test_an_l_shaped_wall_is_two_segments_meeting_at_the_corner():
    walls = [Wall(3.0, -2.0, 3.0, 2.0), Wall(3.0, 2.0, -1.0, 2.0)]
    ranges = cast(0.0, 0.0, 0.0, [], walls, seed=6)
    ranges[:135] = np.inf      # keep the two walls only, in ring order: x = 3 then y = 2
    pts = points_of(ranges)
    shapes = fit_cluster(pts, ORIGIN, 0.04, SETTINGS)
    assert len(shapes) == 2 and all(isinstance(s, SegmentFit) for s in shapes)
    a, b = shapes
    ua = np.array([a.x2 - a.x1, a.y2 - a.y1]) / a.length
    ub = np.array([b.x2 - b.x1, b.y2 - b.y1]) / b.length
    assert abs(float(ua @ ub)) < math.sin(math.radians(5.0))   # perpendicular
    corner = min((math.dist(p, q), p) for p in [(a.x1, a.y1), (a.x2, a.y2)]
                 for q in [(b.x1, b.y1), (b.x2, b.y2)])
    assert corner[0] < 0.15 and math.dist(corner[1], (3.0, 2.0)) < 0.15


@pytest.mark.parametrize('seed', range(4))
def test_a_segment_is_the_total_least_squares_line_of_its_points(seed):
    # the principal axis by numpy's SVD of the centred points, far from the origin (a basin
    # wall seen from its far side): ends the extreme projections, rms the perpendicular one
    rng = np.random.default_rng(seed)
    angle, length = rng.uniform(-math.pi, math.pi), rng.uniform(0.3, 5.0)
    start = rng.uniform(-20.0, 20.0, 2)
    t = np.sort(rng.uniform(0.0, length, 40))
    u = np.array((math.cos(angle), math.sin(angle)))
    pts = start + np.outer(t, u) + 0.02 * np.outer(rng.standard_normal(40), (-u[1], u[0]))
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre)
    axis, normal = vt[0], vt[1]
    proj = (pts - centre) @ axis
    ends = [centre + proj.min() * axis, centre + proj.max() * axis]
    seg = fit_segment(pts)
    got = [np.array((seg.x1, seg.y1)), np.array((seg.x2, seg.y2))]
    if float((got[1] - got[0]) @ axis) < 0.0:
        got.reverse()
    np.testing.assert_allclose(got, ends, atol=1e-9)
    assert seg.rms == pytest.approx(float(np.sqrt(np.mean(((pts - centre) @ normal) ** 2))),
                                    rel=1e-9)
    assert seg.points == 40


def test_split_keeps_a_straight_run_whole_and_cuts_a_corner_once():
    line = np.column_stack((np.linspace(0, 4, 20), np.zeros(20)))
    assert split(line, 0.05) == [(0, 20)]
    corner = np.vstack((line, np.column_stack((np.full(10, 4.0), np.linspace(0.4, 4, 10)))))
    assert split(corner, 0.05) == [(0, 20), (19, 30)]
    # a short bend at the end lies on one side of the union's line only, on either side: the
    # merge must not take it back into the straight run
    line = np.column_stack((np.linspace(0, 4, 40), np.zeros(40)))
    bend = np.vstack((line, [[4.1, -0.1], [4.2, -0.2], [4.3, -0.3]]))
    assert split(bend, 0.05) == [(0, 40), (39, 43)]
    assert split(bend * (1.0, -1.0), 0.05) == [(0, 40), (39, 43)]


def test_settings_refuse_a_minimum_radius_above_the_maximum():
    with pytest.raises(ValueError, match='^min_radius:'):
        FitSettings(2.0, 1.0, 0.4, 0.8, 0.1).validate()


@pytest.mark.parametrize(('x', 'length'), [(3.0, 0.6), (4.0, 0.8)])
def test_noisy_short_wall_pieces_stay_segments_though_a_circle_fits_them_too(x, length):
    # Short enough for a circle, and at 2 % noise a circle often fits as well (a quarter of
    # these 40 scans): only a clearly better circle takes a cluster from the line.
    segments = 0
    for seed in range(40):
        pts = points_of(cast(0.0, 0.0, 0.0, [], [Wall(x, 0.2, x, 0.2 + length)], seed=seed))
        sigma = (0.01 if x < 3.0 else 0.02) * x
        shapes = fit_cluster(pts, ORIGIN, sigma, SETTINGS)
        segments += all(isinstance(s, SegmentFit) for s in shapes)
    assert segments >= 35


def test_the_centre_covariance_is_s2_times_the_inverse_of_jtj():
    # Written out here with numpy: J's rows -[(p - c) / |p - c|, 1], s^2 the larger of the
    # residual variance (n - 3 degrees of freedom) and the noise's.
    pts = half_arc(2.0, -1.0, 0.4, 10, 0.02, 3)
    fit = fit_circle(pts, ORIGIN, 0.01, 0.05, 1.0)
    d = pts - (fit.x, fit.y)
    dist = np.hypot(d[:, 0], d[:, 1])
    jac = -np.column_stack((d / dist[:, None], np.ones(len(pts))))
    e = dist - fit.radius
    s2 = max(float(e @ e) / (len(pts) - 3), 0.01 ** 2)
    cov = s2 * np.linalg.inv(jac.T @ jac)
    assert fit.cov == pytest.approx((cov[0, 0], cov[0, 1], cov[1, 1]), rel=1e-6)


@pytest.mark.parametrize(('cx', 'cy'), [(0.0, 4.0), (0.0, -4.0), (4.0, 0.0), (-4.0, 0.0)])
def test_a_buoy_on_any_bearing_is_fitted_behind_its_arc(cx, cy):
    # Abeam (x the same as the sensor's) only the y half of "behind the points" can tell
    # the fitted centre from a centre in front of them; the sensor away from the origin.
    sensor = np.array((3.0, -2.0))
    pts = half_arc(cx, cy, 0.4, 12, 0.01, 2) + sensor
    fit = fit_circle(pts, sensor, 0.01, 0.05, 1.0)
    assert not fit.fallback
    assert math.dist((fit.x, fit.y), (cx + 3.0, cy - 2.0)) < 0.05
