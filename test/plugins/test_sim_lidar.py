"""The simulated RPLidar A1 (sim_lidar): its error model against the CS Saucer manual's
figures (typed here from Table 1.1 and section 1.5, not read from the code), its mask, and
the node's scans against the real driver's (rplidar on its emulator, the same world)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import LaserScan
from support.devices import FAST_RECONNECT as FAST
from support.nodes import add, probe, TIMEOUT
from support.saucer import odometry_msg, SimClock, T0_NS

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import Frame, FrameTree, Transform
from enbarr_core.framework.node import install_frame_tree, install_world
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Walls, World
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.lidar.rplidar import RplidarNode
from enbarr_plugins.lidar.rplidar_emulator import RplidarEmulatorNode
from enbarr_plugins.lidar.scan import bin_revolution
from enbarr_plugins.lidar.sim import SimLidarNode
from enbarr_plugins.lidar.sim_scan import A1Model, range_sigma, SimulatedA1

# Manual Table 1.1, "RPLidar A1": effective range 12 m, angular resolution 1 deg, range
# accuracy 1 % below 3 m, 2 % in [3, 5] m, 2.5 % beyond 5 m. The 0.15 m nearest range is
# Slamtec's A1 datasheet's.
MANUAL_RANGE_MAX = 12.0
DATASHEET_RANGE_MIN = 0.15
MANUAL_RESOLUTION_DEG = 1.0
MANUAL_ACCURACY = [(2.0, 0.01), (2.999, 0.01), (3.0, 0.02), (4.0, 0.02), (5.0, 0.02),
                   (5.001, 0.025), (8.0, 0.025), (11.0, 0.025)]
BASIN = Obstacle('basin', Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225),
                                 (-20.0, 3.225)), closed=True))


def ring(radius: float) -> World:
    """A solid disc around the lidar: seen from inside, every ray meets it at ``radius``."""
    return World([Obstacle('ring', Circle((0.0, 0.0), radius))])


def a1(world: World, seed: int = 0, mount: Transform = Transform(),
       **model: object) -> SimulatedA1:
    return SimulatedA1(world, mount, A1Model(**model), np.random.default_rng(seed))


# -- unit: the model -------------------------------------------------------------------------

@pytest.mark.parametrize('r, fraction', MANUAL_ACCURACY)
def test_the_error_bands_are_the_manuals(r: float, fraction: float) -> None:
    assert range_sigma(np.array([r]))[0] == pytest.approx(fraction * r)


@pytest.mark.parametrize('r, fraction', [(2.0, 0.01), (4.0, 0.02), (8.0, 0.025)])
def test_the_range_error_per_band_has_the_manuals_spread(r: float, fraction: float) -> None:
    lidar = a1(ring(r), seed=7)
    mm = np.concatenate([lidar.distances_mm(0.0, 0.0, 0.0, 0.0) for _ in range(40)])
    err = mm / 1000.0 - r  # 14 400 samples: the spread is known within about 1 %
    assert np.all(mm > 0.0)
    assert abs(err.mean()) < 4.0 * fraction * r / math.sqrt(len(err))  # unbiased
    assert err.std() == pytest.approx(fraction * r, rel=0.05)
    # a multiple of the protocol's quarter millimetre
    assert np.all(mm * 4.0 == np.round(mm * 4.0))


def test_a_seed_repeats_the_noise_and_another_does_not() -> None:
    one = a1(ring(4.0), seed=5).distances_mm(0.0, 0.0, 0.0, 0.0)
    assert np.array_equal(one, a1(ring(4.0), seed=5).distances_mm(0.0, 0.0, 0.0, 0.0))
    assert not np.array_equal(one, a1(ring(4.0), seed=6).distances_mm(0.0, 0.0, 0.0, 0.0))


def test_no_return_outside_the_range() -> None:
    lidar = a1(ring(MANUAL_RANGE_MAX - 0.1), noise_scale=0.0)
    assert np.all(lidar.distances_mm(0.0, 0.0, 0.0, 0.0) == pytest.approx(11900.0))
    assert np.all(a1(ring(MANUAL_RANGE_MAX + 0.1), noise_scale=0.0).distances_mm(
        0.0, 0.0, 0.0, 0.0) == 0.0)
    assert np.all(a1(ring(DATASHEET_RANGE_MIN - 0.01), noise_scale=0.0).distances_mm(
        0.0, 0.0, 0.0, 0.0) == 0.0)
    assert np.all(a1(ring(DATASHEET_RANGE_MIN + 0.01), noise_scale=0.0).distances_mm(
        0.0, 0.0, 0.0, 0.0) == pytest.approx(160.0))
    scan = a1(World(), noise_scale=0.0).scan(0.0, 0.0, 0.0, 0.0, 360)
    assert np.all(np.isposinf(scan))  # REP-117: nothing returned


def test_one_sample_per_degree() -> None:
    lidar = a1(World())
    assert len(lidar.angles) == round(360.0 / MANUAL_RESOLUTION_DEG)
    assert np.diff(lidar.angles) == pytest.approx(MANUAL_RESOLUTION_DEG)


def test_dropouts_return_nothing_at_the_given_rate() -> None:
    lidar = a1(ring(2.0), seed=1, noise_scale=0.0, dropout_probability=0.3)
    mm = np.concatenate([lidar.distances_mm(0.0, 0.0, 0.0, 0.0) for _ in range(20)])
    assert np.mean(mm == 0.0) == pytest.approx(0.3, abs=0.02)
    assert np.all(mm[mm > 0] == 2000.0)


def laser_bearings_deg(bins: int = 360) -> np.ndarray:
    return np.degrees(-math.pi + np.arange(bins) * 2.0 * math.pi / bins)


def test_the_mask_hides_the_marker_rods_sectors() -> None:
    """Manual 1.5: the rods stand outside [-90, 90] deg; here rods at 100-120 deg (port, aft)
    and at 170 to -170 deg (astern, through 180): those rays report no return (a rod inside
    the blind zone) or the rod's distance, and nothing beyond them."""
    b = laser_bearings_deg()
    sectors = ((99.5, 120.5), (169.5, -169.5))  # half-way between rays
    hidden = ((b > 99.5) & (b < 120.5)) | (b > 169.5) | (b < -169.5)
    assert hidden.sum() == 21 + 21
    scan = a1(ring(2.0), noise_scale=0.0, mask_sectors=sectors).scan(0.0, 0.0, 0.0, 0.0, 360)
    assert np.all(np.isposinf(scan[hidden])) and np.all(scan[~hidden] == 2.0)
    assert np.all(scan[(b > -90.0) & (b < 90.0)] == 2.0)  # the manual's clear sector
    rods = a1(ring(2.0), noise_scale=0.0, mask_sectors=sectors, mask_range=0.3)
    scan = rods.scan(0.0, 0.0, 0.0, 0.0, 360)
    assert np.all(scan[hidden] == 0.3) and np.all(scan[~hidden] == 2.0)


def test_the_mount_and_the_heading_turn_the_rays() -> None:
    """A wall 3 m north of the origin (y = 3). Vessel at the origin heading north (yaw pi/2);
    lidar 0.5 m ahead of base_link with its 0 deg mark to port (yaw pi/2): the lidar sits at
    (0, 0.5) and its +x looks west, so the wall (2.5 m away) is at -90 deg in its frame."""
    wall = World([Obstacle('w', Walls(((-50.0, 3.0), (50.0, 3.0))))])
    lidar = a1(wall, noise_scale=0.0, mount=Transform.planar(0.5, 0.0, math.pi / 2))
    scan = lidar.scan(0.0, 0.0, math.pi / 2, 0.0, 360)
    b = laser_bearings_deg()
    assert scan[np.argmin(np.abs(b + 90.0))] == pytest.approx(2.5)
    # +90 deg in its frame looks south, 0 deg west along the wall: nothing within 12 m
    assert np.isinf(scan[np.argmin(np.abs(b - 90.0))])
    assert np.isinf(scan[np.argmin(np.abs(b))])


def test_the_rays_are_the_drivers_bins_of_the_same_revolution() -> None:
    """The published rays are what rplidar's scan.bin_revolution makes of the A1's samples
    (clockwise angles, distances in mm): ray k at bearing -pi + k 2 pi / 360."""
    world = World([BASIN, Obstacle('buoy', Circle((3.0, 1.0), 0.3))])
    lidar = a1(world, seed=3)
    rng_copy = a1(world, seed=3)
    mm = rng_copy.distances_mm(1.0, 0.5, 0.3, 0.0)
    expected = bin_revolution(rng_copy.angles, mm, 360, DATASHEET_RANGE_MIN, MANUAL_RANGE_MAX)
    got = lidar.scan(1.0, 0.5, 0.3, 0.0, 360)
    assert np.array_equal(got, expected, equal_nan=True)
    # a clockwise angle a is the bearing -a: the sample at 90 deg lands on the ray at -90 deg
    k = int(np.argmin(np.abs(laser_bearings_deg() + 90.0)))
    assert got[k] == mm[90] / 1000.0


# -- node tests ------------------------------------------------------------------------------

def sim_rig(context, executor, world, tree=None, **params):
    install_world(context, world, epoch_ns=T0_NS)
    install_frame_tree(context, tree or FrameTree.of([
        Frame('odom'), Frame('base_link', 'odom', pose='observer/odometry'),
        Frame('laser', 'base_link', Transform((0.0, 0.0, 0.15)))]))
    lidar = add(executor, SimLidarNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()]))
    lidar.start()
    clock = SimClock(lidar)
    p = probe(context, executor, 'simulator')
    truth = p.create_topic_publisher(topics.SIM_ODOMETRY)
    scans: list[LaserScan] = []
    p.create_subscription(LaserScan, topics.SCAN.name, scans.append, topics.SCAN.qos)
    LinkBus.of(context).connect()
    return lidar, clock, truth, scans


def feed(spin, executor, lidar, truth, clock, scans, eta=(0.0, 0.0, 0.0)):
    """One truth now, then 10 ms on; each scan it makes received before the next (the
    sensor QoS keeps only the last few)."""
    truth.publish(odometry_msg(clock.ns, list(eta)))
    assert spin(executor, lambda: len(scans) == lidar.revolutions, TIMEOUT)
    clock.advance(0.01)


def test_the_node_scans_the_world_at_the_rotation_rate(context, executor, spin):
    """A boat 10 m east moving west at 1 m/s: the scans see it at the world time of their
    stamps (world time 0 = the scenario's start, T0), one scan per 1 / 5.5 s of truth."""
    boat = Obstacle('boat', Circle((10.0, 0.0), 0.5), ConstantVelocity((-1.0, 0.0)))
    lidar, clock, truth, scans = sim_rig(context, executor, World([BASIN, boat]),
                                         noise_scale=0.0)
    for _ in range(101):  # 1 s of truth at 100 Hz, from T0
        feed(spin, executor, lidar, truth, clock, scans)
    assert len(scans) == 6  # at 0, 0.19, 0.37, 0.55, 0.73, 0.91 s (on the 10 ms truths)
    s = scans[-1]
    assert s.header.frame_id == 'laser' and len(s.ranges) == 360
    assert (s.angle_min, s.angle_increment) == (pytest.approx(-math.pi),
                                                pytest.approx(2 * math.pi / 360))
    assert s.angle_max == pytest.approx(math.pi - 2 * math.pi / 360)
    assert (s.range_min, s.range_max) == (pytest.approx(0.15), pytest.approx(12.0))
    assert s.time_increment == 0.0 and s.scan_time == pytest.approx(1 / 5.5)
    for scan in scans:
        t = (scan.header.stamp.sec * 10**9 + scan.header.stamp.nanosec - T0_NS) * 1e-9
        ahead = scan.ranges[180]  # bearing 0: east, where the boat comes from
        assert ahead == pytest.approx(10.0 - t - 0.5, abs=1e-3)
        assert scan.ranges[270] == pytest.approx(3.225, abs=1e-3)  # north wall, 90 deg
    stamps = [sc.header.stamp.sec * 10**9 + sc.header.stamp.nanosec for sc in scans]
    assert np.diff(stamps) == pytest.approx([0.19e9, 0.18e9, 0.18e9, 0.18e9, 0.18e9],
                                            abs=0.011e9)
    assert lidar.status_values()['revolutions'] == 6


def test_rotation_rate_and_mask_are_tuned_live(context, executor, spin):
    lidar, clock, truth, scans = sim_rig(context, executor, World([BASIN]), noise_scale=0.0)
    lidar.set_parameters([Parameter('rotation_hz', value=10.0),
                          Parameter('mask_sectors', value=[100.0, 120.0])])
    for _ in range(100):
        feed(spin, executor, lidar, truth, clock, scans)
    assert len(scans) == 10
    assert scans[-1].scan_time == pytest.approx(0.1)
    assert math.isinf(scans[-1].ranges[180 + 110]) and scans[-1].ranges[180 + 90] == \
        pytest.approx(3.225, abs=1e-3)


def test_a_stalled_lidar_sends_nothing_in_its_windows(context, executor, spin):
    """An unplugged or stalled lidar publishes no scan (a scan of +inf would read as clear
    water): in world time [0.3, 0.7) s the revolutions at 0.37 and 0.55 s are not sent."""
    lidar, clock, truth, scans = sim_rig(context, executor, World([BASIN]), noise_scale=0.0,
                                         stall_windows=[0.3, 0.7])
    for _ in range(101):
        feed(spin, executor, lidar, truth, clock, scans)
    times = [(sc.header.stamp.sec * 10**9 + sc.header.stamp.nanosec - T0_NS) * 1e-9
             for sc in scans]
    assert times == pytest.approx([0.0, 0.19, 0.73, 0.91], abs=0.011)
    assert lidar.status_values()['stalled'] == 2


def test_a_truth_stamped_ahead_is_refused_and_does_not_silence_the_lidar(
        context, executor, spin):
    """A truth stamped ahead of the clock neither schedules a revolution nor moves the next
    one: it is refused, counted, and the node is DEGRADED for it."""
    lidar, clock, truth, scans = sim_rig(context, executor, World([BASIN]), noise_scale=0.0)
    for _ in range(10):
        feed(spin, executor, lidar, truth, clock, scans)
    for ahead in (20.0, 5.0):
        truth.publish(odometry_msg(clock.ns + round(ahead * 1e9), [0.0, 0.0, 0.0]))
    assert spin(executor, lambda: lidar.status_values()['refused'] == 2, TIMEOUT)
    level, message = lidar.status()
    assert level == 1 and 'sim/odometry: refused 2 of 12' in message, message
    for _ in range(91):
        feed(spin, executor, lidar, truth, clock, scans)
    assert len(scans) == 6  # as without the truths ahead: one per 1 / 5.5 s of 1 s


def test_bad_parameters_and_a_missing_frame_are_named(context):
    install_world(context, World())
    install_frame_tree(context, FrameTree.of([Frame('base_link')]))
    with pytest.raises(ConfigurationError, match="frame_id: the frame tree cannot place the "
                                                 "lidar: no frame 'laser'"):
        SimLidarNode(context=context)
    with pytest.raises(ConfigurationError, match='mask_sectors: expected pairs'):
        SimLidarNode(context=context, parameter_overrides=[
            Parameter('frame_id', value='base_link'),
            Parameter('mask_sectors', value=[100.0, 120.0, 130.0])])
    with pytest.raises(ConfigurationError, match='stall_windows: expected pairs of start < end'):
        SimLidarNode(context=context, parameter_overrides=[
            Parameter('frame_id', value='base_link'),
            Parameter('stall_windows', value=[5.0, 2.0])])
    with pytest.raises(ConfigurationError, match='mask_range: 0 .* got 0.1'):
        SimLidarNode(context=context, parameter_overrides=[
            Parameter('frame_id', value='base_link'), Parameter('mask_range', value=0.1)])


def test_the_simulated_scan_is_the_real_drivers(context, executor, spin):
    """The same world, the same pose: sim_lidar (noise off) and rplidar reading its emulator
    publish the same message: frame, ray geometry, limits, time_increment, and ranges that
    agree ray by ray within what the A1's own angles allow (the emulator's ~364 samples a
    revolution fall up to half a degree off the rays)."""
    world = World([BASIN, Obstacle('buoy', Circle((3.0, 1.0), 0.3))])
    lidar, clock, truth, sim_scans = sim_rig(context, executor, world, noise_scale=0.0)
    emu = add(executor, RplidarEmulatorNode(node_name='emu_same', context=context,
                                            parameter_overrides=[Parameter('name', value='same')]))
    emu.start()
    emu.emulator.set_pose(1.0, 0.5, 0.3)
    driver = add(executor, RplidarNode(node_name='rplidar_same', namespace='real',
                                       context=context, parameter_overrides=[
                                           Parameter('port', value='emulated:same'), *FAST]))
    driver.start()
    real: list[LaserScan] = []
    probe(context, executor, 'real_probe').create_subscription(
        LaserScan, '/real/scan', real.append, topics.SCAN.qos)
    truth.publish(odometry_msg(clock.ns, [1.0, 0.5, 0.3]))
    assert spin(executor, lambda: len(real) >= 2 and sim_scans, TIMEOUT), driver.last_fault
    r, s = real[-1], sim_scans[0]
    for field in ('angle_min', 'angle_increment', 'angle_max', 'time_increment', 'range_min',
                  'range_max'):
        assert getattr(s, field) == pytest.approx(getattr(r, field)), field
    assert s.header.frame_id == r.header.frame_id == 'laser'
    assert len(s.ranges) == len(r.ranges) == 360
    a, b = np.array(s.ranges), np.array(r.ranges)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 250
    assert np.median(np.abs(a[both] - b[both])) < 0.02
    assert np.mean(np.isposinf(a) == np.isposinf(b)) > 0.95


def test_the_scan_carries_its_truths_stamp_and_pose(context, executor, spin):
    """A truth that arrives 5 ms after it was taken: the scan is stamped with the truth's
    time (the pose and the world it was cast at), not with the clock's."""
    lidar, clock, truth, scans = sim_rig(context, executor, World([BASIN]), noise_scale=0.0)
    clock.advance(0.5)
    taken = clock.ns - 5_000_000
    truth.publish(odometry_msg(taken, [0.0, 2.0, 0.0]))
    assert spin(executor, lambda: scans, TIMEOUT)
    s = scans[0]
    assert s.header.stamp.sec * 10**9 + s.header.stamp.nanosec == taken
    assert s.ranges[270] == pytest.approx(1.225, abs=1e-3)  # the north wall from y = 2
