"""Adaptive breakpoint segmentation (pure): clusters of scans cast in support.lidar_scene.

The expected splits come from the breakpoint rule written out here from the paper (Borges and
Aldon 2004, D_max = r_{n-1} sin(dphi) / sin(lambda - dphi) + 3 sigma_r) with the manual's
noise figures typed in support.lidar_scene, not from the module under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.lidar_scene import Circle, NOISE_FRACTIONS, NOISE_LIMITS, Wall, cast

from enbarr_core.perception.scan_geometry import RangeNoise, scan_points
from enbarr_core.perception.segmentation import (_break, BreakpointSettings,
                                                  breakpoint_distance, clusters)

LAM = math.radians(10.0)
INC = 2.0 * math.pi / 360
SETTINGS = BreakpointSettings(LAM, 2, RangeNoise(NOISE_LIMITS, NOISE_FRACTIONS))


def d_max(r: float, rays_apart: int) -> float:
    """The paper's bound, sigma_r from the manual (1 % < 3 m, 2 % 3-5 m, 2.5 % beyond)."""
    sigma = r * (0.01 if r < 3.0 else 0.02 if r < 5.0 else 0.025)
    dphi = rays_apart * INC
    return r * math.sin(dphi) / math.sin(LAM - dphi) + 3.0 * sigma


def cluster_rays(ranges: np.ndarray, settings: BreakpointSettings = SETTINGS) -> list[set[int]]:
    scan = scan_points(ranges, -math.pi, INC)
    return [set(scan.index[c].tolist()) for c in clusters(scan, settings)]


@pytest.mark.parametrize('apart', [[1, 1, 2, 3], [1, 2, 12, 1]])
def test_the_breakpoint_distance_is_the_papers_and_a_wide_gap_always_breaks(apart):
    # whether or not a gap reaches lambda (10 rays here), each pair gets the paper's bound
    r = np.array([0.5, 2.9, 4.0, 7.5])
    sigma = SETTINGS.noise.sigma(r)
    got = breakpoint_distance(r, np.array(apart) * INC, LAM, sigma)
    want = [d_max(ri, k) if k * INC < LAM else -1.0 for ri, k in zip(r.tolist(), apart)]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_a_scan_without_missing_rays_breaks_where_the_papers_bound_says():
    """_breaks' path for gaps of one ray: the bound of each pair written out from the paper."""
    from enbarr_core.perception.segmentation import _breaks
    rng = np.random.default_rng(8)
    for _ in range(50):
        r = rng.uniform(0.2, 12.0, 300)
        d = rng.uniform(0.0, 0.4, 300)
        gap = np.ones(300, dtype=np.intp)
        sigma = np.array([NOISE_FRACTIONS[sum(x >= lim for lim in NOISE_LIMITS)] * x
                          for x in r])
        bound = r * math.sin(INC) / math.sin(LAM - INC) + 3.0 * sigma
        got = _breaks(r, gap, d, INC, SETTINGS)
        assert got.tolist() == (d > bound).tolist()
        assert 0 < got.sum() < 300
    wide = BreakpointSettings(0.5 * INC, 2, SETTINGS.noise)   # rays further apart than lambda
    assert _breaks(r, gap, d, INC, wide).all()


def test_two_buoys_one_behind_the_other_split_exactly_where_the_breakpoint_says():
    outcomes = set()
    for behind in np.linspace(0.0, 1.0, 21):
        a = Circle(3.0, 0.0, 0.3)
        b = Circle(3.0 + behind, 0.55, 0.3)   # beside a, then further behind it
        ranges = cast(0.0, 0.0, 0.0, [a, b], seed=int(behind * 1000))
        only_a = cast(0.0, 0.0, 0.0, [a], noise=False)
        only_b = cast(0.0, 0.0, 0.0, [b], noise=False)
        ray_a = np.isfinite(only_a) & ~(only_b < only_a)
        rays = np.flatnonzero(np.isfinite(ranges))
        # the consecutive pair where a's rays give way to b's
        last_a = max(i for i in rays if ray_a[i])
        first_b = min(i for i in rays if i > last_a)
        pts = [ranges[i] * np.array([math.cos(-math.pi + i * INC),
                                     math.sin(-math.pi + i * INC)]) for i in (last_a, first_b)]
        apart = first_b - last_a   # more than max_gap + 1 = 3: too many rays missing
        split = apart > 3 or math.dist(*pts) > d_max(ranges[last_a], apart)
        got = cluster_rays(ranges)
        assert len(got) == (2 if split else 1), behind
        outcomes.add(split)
    assert outcomes == {True, False}   # the sweep saw both sides of the bound


def test_a_wall_behind_a_buoy_is_cut_in_two_around_it():
    buoy = Circle(2.0, 0.0, 0.25)
    ranges = cast(0.0, 0.0, 0.0, [buoy], [Wall(5.0, -3.0, 5.0, 3.0)], seed=3)
    got = cluster_rays(ranges)
    assert len(got) == 3
    scan = scan_points(ranges, -math.pi, INC)
    xy = dict(zip(scan.index.tolist(), scan.laser))
    on_buoy = [c for c in got if all(abs(math.dist(xy[i], (2.0, 0.0)) - 0.25) < 0.1 for i in c)]
    assert len(on_buoy) == 1
    walls = [c for c in got if c is not on_buoy[0]]
    assert all(all(abs(xy[i][0] - 5.0) < 0.5 for i in c) for c in walls)


def test_a_buoy_across_the_seam_at_pi_is_one_cluster():
    # Straight astern: its rays are the scan's first and last (angle_min = -pi).
    ranges = cast(0.0, 0.0, 0.0, [Circle(-3.0, 0.0, 0.3)], seed=1)
    assert np.isfinite(ranges[0]) and np.isfinite(ranges[-1])
    got = cluster_rays(ranges)
    assert len(got) == 1 and {0, 359} <= got[0]


def test_two_buoys_either_side_of_the_seam_stay_two():
    ranges = cast(0.0, 0.0, 0.0, [Circle(-3.0, 0.4, 0.2), Circle(-3.0, -0.4, 0.2)], seed=2)
    got = cluster_rays(ranges)
    assert len(got) == 2


@pytest.mark.parametrize(('missing', 'pieces'), [(2, 1), (3, 2)])
def test_rays_without_a_sample_are_bridged_up_to_max_gap(missing, pieces):
    ranges = cast(0.0, 0.0, 0.0, [], [Wall(2.0, -2.0, 2.0, 2.0)], noise=False)
    middle = 180   # straight ahead: the wall's nearest point
    ranges[middle:middle + missing] = np.nan
    assert len(cluster_rays(ranges)) == pieces


def test_a_ray_too_close_or_without_return_is_a_gap_like_a_missing_sample():
    ranges = cast(0.0, 0.0, 0.0, [], [Wall(2.0, -2.0, 2.0, 2.0)], noise=False)
    ranges[180] = -np.inf
    ranges[182] = np.inf
    assert len(cluster_rays(ranges)) == 1


def test_an_empty_scan_has_no_cluster_and_one_point_is_one():
    ranges = np.full(360, np.inf)
    assert cluster_rays(ranges) == []
    ranges[10] = 4.0
    assert cluster_rays(ranges) == [{10}]


def test_settings_refuse_a_lambda_beyond_a_right_angle():
    with pytest.raises(ValueError, match='^lam:'):
        BreakpointSettings(2.0, 2, SETTINGS.noise).validate()
    with pytest.raises(ValueError, match='^fractions:'):
        BreakpointSettings(LAM, 2, RangeNoise((3.0,), (0.01,))).validate()


@pytest.mark.parametrize('seed', range(3))
def test_the_seams_pair_is_judged_by_the_papers_bound(seed):
    # The seam of a full circle is one pair, judged in floats: just inside the paper's bound
    # (3 sigma_r included) it joins, just beyond it breaks, and a gap of more than max_gap
    # rays always breaks.
    rng = np.random.default_rng(seed)
    for r in rng.uniform(0.3, 11.0, 20).tolist():
        for apart in (1, 2, 3):
            bound = d_max(r, apart)
            joins = apart <= 3   # max_gap 2: up to two rays missing between them
            assert _break(r, apart, 0.999 * bound, INC, SETTINGS) is not joins
            assert _break(r, apart, 1.001 * bound, INC, SETTINGS) is True
        assert _break(r, 4, 0.0, INC, SETTINGS) is True
