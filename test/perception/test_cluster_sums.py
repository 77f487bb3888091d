"""Every cluster of a scan fitted from one pass of sums (pure): the per-cluster fit's answers.

``fit_clusters`` must give exactly the shapes of ``fit_cluster`` called on each cluster (the
straightforward computation, itself pinned to the paper and to numpy's SVD in test_fitting),
and ``cluster_sums`` the sums, extents and chord distances written out here per cluster with
numpy. The scenes are cast in support.lidar_scene: buoys, straight walls, L-shaped corners
(which split and merge must cut), short wall pieces (circle or segment by the residuals) and
clusters of one, two and three points.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.lidar_scene import Circle, NOISE_FRACTIONS, NOISE_LIMITS, Wall, cast

from enbarr_core.perception.fitting import (CircleFit, cluster_sums, fit_cluster, fit_clusters,
                                            fit_segment, FitSettings, kasa, kasa_from_sums,
                                            SegmentFit)
from enbarr_core.perception.scan_geometry import RangeNoise, scan_points
from enbarr_core.perception.segmentation import BreakpointSettings, clusters

SETTINGS = FitSettings(min_radius=0.05, max_radius=1.0, min_segment_length=0.4,
                       circle_ratio=0.8, split_distance=0.1)
NOISE = RangeNoise(NOISE_LIMITS, NOISE_FRACTIONS)
BREAKS = BreakpointSettings(math.radians(10.0), 2, NOISE)
INC = 2.0 * math.pi / 360


def scene(seed: int) -> np.ndarray:
    """A seeded basin: buoys, straight walls, an L-shaped corner and a short wall piece."""
    rng = np.random.default_rng(seed)
    circles = [Circle(*rng.uniform(-7.0, 7.0, 2), rng.uniform(0.1, 0.9)) for _ in range(4)]
    cx, cy = rng.uniform(2.0, 4.0, 2)
    walls = [Wall(-9.0, -9.0, 9.0, -9.0), Wall(9.0, -9.0, 9.0, 9.0),       # a corner
             Wall(cx, -cy, cx, cy), Wall(cx, cy, cx - 3.0, cy),            # an L
             Wall(-4.0, 1.0, -4.0, 1.0 + rng.uniform(0.4, 1.5))]          # a short piece
    return cast(0.0, 0.0, 0.0, circles, walls, seed=seed)


def pieces_of(ranges: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The scan's points and its clusters (positions), as the pipeline cuts them."""
    scan = scan_points(ranges, -math.pi, INC)
    return scan.laser, clusters(scan, BREAKS)


def batched(points: np.ndarray, pieces: list[np.ndarray]
            ) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """The clusters one after the other, each one's start and range noise."""
    start = np.cumsum([0] + [len(c) for c in pieces[:-1]]).astype(np.intp)
    sigmas = [NOISE.sigma_at(float(np.hypot(*points[c[len(c) // 2]]))) for c in pieces]
    return points[np.concatenate(pieces)], start, sigmas


def row(shape: CircleFit | SegmentFit) -> tuple[object, ...]:
    if isinstance(shape, CircleFit):
        return ('circle', shape.x, shape.y, shape.radius, *shape.cov, shape.rms, shape.fallback)
    return ('segment', shape.x1, shape.y1, shape.x2, shape.y2, shape.rms, shape.points)


def assert_same(got: list[CircleFit | SegmentFit], want: list[CircleFit | SegmentFit]) -> None:
    assert [row(g)[0] for g in got] == [row(w)[0] for w in want]
    for g, w in zip(got, want):
        assert row(g)[1:] == pytest.approx(row(w)[1:], rel=1e-9, abs=1e-9)


@pytest.mark.parametrize('seed', range(12))
def test_every_cluster_of_a_scan_gets_the_per_cluster_fits_shapes(seed):
    points, pieces = pieces_of(scene(seed))
    ordered, start, sigmas = batched(points, pieces)
    sensors = np.zeros((len(pieces), 2))
    want = [z for c, sigma in zip(pieces, sigmas)
            for z in fit_cluster(points[c], np.zeros(2), sigma, SETTINGS)]
    assert_same(fit_clusters(ordered, start, sensors, sigmas, SETTINGS), want)


def test_the_scenes_hold_circles_straight_walls_and_bent_walls():
    # the comparison above means something only if every path of fit_clusters is taken
    kinds = {'circle': 0, 'straight': 0, 'bent': 0, 'tiny': 0}
    for seed in range(12):
        points, pieces = pieces_of(scene(seed))
        for c in pieces:
            shapes = fit_cluster(points[c], np.zeros(2), 0.05, SETTINGS)
            kinds['tiny'] += len(c) <= 3
            kinds['circle'] += isinstance(shapes[0], CircleFit)
            kinds['straight'] += len(shapes) == 1 and isinstance(shapes[0], SegmentFit)
            kinds['bent'] += len(shapes) > 1
    assert min(kinds.values()) >= 3, kinds


def test_the_sums_extents_and_chords_are_each_clusters_own():
    rng = np.random.default_rng(7)
    sizes = [1, 2, 3, 17, 40]
    points = rng.uniform(-20.0, 20.0, (sum(sizes), 2))
    start = np.cumsum([0] + sizes[:-1]).astype(np.intp)
    got = cluster_sums(points, start)
    assert got.count.tolist() == sizes
    for k, (a, n) in enumerate(zip(start, sizes)):
        p = points[a:a + n]
        rel = p - p[0]
        x, y = rel[:, 0], rel[:, 1]
        want = [x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum(),
                (x ** 3).sum(), (x * x * y).sum(), (x * y * y).sum(), (y ** 3).sum()]
        np.testing.assert_allclose(got.sums[k], want, rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(got.origin[k], p[0])
        np.testing.assert_allclose(got.last[k], p[-1] - p[0], atol=1e-12)
        np.testing.assert_array_equal(got.low[k], p.min(axis=0))
        np.testing.assert_array_equal(got.high[k], p.max(axis=0))
        if n == 1:   # first and last point coincide: no chord to measure from
            assert got.chord[k] == math.inf
            continue
        # the distance of each point from the line through the first and the last
        u = (p[-1] - p[0]) / np.linalg.norm(p[-1] - p[0])
        dist = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
        assert got.chord[k] == pytest.approx(dist.max(), rel=1e-12, abs=1e-12)


def test_a_straight_wall_is_one_segment_of_the_svd_line_and_an_l_two():
    # Known answers: the straight run is the principal axis of its points (numpy's SVD), ends
    # the extreme projections; the L is cut at its corner into two perpendicular segments.
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 4.0, 60))
    wall = np.column_stack((12.0 + 0.6 * t, -3.0 + 0.8 * t)) + 0.01 * rng.standard_normal((60, 2))
    leg = np.column_stack((np.full(30, 2.0), np.linspace(0.0, 3.0, 30)))
    foot = np.column_stack((np.linspace(2.1, 5.0, 30), np.full(30, 3.0)))
    points = np.vstack((wall, leg, foot))
    start = np.array([0, 60], dtype=np.intp)
    shapes = fit_clusters(points, start, np.zeros((2, 2)), [0.01, 0.01], SETTINGS)
    assert len(shapes) == 3 and all(isinstance(s, SegmentFit) for s in shapes)
    straight, *corner = shapes
    centre = wall.mean(axis=0)
    axis = np.linalg.svd(wall - centre)[2][0]
    proj = (wall - centre) @ axis
    ends = sorted([tuple(centre + proj.min() * axis), tuple(centre + proj.max() * axis)])
    got = sorted([(straight.x1, straight.y1), (straight.x2, straight.y2)])
    np.testing.assert_allclose(got, ends, atol=1e-9)
    assert straight.points == 60
    assert straight.rms == pytest.approx(fit_segment(wall).rms, rel=1e-9)
    a, b = corner
    assert abs((a.x2 - a.x1) * (b.x2 - b.x1) + (a.y2 - a.y1) * (b.y2 - b.y1)) < 1e-6
    assert (a.x2, a.y2) == pytest.approx((2.0, 3.0), abs=0.11)


@pytest.mark.parametrize(('arm', 'pieces'), [(0.09, 1), (0.13, 2)])
def test_a_wall_bent_by_more_than_the_split_distance_is_cut_and_less_is_not(arm, pieces):
    # A noise-free 4 m wall with a short arm at its end, ``arm`` long at right angles: the
    # corner lies about ``arm`` off the chord. Split and merge cuts there when that exceeds
    # split_distance (0.1 m) plus 3 sigma (0 here), and the merge keeps the cut for 0.13 m;
    # the chord test of fit_clusters must leave the 0.13 m bend to split.
    x = np.linspace(0.0, 4.0, 41)
    wall = np.vstack((np.column_stack((x, np.zeros(41))),
                      np.column_stack((np.full(5, 4.0), np.linspace(0.0, arm, 6)[1:]))))
    wall += (5.0, 1.0)
    hairpin = np.vstack((np.column_stack((np.zeros(30), np.linspace(0.0, 3.0, 30))),
                         np.column_stack((np.full(30, 0.3), np.linspace(3.0, 0.0, 30)))))
    points = np.vstack((wall, hairpin + (-6.0, 2.0)))
    start = np.array([0, len(wall)], dtype=np.intp)
    got = fit_clusters(points, start, np.zeros((2, 2)), [0.0, 0.0], SETTINGS)
    want = (fit_cluster(wall, np.zeros(2), 0.0, SETTINGS)
            + fit_cluster(hairpin + (-6.0, 2.0), np.zeros(2), 0.0, SETTINGS))
    assert_same(got, want)
    assert all(isinstance(s, SegmentFit) for s in got)
    lengths = [round(s.length, 2) for s in got[:pieces]]
    assert lengths == ([4.0] if pieces == 1 else [4.0, 0.13])
    # the hairpin's ends are 0.3 m apart, but it is 3 m long: segments (a wall), not a circle
    # of 0.15 m; only its extent along y says so
    assert max(s.length for s in got[pieces:]) == pytest.approx(3.0, abs=0.01)


@pytest.mark.parametrize('seed', range(6))
def test_kasas_circle_from_the_sums_is_kasas_circle_from_the_points(seed):
    # a buoy's arc far out in the basin (large coordinates, small spread: the sums about the
    # first point must not lose the digits kasa keeps by centring)
    rng = np.random.default_rng(seed)
    centre, r = rng.uniform(-15.0, 15.0, 2), rng.uniform(0.1, 0.9)
    a = rng.uniform(-1.2, 1.2) + np.linspace(0.0, rng.uniform(0.6, 2.5), int(rng.integers(3, 30)))
    pts = centre + r * np.column_stack((np.cos(a), np.sin(a)))
    pts += 0.01 * rng.standard_normal(pts.shape)
    c = cluster_sums(pts, np.zeros(1, dtype=np.intp))
    got = kasa_from_sums(len(pts), *c.origin[0].tolist(), c.sums[0].tolist())
    assert got == pytest.approx(kasa(pts), rel=1e-9, abs=1e-9)
    assert kasa_from_sums(2, 0.0, 0.0, c.sums[0].tolist()) is None
