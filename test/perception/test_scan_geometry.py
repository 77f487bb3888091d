"""Scan points and their posing in the world (pure): pose history, per-ray poses, the mount."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.lidar_scene import Circle, NOISE_FRACTIONS, NOISE_LIMITS, RAYS, cast

from enbarr_core.framework.frames import Transform
from enbarr_core.perception.fitting import CircleFit
from enbarr_core.perception.pipeline import LidarMount
from enbarr_core.perception.scan_geometry import PoseHistory, RangeNoise, scan_points

MS = 1_000_000
INC = 2.0 * math.pi / RAYS


def test_range_noise_is_the_manuals_bands():
    noise = RangeNoise(NOISE_LIMITS, NOISE_FRACTIONS)
    r = np.array([1.0, 2.99, 3.0, 4.5, 5.0, 10.0])
    assert noise.sigma(r) == pytest.approx([0.01, 0.0299, 0.06, 0.09, 0.125, 0.25])
    # one range at a time (the fits' noise at a cluster's middle ray): the same bands
    assert [noise.sigma_at(float(x)) for x in r] == pytest.approx(
        [0.01, 0.0299, 0.06, 0.09, 0.125, 0.25])


def test_only_finite_ranges_become_points_in_ring_order():
    ranges = np.array([1.0, np.nan, np.inf, -np.inf, 2.0, 3.0])
    scan = scan_points(ranges, -math.pi, 2.0 * math.pi / 6)
    assert scan.index.tolist() == [0, 4, 5]
    assert scan.laser[0] == pytest.approx([-1.0, 0.0], abs=1e-12)   # the first ray: -pi
    assert scan.full_circle
    assert not scan_points(ranges, -1.0, 0.1).full_circle


def test_poses_are_interpolated_across_the_heading_seam():
    h = PoseHistory()
    assert h.add(0, 0.0, 0.0, math.pi - 0.1)
    assert h.add(20 * MS, 0.2, 0.0, -math.pi + 0.1)   # turned 0.2 rad counter-clockwise
    assert not h.add(10 * MS, 9.0, 9.0, 0.0)          # older: refused
    eta = h.at(np.array([10 * MS]), 15 * MS)
    assert eta is not None
    assert eta[0, :2] == pytest.approx([0.1, 0.0])
    assert math.remainder(eta[0, 2] - math.pi, 2.0 * math.pi) == pytest.approx(0.0, abs=1e-12)


def test_a_time_without_a_pose_near_it_is_not_posed():
    h = PoseHistory()
    assert h.at(np.array([0]), 10 * MS) is None      # no pose at all
    h.add(0, 0.0, 0.0, 0.0)
    h.add(300 * MS, 1.0, 0.0, 0.0)
    assert h.at(np.array([100 * MS]), 90 * MS) is None          # a gap in the estimate
    assert h.at(np.array([-50 * MS]), 90 * MS) is not None      # held within the tolerance
    assert h.at(np.array([400 * MS]), 90 * MS) is None          # newer than the history


def test_the_history_keeps_its_newest_poses():
    h = PoseHistory(capacity=4)
    for k in range(20):
        h.add(k * MS, float(k), 0.0, 0.0)
    assert len(h) <= 8
    eta = h.at(np.array([19 * MS]), 0)
    assert eta is not None and eta[0, 0] == 19.0
    assert h.at(np.array([2 * MS]), 0) is None


def test_poses_between_the_history_s_poses_are_its_interpolation():
    """``at`` reads only the poses around the times asked: the same as over all of them."""
    rng = np.random.default_rng(4)
    h = PoseHistory(capacity=64)
    stamps = np.cumsum(rng.integers(15 * MS, 25 * MS, 100))
    poses = rng.uniform(-1.0, 1.0, (100, 3))
    for t, (x, y, psi) in zip(stamps.tolist(), poses.tolist()):
        h.add(t, x, y, psi)
    kept = stamps[len(stamps) - len(h):]
    rows = poses[len(stamps) - len(h):]
    psi = np.unwrap(poses[:, 2])[len(stamps) - len(h):]
    for _ in range(50):
        q = np.sort(rng.integers(int(kept[10]), int(kept[-10]), 30))
        eta = h.at(q, 30 * MS)
        assert eta is not None
        np.testing.assert_allclose(eta[:, 0], np.interp(q, kept, rows[:, 0]), atol=1e-12)
        np.testing.assert_allclose(eta[:, 1], np.interp(q, kept, rows[:, 1]), atol=1e-12)
        np.testing.assert_allclose(eta[:, 2], np.interp(q, kept, psi), atol=1e-12)


def test_one_time_is_posed_as_in_an_array_of_times():
    """The single-time path in floats gives the array path's pose and refusals."""
    rng = np.random.default_rng(2)
    h = PoseHistory(capacity=64)
    stamps = np.cumsum(rng.integers(15 * MS, 25 * MS, 100))
    for t, (x, y, psi) in zip(stamps.tolist(), rng.uniform(-3.0, 3.0, (100, 3)).tolist()):
        h.add(t, x, y, psi)
    refused = 0
    for q in rng.integers(int(stamps[0]) - 50 * MS, int(stamps[-1]) + 50 * MS, 2000).tolist():
        one, two = h.at(np.array([q]), 12 * MS), h.at(np.array([q, q]), 12 * MS)
        assert (one is None) == (two is None)
        if one is None:
            refused += 1
            continue
        np.testing.assert_allclose(one[0], two[0], rtol=0.0, atol=1e-12)
    assert 20 < refused < 500      # both ways refused some: gaps, and beyond the history


def test_a_mount_and_one_pose_map_points_as_the_two_steps_do():
    """LidarMount.to_world (one affine map) against to_base then to_world, tilted mounts too."""
    from scipy.spatial.transform import Rotation
    from enbarr_core.perception.pipeline import LidarMount
    from enbarr_core.perception.scan_geometry import to_world
    rng = np.random.default_rng(6)
    for _ in range(20):
        r = Rotation.from_euler('xyz', rng.uniform(-0.3, 0.3, 3) * (1, 1, 10)).as_matrix()
        mount = LidarMount(r, rng.uniform(-0.5, 0.5, 3))
        laser = rng.uniform(-5.0, 5.0, (40, 2))
        eta = rng.uniform(-3.0, 3.0, 3)
        np.testing.assert_allclose(mount.to_world(laser, eta.tolist()),
                                   to_world(mount.to_base(laser), eta), atol=1e-12)


def measure(ranges, time_increment, mount, poses, stamp=0, scan_time=0.0,
            sweep='clockwise_from_zero'):
    from enbarr_core.perception.fitting import FitSettings
    from enbarr_core.perception.pipeline import PerceptionSettings, ScanObstacles
    from enbarr_core.perception.segmentation import BreakpointSettings
    from enbarr_core.perception.tracking import TrackerSettings
    settings = PerceptionSettings(
        BreakpointSettings(math.radians(10.0), 2, RangeNoise(NOISE_LIMITS, NOISE_FRACTIONS)),
        2, FitSettings(0.05, 1.0, 0.4, 0.8, 0.1),
        TrackerSettings(3, 5, 9.21, 0.2, 1.0, 0.3, 0.3, 0.2), 100 * MS, sweep)
    return ScanObstacles(settings).measure(ranges, -math.pi, INC, time_increment, stamp,
                                           mount, poses, scan_time)


def test_each_ray_is_posed_at_its_own_time_while_the_vessel_turns():
    # Turning at 1 rad/s through a 0.18 s revolution; each ray cast with the heading of its
    # own time (geometry of the test). A buoy on the left is seen by the rays of the last
    # quarter, 0.13 s after the scan's stamp.
    rate, dt_ray = 1.0, (1.0 / 5.5) / RAYS
    buoy = Circle(0.0, 3.0, 0.3)
    ranges = np.full(RAYS, np.inf)
    for i in range(RAYS):
        psi = rate * i * dt_ray
        ranges[i] = cast(0.0, 0.0, psi, [buoy], noise=False)[i]
    poses = PoseHistory()
    for k in range(-2, 12):
        poses.add(k * 20 * MS, 0.0, 0.0, rate * k * 0.02)
    got = measure(ranges, dt_ray, LidarMount(np.eye(3), np.zeros(3)), poses)
    assert got is not None
    shapes, _, _ = got
    circles = [s for s in shapes if isinstance(s, CircleFit)]
    assert len(circles) == 1
    assert math.dist((circles[0].x, circles[0].y), (0.0, 3.0)) < 0.02
    # posing the whole scan at its stamp puts it 0.4 m off
    still = measure(ranges, 0.0, LidarMount(np.eye(3), np.zeros(3)), poses)
    assert still is not None
    off = [s for s in still[0] if isinstance(s, CircleFit)]
    assert math.dist((off[0].x, off[0].y), (0.0, 3.0)) > 0.3


@pytest.mark.parametrize('bearing', [0.5 * math.pi, -0.5 * math.pi, 0.9 * math.pi, 0.0, 0.03])
def test_a_scan_without_time_increment_is_read_as_the_rplidar_sweeps(bearing):
    # The RPLidar (the rplidar plugin's scans: time_increment 0): the revolution starts at
    # bearing 0 and turns clockwise over scan_time, so the ray at bearing b was taken
    # ((-b) mod 2 pi) / 2 pi of a revolution after the stamp. Turning at 1 rad/s.
    rate, scan_time = 1.0, 1.0 / 5.5
    buoy = Circle(3.0 * math.cos(bearing), 3.0 * math.sin(bearing), 0.3)
    ranges = np.full(RAYS, np.inf)
    for i in range(RAYS):
        b = -math.pi + i * INC
        psi = rate * (-b % (2.0 * math.pi)) / (2.0 * math.pi) * scan_time
        ranges[i] = cast(0.0, 0.0, psi, [buoy], noise=False)[i]
    poses = PoseHistory()
    for k in range(-2, 12):
        poses.add(k * 20 * MS, 0.0, 0.0, rate * k * 0.02)
    mount = LidarMount(np.eye(3), np.zeros(3))
    got = measure(ranges, 0.0, mount, poses, scan_time=scan_time)
    assert got is not None
    (circle,) = [s for s in got[0] if isinstance(s, CircleFit)]
    assert math.dist((circle.x, circle.y), (buoy.x, buoy.y)) < 0.02
    if abs(bearing) < 0.5:
        return   # dead ahead: its rays are the first and the last of the sweep, seen once
    still = measure(ranges, 0.0, mount, poses, scan_time=scan_time, sweep='at_stamp')
    assert still is not None
    (off,) = [s for s in still[0] if isinstance(s, CircleFit)]
    assert math.dist((off.x, off.y), (buoy.x, buoy.y)) > 0.1


def test_the_lidar_mount_and_the_pose_place_points_in_the_world():
    # The lidar 0.3 m ahead of and 0.1 m left of base_link, turned a quarter turn; the vessel
    # at (1, 2) heading 0.5 rad. The buoy at (4, 3) in the world.
    t = Transform.from_rpy((0.3, 0.1, 0.15), (0.0, 0.0, 0.5 * math.pi))
    mount = LidarMount(t.rotation_matrix, np.asarray(t.translation))
    x, y, psi = 1.0, 2.0, 0.5
    lx = x + math.cos(psi) * 0.3 - math.sin(psi) * 0.1
    ly = y + math.sin(psi) * 0.3 + math.cos(psi) * 0.1
    ranges = cast(lx, ly, psi + 0.5 * math.pi, [Circle(4.0, 3.0, 0.3)], noise=False)
    poses = PoseHistory()
    for k in range(-3, 4):
        poses.add(k * 20 * MS, x, y, psi)
    got = measure(ranges, 0.0, mount, poses)
    assert got is not None
    circles = [s for s in got[0] if isinstance(s, CircleFit)]
    assert len(circles) == 1
    assert math.dist((circles[0].x, circles[0].y), (4.0, 3.0)) < 0.01


def test_a_scan_without_a_pose_near_it_measures_nothing():
    poses = PoseHistory()
    poses.add(0, 0.0, 0.0, 0.0)
    ranges = cast(0.0, 0.0, 0.0, [Circle(2.0, 0.0, 0.3)])
    assert measure(ranges, 0.0, LidarMount(np.eye(3), np.zeros(3)), poses,
                   stamp=500 * MS) is None


def test_a_snapshot_keeps_the_poses_of_its_time():
    h = PoseHistory()
    h.add(0, 0.0, 0.0, 0.0)
    h.add(20 * MS, 1.0, 0.0, 0.0)
    copy = h.snapshot()
    h.add(40 * MS, 2.0, 0.0, 0.0)
    assert len(copy) == 2 and len(h) == 3
    eta = copy.at(np.array([10 * MS]), 15 * MS)
    assert eta is not None and eta[0, 0] == pytest.approx(0.5)
    assert copy.at(np.array([40 * MS]), 5 * MS) is None
