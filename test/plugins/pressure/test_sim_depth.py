"""The simulated depth sensor: the simulator's depth as the MS5837-30BA would report it."""

from __future__ import annotations

from nav_msgs.msg import Odometry
import pytest
from rclpy.parameter import Parameter

from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.pressure import sim
from enbarr_plugins.pressure.sim import SimDepthNode
from support.nodes import add, probe
from support.saucer import SimClock
from support.waiting import spin_until

TIMEOUT = 10.0


def settings(**changes):
    values = {spec.name: spec.default for spec in sim.SPECS}
    values.update(changes)
    return sim.SimDepthSettings.from_params(values)


def test_measure_rounds_to_the_chips_steps():
    s = settings(water_temperature=12.346)
    # 5 m of fresh water: 101325 + 997 * 9.80665 * 5 = 150211.15 Pa -> 150210 (10 Pa steps).
    assert sim.measure(5.0, s, 0.0) == (150210.0, pytest.approx(12.35))
    # +3 Pa of noise stays in the step (150214.15); -7 Pa falls to the next (150204.15).
    assert sim.measure(5.0, s, 3.0)[0] == 150210.0
    assert sim.measure(5.0, s, -7.0)[0] == 150200.0
    # Above the surface the sensor reads the air.
    assert sim.measure(-0.5, s, 0.0)[0] == 101320.0  # 101325 rounds (half to even) to 101320
    # Salt water in the simulated world: 101325 + 1029 * 9.80665 * 5 = 151779.2 -> 151780.
    assert sim.measure(5.0, settings(water_density=1029.0), 0.0)[0] == 151780.0


def odometry(t_ns: int, z: float) -> Odometry:
    msg = Odometry()
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    msg.header.frame_id = topics.WORLD_FRAME
    msg.pose.pose.position.z = z
    msg.pose.pose.orientation.w = 1.0
    return msg


def test_the_twin_publishes_the_drivers_topics_from_the_simulated_depth(context, executor):
    node = add(executor, SimDepthNode(context=context, parameter_overrides=[
        Parameter('rate', value=10.0), Parameter('pressure_noise', value=20.0),
        Parameter('water_temperature', value=8.0)]))
    node.start()
    clock = SimClock(node)
    p = probe(context, executor, 'simulator')
    truth = p.create_topic_publisher(topics.SIM_ODOMETRY)
    got: dict[str, list] = {'p': [], 't': [], 'd': []}
    p.create_topic_subscription(topics.PRESSURE, got['p'].append)
    p.create_topic_subscription(topics.PRESSURE_TEMPERATURE, got['t'].append)
    p.create_topic_subscription(topics.DEPTH, got['d'].append)
    LinkBus.of(context).connect()
    # The depth topics are ROS topics (best effort): publish once the probe is matched.
    assert spin_until(executor, lambda: all(
        node.count_subscribers(t.name) >= 1
        for t in (topics.PRESSURE, topics.PRESSURE_TEMPERATURE, topics.DEPTH)), TIMEOUT)
    for _ in range(50):                        # 1 s at 50 Hz, 3 m deep: 10 samples
        truth.publish(odometry(clock.advance(0.02), -3.0))
        # Each sample taken before the next (the subscription keeps only the last few).
        assert spin_until(executor, lambda: all(len(v) == node.samples for v in got.values()),
                          TIMEOUT)
    assert node.samples == 10, node.status_values()
    pressures = [m.fluid_pressure for m in got['p']]
    assert all(round(x) % 10 == 0 for x in pressures)          # 0.1 mbar steps
    # 101325 + 997 * 9.80665 * 3 = 130656.9 Pa; noise 20 Pa std: every sample within 5 std.
    assert all(abs(x - 130656.9) < 110.0 for x in pressures)
    assert len(set(pressures)) > 1                              # the noise is there
    assert got['t'][-1].temperature == pytest.approx(8.0)
    depths = [-m.pose.pose.position.z for m in got['d']]
    assert all(abs(d - 3.0) < 0.012 for d in depths)
    assert got['d'][-1].header.frame_id == 'odom'
