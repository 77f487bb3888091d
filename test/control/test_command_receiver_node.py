"""Node tests: command receiver node."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from support.nodes import TIMEOUT, add, probe
from support.rov import io_msg, stamp_ns, twist

from enbarr_core.control.command_gate import Verdict
from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


class Surface:
    """The receiver and a surface station talking to it over ROS topics."""

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, CommandReceiverNode(
            node_name='command_receiver', context=context, parameter_overrides=[
                Parameter('timeout', value=0.2), Parameter('max_age', value=5.0),
                Parameter('max_linear', value=1.0)]))
        self.probe = surface = probe(context, executor, 'surface')
        self.twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                                  topics.SURFACE_TWIST.qos)
        self.io_pub = surface.create_publisher(ParameterMsg, topics.SURFACE_IO.name,
                                               topics.SURFACE_IO.qos)
        self.goals: list[np.ndarray] = []
        self.ios: list[ParameterMsg] = []
        surface.create_topic_subscription(
            topics.TRAJECTORY_REQUEST, lambda m: self.goals.append(convert.twist_to_nu(m.twist)))
        surface.create_topic_subscription(topics.IO_REQUEST, self.ios.append)
        # A plain ROS subscription (as `ros2 topic echo` would make) gets the link topic.
        self.echoed: list[TwistStamped] = []
        surface.create_subscription(TwistStamped, topics.TRAJECTORY_REQUEST.name,
                                    self.echoed.append, topics.TRAJECTORY_REQUEST.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.twist_pub.get_subscription_count() > 0
                    and self.io_pub.get_subscription_count() > 0, TIMEOUT)

    def until(self, condition: Any) -> bool:
        return self.spin(self.executor, condition, TIMEOUT)

    def send(self, nu: list[float], offset_s: float = 0.0) -> None:
        self.twist_pub.publish(twist(self.probe, nu, offset_s))


@pytest.fixture
def rig(context, executor, spin) -> Surface:
    return Surface(context, executor, spin)


WANTED = [0.3, -0.2, 0.1, 0.0, 0.05, -0.4]


# -- velocity commands -----------------------------------------------------------------------

def test_goal_travels_over_the_link_bus(rig):
    # The receiver's goal publisher is in this process: the probe is fed by direct calls.
    assert all(s.local for s in rig.probe._links)


def test_zero_goal_before_any_command(rig):
    assert rig.until(lambda: len(rig.goals) >= 2)
    assert not np.any(rig.goals[-1])


def test_plain_ros_subscribers_get_the_goal(rig):
    assert rig.until(lambda: len(rig.echoed) >= 2)
    assert rig.echoed[-1].header.frame_id == topics.BODY_FRAME


def test_a_fresh_valid_command_becomes_the_goal(rig):
    rig.send(WANTED)
    assert rig.until(lambda: any(np.allclose(g, WANTED) for g in rig.goals))
    assert rig.node.gate.counts[Verdict.ACCEPTED] == 1


REFUSED = [
    (Verdict.NON_FINITE, [math.nan, 0, 0, 0, 0, 0], 0.0),
    (Verdict.NON_FINITE, [0, 0, 0, 0, 0, math.inf], 0.0),
    (Verdict.OUT_OF_RANGE, [1.5, 0, 0, 0, 0, 0], 0.0),
    (Verdict.OUT_OF_RANGE, [0, 0, 0, 0, 0, -1.25], 0.0),
    (Verdict.STALE, [0.77, 0, 0, 0, 0, 0], -30.0),
    (Verdict.FUTURE, [0.66, 0, 0, 0, 0, 0], +30.0),
]


def test_refused_commands_are_counted_and_never_passed_on(rig):
    rig.send(WANTED)
    assert rig.until(lambda: rig.node.gate.counts[Verdict.ACCEPTED] == 1)
    expected = {v: 0 for v in Verdict}
    expected[Verdict.ACCEPTED] = 1
    for verdict, nu, offset in REFUSED:
        expected[verdict] += 1
        rig.send(nu, offset)
        assert rig.until(lambda v=verdict: rig.node.gate.counts[v] == expected[v]), \
            f'{verdict} not counted: {rig.node.gate.counts}'
    assert rig.node.gate.counts == expected
    for g in rig.goals:
        assert np.all(np.isfinite(g))
        assert np.all(np.abs(g) <= 1.0)
        assert not np.isclose(g[0], 0.77) and not np.isclose(g[0], 0.66)


def test_goal_falls_to_zero_when_commands_stop(rig):
    rig.send(WANTED)
    assert rig.until(lambda: any(np.allclose(g, WANTED) for g in rig.goals))
    n = len(rig.goals)
    assert rig.until(lambda: len(rig.goals) > n and not np.any(rig.goals[-1]))
    assert rig.node.gate.failsafe(stamp_ns(rig.node))


def test_failsafe_ends_with_a_new_command_and_comes_back(rig):
    """A command, then silence: zero goal after `timeout`, and back on a new one."""
    wanted = [0.0, 0.0, -0.2, 0.0, 0.0, 0.1]
    for _ in range(2):
        accepted = rig.node.gate.counts[Verdict.ACCEPTED]
        n = len(rig.goals)
        rig.send(wanted)
        assert rig.until(lambda a=accepted: rig.node.gate.counts[Verdict.ACCEPTED] > a)
        assert any(np.allclose(g, wanted) for g in rig.goals[n:])  # passed on at once
        n = len(rig.goals)
        assert rig.until(lambda n=n: len(rig.goals) > n and not np.any(rig.goals[-1]))
        assert rig.node._failsafe


# -- io requests -----------------------------------------------------------------------------

def test_valid_io_requests_are_forwarded_as_they_are(rig):
    rig.io_pub.publish(io_msg('gpio_12', True))
    rig.io_pub.publish(io_msg('manipulator', 400))
    rig.io_pub.publish(io_msg('manipulator', 2.5))
    assert rig.until(lambda: len(rig.ios) == 3)
    assert [(m.name, convert.parameter_value_to_python(m.value)) for m in rig.ios] == [
        ('gpio_12', True), ('manipulator', 400), ('manipulator', 2.5)]
    assert rig.node.io_forwarded == 3


@pytest.mark.parametrize('msg', [
    io_msg('manipulator', math.nan),
    io_msg('', True),
    io_msg('lights', ParameterValue(type=ParameterType.PARAMETER_NOT_SET)),
], ids=['not finite', 'no executor', 'not set'])
def test_invalid_io_requests_are_refused_and_counted(rig, msg):
    rig.io_pub.publish(msg)
    assert rig.until(lambda: rig.node.io_rejected == 1)
    assert rig.node.io_forwarded == 0 and rig.ios == []


def test_the_failsafe_never_emits_io(rig):
    rig.io_pub.publish(io_msg('gpio_12', True))
    assert rig.until(lambda: len(rig.ios) == 1)
    n = len(rig.goals)
    assert rig.until(lambda: len(rig.goals) >= n + 3)  # failsafe active, goals keep coming
    assert not np.any(rig.goals[-1])
    assert len(rig.ios) == 1


# -- failsafe latency on a controlled clock ------------------------------------------------------

class ClockedSurface:
    """The receiver on ROS time (``use_sim_time``) driven by ``/clock`` from the test.

    Its goal timer and its gate then see only the time the test publishes: the failsafe's
    latency is measured in that time, whatever the machine's load.
    """

    TIMEOUT_NS = 200_000_000  # the receiver's timeout [ns]
    PERIOD_NS = 100_000_000   # 1 / rate: the profile's 10 Hz

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, CommandReceiverNode(
            node_name='command_receiver', context=context, parameter_overrides=[
                Parameter('use_sim_time', value=True),
                Parameter('timeout', value=self.TIMEOUT_NS * 1e-9),
                Parameter('rate', value=1e9 / self.PERIOD_NS)]))
        self.probe = surface = probe(context, executor, 'surface')
        self.clock_pub = surface.create_publisher(Clock, '/clock', 10)
        self.twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                                  topics.SURFACE_TWIST.qos)
        self.goals: list[tuple[int, np.ndarray]] = []  # (stamp [ns], goal)
        surface.create_topic_subscription(
            topics.TRAJECTORY_REQUEST,
            lambda m: self.goals.append((convert.stamp_to_ns(m.header.stamp),
                                         convert.twist_to_nu(m.twist))))
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.twist_pub.get_subscription_count() > 0
                    and self.clock_pub.get_subscription_count() > 0, TIMEOUT)
        self.ns = 0

    def set_time(self, ns: int) -> None:
        """Publish ``ns`` on /clock, wait until the receiver's clock reads it, then run what
        fell due (its goal timer) before returning.
        """
        self.ns = ns
        msg = Clock()
        convert.ns_to_stamp(ns, msg.clock)
        self.clock_pub.publish(msg)
        assert self.spin(self.executor, lambda: stamp_ns(self.node) == ns, TIMEOUT), \
            f'the receiver never read /clock = {ns}'
        for _ in range(5):  # a due timer is ready now; 5 rounds drain it and the report
            self.executor.spin_once(timeout_sec=0.0)

    def send(self, nu: list[float]) -> None:
        accepted = self.node.gate.counts[Verdict.ACCEPTED]
        msg = TwistStamped()
        convert.ns_to_stamp(self.ns, msg.header.stamp)  # stamped now, on the test's clock
        msg.header.frame_id = topics.BODY_FRAME
        convert.set_twist(msg.twist, nu)
        self.twist_pub.publish(msg)
        assert self.spin(self.executor,
                         lambda: self.node.gate.counts[Verdict.ACCEPTED] == accepted + 1, TIMEOUT)

    def timer_stamps(self, start_ns: int) -> list[int]:
        return [t for t, _ in self.goals if t >= start_ns]


def test_failsafe_latency_on_a_controlled_clock(context, executor, spin):
    """Goal held until ``timeout`` after the last accepted command, zero within one period.

    Bound: the gate holds through ``timeout`` (inclusive) and the goal timer publishes every
    ``P``; so the goal published 5 ms before the deadline is the command, and the first one
    after the deadline, at most ``P`` later, is zero. Time moves in 5 ms steps of /clock.
    """
    rig = ClockedSurface(context, executor, spin)
    step, t0 = 5_000_000, 1_000 * 1_000_000_000
    rig.set_time(t0)
    for k in range(1, 41):  # 200 ms without a command: the timer shows its phase
        rig.set_time(t0 + k * step)
    ticks = rig.timer_stamps(t0 + step)
    assert len(ticks) == 2 and ticks[1] - ticks[0] == rig.PERIOD_NS, ticks  # on ROS time
    assert all(not np.any(g) for _, g in rig.goals)  # zero before any command

    # Accept a command 5 ms after a tick: ticks then fall 5 ms before timeout and 95 ms after.
    t_accept = ticks[-1] + 3 * rig.PERIOD_NS + step
    deadline = t_accept + rig.TIMEOUT_NS
    while rig.ns < t_accept:
        rig.set_time(rig.ns + step)
    n = len(rig.goals)
    rig.send(WANTED)
    while rig.ns < deadline + 2 * rig.PERIOD_NS:
        rig.set_time(rig.ns + step)
    after = rig.goals[n:]
    held = [(t, g) for t, g in after if t <= deadline]
    late = [(t, g) for t, g in after if t > deadline]
    assert held[0][0] == t_accept and np.allclose(held[0][1], WANTED)  # passed on at once
    assert [t - t_accept for t, _ in held[1:]] == [
        rig.PERIOD_NS - step, rig.TIMEOUT_NS - step]
    assert all(np.allclose(g, WANTED) for _, g in held), held
    assert late and late[0][0] - deadline <= rig.PERIOD_NS, (late[0][0] - deadline)
    assert all(not np.any(g) for _, g in late), late
    assert rig.node._failsafe


# -- ordering, frame and the single-source rule ---------------------------------------------

def frame_twist(node: Any, nu: list[float], frame_id: str, offset_s: float = 0.0) -> Any:
    msg = twist(node, nu, offset_s)
    msg.header.frame_id = frame_id
    return msg


def test_an_out_of_order_command_is_refused_and_counted(rig):
    rig.send(WANTED)
    assert rig.until(lambda: rig.node.gate.counts[Verdict.ACCEPTED] == 1)
    rig.send([0.9, 0, 0, 0, 0, 0], offset_s=-0.2)  # older than the accepted one
    assert rig.until(lambda: rig.node.gate.counts[Verdict.NOT_NEWER] == 1)
    assert np.allclose(rig.node.gate.goal, WANTED)


@pytest.mark.parametrize('frame_id, accepted', [
    (topics.BODY_FRAME, True), ('', True), ('odom', False), ('map', False)])
def test_a_command_in_another_frame_is_refused_and_counted(rig, frame_id, accepted):
    """A twist in 'odom' must not be executed as if in base_link (it once was)."""
    rig.twist_pub.publish(frame_twist(rig.probe, WANTED, frame_id))
    if accepted:
        assert rig.until(lambda: rig.node.gate.counts[Verdict.ACCEPTED] == 1)
    else:
        assert rig.until(lambda: rig.node.gate.counts[Verdict.WRONG_FRAME] == 1)
        assert not np.any(rig.node.gate.goal)


class Reports:
    def __init__(self, node: Any) -> None:
        self.node = node
        self.all: list[tuple[int, str, dict[str, Any]]] = []
        node.publish_diagnostics = lambda *a: self.all.append(a)


def test_two_twist_publishers_are_refused_and_named(context, executor, spin):
    """An outside publisher alternating with the scripted one once made the goal
    alternate. Now while two publish, no command is executed, the goal is zero and
    /diagnostics says ERROR naming both."""
    rig = Surface(context, executor, spin)
    reports = Reports(rig.node)
    intruder = probe(context, executor, 'intruder')
    other = intruder.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                      topics.SURFACE_TWIST.qos)
    assert rig.until(lambda: other.get_subscription_count() > 0)
    assert rig.until(lambda: rig.node.twist_guard._sub.get_publisher_count() == 2)
    n = len(rig.goals)
    for k in range(6):
        if k % 2:
            other.publish(twist(intruder, [-0.5, 0, 0, 0, 0, 0]))
        else:
            rig.send(WANTED)
        assert rig.until(lambda k=k: rig.node.gate.counts[Verdict.CONTESTED] == k + 1)
    assert rig.node.gate.counts[Verdict.ACCEPTED] == 0
    assert all(not np.any(g) for g in rig.goals[n:])
    rig.node._report()
    level, message, values = reports.all[-1]
    assert level == 2, message
    assert '/surface' in message and '/intruder' in message, message
    assert values['contested'] == 6
    # One publisher left: commands are taken again.
    intruder.destroy_publisher(other)
    assert rig.until(lambda: rig.node.twist_guard._sub.get_publisher_count() == 1)
    rig.send(WANTED)
    assert rig.until(lambda: rig.node.gate.counts[Verdict.ACCEPTED] == 1)


def test_two_io_publishers_are_refused(context, executor, spin):
    rig = Surface(context, executor, spin)
    intruder = probe(context, executor, 'intruder')
    other = intruder.create_publisher(ParameterMsg, topics.SURFACE_IO.name,
                                      topics.SURFACE_IO.qos)
    assert rig.until(lambda: rig.node.io_guard._sub.get_publisher_count() == 2)
    rig.io_pub.publish(io_msg('gpio_12', True))
    other.publish(io_msg('gpio_12', False))
    assert rig.until(lambda: rig.node.io_contested == 2)
    assert rig.ios == [] and rig.node.io_forwarded == 0


# -- timeout against the measured command rate (valid but harmful) ---------------------------

def test_a_timeout_shorter_than_two_command_periods_is_refused_live(context, executor, spin):
    """A timeout under the surface's command period drops the goal to zero between every two
    commands (the vehicle stutters). Refused live with the measured period; ok once longer."""
    from support.nodes import param_client, set_param
    rig = ClockedSurface(context, executor, spin)
    t = 1_000 * 1_000_000_000
    for k in range(12):  # 10 Hz commands
        rig.set_time(t + k * 100_000_000)
        rig.send(WANTED)
    client = param_client(executor, spin, context, 'command_receiver')
    result = set_param(executor, spin, client, 'timeout', 0.15)
    assert not result.successful
    assert 'timeout' in result.reason and 'period' in result.reason, result.reason
    assert set_param(executor, spin, client, 'timeout', 0.25).successful


def test_a_start_timeout_too_short_for_the_commands_is_reported(context, executor, spin):
    rig = ClockedSurface(context, executor, spin)
    reports = Reports(rig.node)
    rig.node.gate.settings = rig.node.gate.settings.__class__(
        **{**rig.node.gate.settings.__dict__, 'timeout': 0.05})
    t = 1_000 * 1_000_000_000
    for k in range(12):
        rig.set_time(t + k * 100_000_000)
        rig.send(WANTED)
    rig.node._report()
    level, message, _ = reports.all[-1]
    assert level >= 1 and 'timeout' in message and 'period' in message, message


def test_goal_stamps_strictly_increase_at_a_standing_clock(context, executor, spin):
    """The timer and a command at one simulated instant both publish the goal: the second is
    stamped 1 ns later, so the controller's time policy takes it (it refuses repeats)."""
    rig = ClockedSurface(context, executor, spin)
    rig.set_time(1_000 * 1_000_000_000)
    n = len(rig.goals)
    rig.node._publish_goal()
    rig.send(WANTED)
    stamps = [t for t, _ in rig.goals[n:]]
    assert len(stamps) >= 2 and all(b > a for a, b in zip(stamps, stamps[1:])), stamps
    assert np.allclose(rig.goals[-1][1], WANTED)


def test_goal_stamps_start_over_when_the_clock_goes_back(context, executor, spin):
    """A restarted simulation: the goal is stamped on the new clock, not 1 ns after an old
    stamp that every node on the new clock would refuse as from the future."""
    rig = ClockedSurface(context, executor, spin)
    rig.set_time(1_000 * 1_000_000_000)
    rig.node._publish_goal()
    rig.set_time(10 * 1_000_000_000)
    rig.node._publish_goal()
    assert rig.goals[-1][0] == 10 * 1_000_000_000
