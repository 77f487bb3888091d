"""Tracking across scans (pure): the whole pipeline on scans cast in support.lidar_scene, and
the assignment on hand-placed measurements.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from support.lidar_scene import Circle, NOISE_FRACTIONS, NOISE_LIMITS, Wall, cast

from enbarr_interfaces.obstacles import CIRCLE, SEGMENT
from enbarr_core.perception.fitting import CircleFit, FitSettings
from enbarr_core.perception.pipeline import LidarMount, PerceptionSettings, ScanObstacles
from enbarr_core.perception.scan_geometry import PoseHistory, RangeNoise
from enbarr_core.perception.segmentation import BreakpointSettings
from enbarr_core.perception.tracking import (
    assign, CircleTrack, inverse_2x2, motion, Tracker, TrackerSettings)

N, M = 3, 5
TRACKER = TrackerSettings(confirm_hits=N, drop_misses=M, gate=9.21, accel_noise=0.2,
                          initial_speed_std=1.0, radius_smoothing=0.3, segment_gate=0.3,
                          segment_angle_gate=0.2)
SETTINGS = PerceptionSettings(
    BreakpointSettings(math.radians(10.0), 2, RangeNoise(NOISE_LIMITS, NOISE_FRACTIONS)), 2,
    FitSettings(0.05, 1.0, 0.4, 0.8, 0.1), TRACKER, 100_000_000, 'at_stamp')
PERIOD_NS = round(1e9 / 5.5)     # the manual's 5.5 Hz revolutions
INC = 2.0 * math.pi / 360
LEVEL = LidarMount(np.eye(3), np.zeros(3))


class Run:
    """The pipeline fed scans of a still vessel at the origin, poses at 50 Hz around them."""

    def __init__(self, settings: PerceptionSettings = SETTINGS) -> None:
        self.pipeline = ScanObstacles(settings)
        self.poses = PoseHistory()
        self.k = 0

    def scan(self, ranges: np.ndarray):
        t = (self.k + 1) * PERIOD_NS
        self.k += 1
        for s in range(t - PERIOD_NS, t + 2 * 20_000_000, 20_000_000):
            self.poses.add(s, 0.0, 0.0, 0.0)
        return self.pipeline.process(ranges, -math.pi, INC, 0.0, t, LEVEL, self.poses)


def test_a_buoy_is_published_after_n_scans_and_dropped_after_m_missed():
    run = Run()
    buoy = [Circle(3.0, 1.0, 0.3)]
    for k in range(N - 1):
        assert run.scan(cast(0.0, 0.0, 0.0, buoy, seed=k)).obstacles == []
    out = run.scan(cast(0.0, 0.0, 0.0, buoy, seed=N))
    assert [o.kind for o in out.obstacles] == [CIRCLE]
    seen = out.obstacles[0]
    empty = np.full(360, np.inf)
    for _ in range(M - 1):
        out = run.scan(empty)
        assert [o.id for o in out.obstacles] == [seen.id]
        assert out.obstacles[0].stamp_ns == seen.stamp_ns   # the last scan that measured it
    assert run.scan(empty).obstacles == []


def test_every_obstacle_carries_the_stamp_of_the_scan_that_measured_it():
    run = Run()
    for k in range(N + 2):
        out = run.scan(cast(0.0, 0.0, 0.0, [Circle(3.0, 1.0, 0.3)], [Wall(6, -2, 6, 2)], seed=k))
    assert {o.kind for o in out.obstacles} == {CIRCLE, SEGMENT}
    assert {o.stamp_ns for o in out.obstacles} == {run.k * PERIOD_NS}


@pytest.mark.parametrize('min_points', [1, 2])
def test_single_spurious_returns_never_become_obstacles(min_points):
    settings = dataclasses.replace(SETTINGS, min_cluster_points=min_points)
    run = Run(settings)
    rng = np.random.default_rng(11)
    for _ in range(60):
        ranges = np.full(360, np.inf)
        ranges[rng.integers(360)] = rng.uniform(0.5, 11.0)   # one stray return per scan
        assert run.scan(ranges).obstacles == []


def test_a_buoy_moving_at_0_2_m_s_is_tracked_with_its_velocity_within_3_cm_s():
    # Crossing ahead at 2.5 m (the manual's 1 % band), 11 s after it was first seen.
    run = Run()
    v = np.array([0.2, 0.0])
    p0 = np.array([-1.1, 2.5])
    for k in range(60):
        x, y = p0 + v * (k + 1) * PERIOD_NS * 1e-9
        out = run.scan(cast(0.0, 0.0, 0.0, [Circle(x, y, 0.3)], seed=100 + k))
    assert len(out.obstacles) == 1
    o = out.obstacles[0]
    assert math.hypot(o.vx - v[0], o.vy - v[1]) < 0.03
    assert math.hypot(o.x - x, o.y - y) < 0.05
    assert abs(o.radius - 0.3) < 0.05
    assert 0.0 < o.velocity_cov[0] < 0.01   # and the filter knows it knows it


def test_a_wall_behind_a_buoy_is_a_segment_and_the_buoy_a_circle():
    run = Run()
    for k in range(N):
        out = run.scan(cast(0.0, 0.0, 0.0, [Circle(2.0, 0.0, 0.3)],
                            [Wall(5.0, -3.0, 5.0, 3.0)], seed=k))
    circles = [o for o in out.obstacles if o.kind == CIRCLE]
    walls = [o for o in out.obstacles if o.kind == SEGMENT]
    assert len(circles) == 1 and math.dist((circles[0].x, circles[0].y), (2.0, 0.0)) < 0.1
    assert len(walls) == 2    # the buoy hides the middle of the wall
    for w in walls:
        assert abs(w.x - 5.0) < 0.2 and abs(w.end[0] - 5.0) < 0.2


def test_a_crossing_is_assigned_jointly_where_nearest_first_would_lose_a_track():
    # Tracks at x = 0 and x = 1; measurements at 0.55 and 1.7 (distances in standard
    # deviations, the gate at 1.0 of them). Nearest first takes B <- 0.55 (0.45), then
    # A <- 1.7 is beyond the gate: A misses and a new track starts at 1.7. Jointly,
    # A <- 0.55 and B <- 1.7 are both within the gate.
    sigma2 = 0.5   # track and measurement variance, each: S = 1 per axis
    settings = dataclasses.replace(TRACKER, gate=1.0, confirm_hits=1)
    tracker = Tracker(settings)

    def meas(x: float) -> CircleFit:
        return CircleFit(x, 0.0, 0.2, (sigma2, 0.0, sigma2), 0.01)

    tracker.update([meas(0.0), meas(1.0)], [], 0)
    a, b = tracker.circles
    for t in (a, b):
        t.kf.P = np.diag([sigma2, sigma2, 1e-9, 1e-9])
    tracker.update([meas(0.55), meas(1.7)], [], 1)   # dt = 1 ns: no motion
    assert [t.id for t in tracker.circles] == [a.id, b.id]   # no new track
    assert a.misses == 0 and b.misses == 0
    assert 0.0 < a.kf.x[0, 0] < 0.55 and 1.0 < b.kf.x[0, 0] < 1.7


def test_assign_rules_out_pairs_beyond_the_gate():
    cost = np.array([[0.5, 20.0], [20.0, 30.0]])
    assert assign(cost, 9.0) == [(0, 0)]
    assert assign(np.zeros((0, 3)), 9.0) == []


def test_a_scan_older_than_the_last_is_refused():
    tracker = Tracker(TRACKER)
    tracker.update([], [], 10)
    with pytest.raises(ValueError, match='older'):
        tracker.update([], [], 5)


def test_settings_refuse_zero_hits():
    with pytest.raises(ValueError, match='^confirm_hits:'):
        dataclasses.replace(TRACKER, confirm_hits=0).validate()


def test_a_short_segment_at_a_tracked_buoy_is_its_front_not_a_wall():
    # A far buoy's few noisy points may fit a line as well as a circle in one scan.
    from enbarr_core.perception.fitting import SegmentFit
    tracker = Tracker(TRACKER)
    buoy = CircleFit(3.0, 0.0, 0.3, (0.01, 0.0, 0.01), 0.01)
    for k in range(N):
        tracker.update([buoy], [], k * PERIOD_NS)
    (track,) = tracker.circles
    front = SegmentFit(2.72, -0.25, 2.72, 0.25, 0.03, 6)
    tracker.update([], [front], N * PERIOD_NS)
    assert tracker.segments == [] and tracker.circles == [track]
    # the front places it and stamps it, but is not a circle: no hit, a miss
    assert track.stamp_ns == N * PERIOD_NS and (track.hits, track.misses) == (N, 1)
    assert track.kf.x[0, 0] == pytest.approx(3.0, abs=0.05)
    tracker.update([buoy], [], (N + 1) * PERIOD_NS)
    assert (track.hits, track.misses) == (N + 1, 0)
    # a long segment there is a wall in front of it, not the buoy
    tracker.update([], [SegmentFit(2.6, -2.0, 2.6, 2.0, 0.03, 40)], (N + 2) * PERIOD_NS)
    assert len(tracker.segments) == 1 and track.misses == 1


def test_fronts_alone_do_not_keep_a_circle_alive():
    # A buoy's short arc once fitted far too large (0.66 m): then only the wall behind it is
    # seen, in pieces short enough to be that circle's front. They must not carry the circle
    # along the wall (ca_ten_buoys did so for 44 s): after M scans of fronts it is dropped,
    # and the pieces are the wall's.
    from enbarr_core.perception.fitting import SegmentFit
    tracker = Tracker(TRACKER)
    big = CircleFit(1.0, 2.6, 0.66, (0.01, 0.0, 0.01), 0.01)
    for k in range(N):
        tracker.update([big], [], k * PERIOD_NS)
    (ghost,) = tracker.circles
    for k in range(N, N + M):
        x = 1.0 + 0.1 * (k - N)   # the wall y = 3.225 seen in 1.2 m pieces, moving along
        assert ghost in tracker.circles
        tracker.update([], [SegmentFit(x - 0.6, 3.225, x + 0.6, 3.225, 0.01, 20)],
                       k * PERIOD_NS)
    assert tracker.circles == []
    tracker.update([], [SegmentFit(1.0, 3.225, 2.2, 3.225, 0.01, 20)], (N + M) * PERIOD_NS)
    assert len(tracker.segments) == 1


def test_the_constant_velocity_model_is_bar_shaloms():
    # Bar-Shalom, Li and Kirubarajan 2001, sec. 6.3.2, per axis: F = [[1, T], [0, 1]],
    # Q = q^2 [[T^4/4, T^3/2], [T^3/2, T^2]]; the state here is [px, py, vx, vy]
    f, q = motion(0.5, 0.2)
    assert f.tolist() == [[1, 0, 0.5, 0], [0, 1, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1]]
    per_axis = 0.04 * np.array([[0.015625, 0.0625], [0.0625, 0.25]])
    assert q[np.ix_([0, 2], [0, 2])] == pytest.approx(per_axis, abs=1e-15)
    assert q[np.ix_([1, 3], [1, 3])] == pytest.approx(per_axis, abs=1e-15)
    assert q[np.ix_([0, 2], [1, 3])] == pytest.approx(np.zeros((2, 2)), abs=0.0)


def test_the_written_out_inverse_is_numpys_and_refuses_a_singular_matrix():
    rng = np.random.default_rng(3)
    for _ in range(20):
        s = rng.normal(size=(2, 2))
        assert inverse_2x2(s) == pytest.approx(np.linalg.inv(s), rel=1e-12, abs=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        inverse_2x2(np.array([[1.0, 2.0], [2.0, 4.0]]))


def test_a_track_filters_as_filterpy_does_with_numpys_inverse():
    z = CircleFit(2.0, -1.0, 0.3, (4e-4, 1e-4, 9e-4), 0.01)
    ours, ref = CircleTrack(1, z, 0, 1.0), CircleTrack(2, z, 0, 1.0)
    ref.kf.inv = np.linalg.inv
    f, q = motion(0.18, 0.2)
    for k in range(1, 6):
        for t in (ours, ref):
            t.predict(f, q)
            t.update(dataclasses.replace(z, x=2.0 + 0.03 * k, y=-1.0 - 0.01 * k), k, 0.3)
    assert ours.kf.x == pytest.approx(ref.kf.x, abs=1e-12)
    assert ours.kf.P == pytest.approx(ref.kf.P, abs=1e-12)


@pytest.mark.parametrize('seed', range(4))
def test_assign_is_the_least_cost_set_of_pairs_in_the_gates(seed):
    # Against every assignment tried (itertools): the most pairs within the gate, and of
    # those the least total cost; apart obstacles (one candidate each) and crowded ones.
    rng = np.random.default_rng(seed)
    for _ in range(60):
        rows, cols = rng.integers(1, 5, 2).tolist()
        cost = rng.uniform(0.0, 12.0, (rows, cols))
        if rng.uniform() < 0.5:   # apart: at most one pair in a gate per row and column
            cost[:] = 50.0
            for i, j in zip(rng.permutation(rows), rng.permutation(cols)):
                cost[i, j] = rng.uniform(0.0, 12.0)
        # each way of pairing min(rows, cols) rows and columns, pairs beyond the gate dropped
        best = max((len(pairs), -sum(cost[i, j] for i, j in pairs))
                   for perm in itertools.permutations(range(max(rows, cols)), min(rows, cols))
                   for pairs in [[(i, j) for i, j in (zip(range(rows), perm) if rows <= cols
                                                      else zip(perm, range(cols)))
                                  if cost[i, j] <= 9.0]])
        got = assign(cost, 9.0)
        assert assign(cost.tolist(), 9.0) == got      # the tracker's rows of floats
        assert got == sorted(got)
        assert len({i for i, _ in got}) == len(got) == len({j for _, j in got})
        assert all(cost[i, j] <= 9.0 for i, j in got)
        assert len(got) == best[0]
        assert sum(cost[i, j] for i, j in got) == pytest.approx(-best[1], abs=1e-9)
