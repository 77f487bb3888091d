"""Node tests: command receiver node."""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, add, probe
from support.rov import io_msg, stamp_ns, twist

from enbarr_core.control.command_gate import Verdict
from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_command_receiver_gates_commands_failsafe_and_io(context, executor, spin):
    node = add(executor, CommandReceiverNode(
        node_name='command_receiver', context=context, parameter_overrides=[
            Parameter('timeout', value=0.2), Parameter('max_age', value=5.0),
            Parameter('max_linear', value=1.0)]))
    surface = probe(context, executor, 'surface')
    twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                         topics.SURFACE_TWIST.qos)
    io_pub = surface.create_publisher(ParameterMsg, topics.SURFACE_IO.name,
                                      topics.SURFACE_IO.qos)
    goals: list[np.ndarray] = []
    ios: list[ParameterMsg] = []
    surface.create_topic_subscription(
        topics.TRAJECTORY_REQUEST, lambda m: goals.append(convert.twist_to_nu(m.twist)))
    surface.create_topic_subscription(topics.IO_REQUEST, ios.append)
    LinkBus.of(context).connect()
    # The receiver's goal publisher is in this process: the probe is fed by direct calls.
    assert all(s.local for s in surface._links)
    assert spin(executor, lambda: twist_pub.get_subscription_count() > 0
                and io_pub.get_subscription_count() > 0, TIMEOUT)

    # Before any command: failsafe, a zero goal is republished.
    assert spin(executor, lambda: len(goals) >= 2, TIMEOUT)
    assert not np.any(goals[-1])

    # A fresh valid command is passed on as the goal.
    wanted = [0.3, -0.2, 0.1, 0.0, 0.05, -0.4]
    twist_pub.publish(twist(surface, wanted))
    assert spin(executor, lambda: any(np.allclose(g, wanted) for g in goals), TIMEOUT)
    assert node.gate.counts[Verdict.ACCEPTED] == 1

    # Refused commands: counted per verdict and never passed on.
    refused = [
        (Verdict.NON_FINITE, twist(surface, [math.nan, 0, 0, 0, 0, 0])),
        (Verdict.NON_FINITE, twist(surface, [0, 0, 0, 0, 0, math.inf])),
        (Verdict.OUT_OF_RANGE, twist(surface, [1.5, 0, 0, 0, 0, 0])),
        (Verdict.OUT_OF_RANGE, twist(surface, [0, 0, 0, 0, 0, -1.25])),
        (Verdict.STALE, twist(surface, [0.77, 0, 0, 0, 0, 0], offset_s=-30.0)),
        (Verdict.FUTURE, twist(surface, [0.66, 0, 0, 0, 0, 0], offset_s=+30.0)),
    ]
    expected = {v: 0 for v in Verdict}
    expected[Verdict.ACCEPTED] = 1
    for verdict, msg in refused:
        expected[verdict] += 1
        twist_pub.publish(msg)
        assert spin(executor, lambda v=verdict: node.gate.counts[v] == expected[v], TIMEOUT), \
            f'{verdict} not counted: {node.gate.counts}'
    assert node.gate.counts == expected
    for g in goals:
        assert np.all(np.isfinite(g))
        assert np.all(np.abs(g) <= 1.0)
        assert not np.isclose(g[0], 0.77) and not np.isclose(g[0], 0.66)

    # No accepted command for `timeout`: the goal falls to zero by itself.
    n = len(goals)
    assert spin(executor, lambda: len(goals) > n and not np.any(goals[-1]), TIMEOUT)
    assert node.gate.failsafe(stamp_ns(node))

    # IO: valid requests forwarded as they are, invalid ones refused and counted.
    io_pub.publish(io_msg('gpio_12', True))
    io_pub.publish(io_msg('manipulator', 400))
    io_pub.publish(io_msg('manipulator', 2.5))
    assert spin(executor, lambda: len(ios) == 3, TIMEOUT)
    assert [(m.name, convert.parameter_value_to_python(m.value)) for m in ios] == [
        ('gpio_12', True), ('manipulator', 400), ('manipulator', 2.5)]
    io_pub.publish(io_msg('manipulator', math.nan))
    assert spin(executor, lambda: node.io_rejected == 1, TIMEOUT)
    io_pub.publish(io_msg('', True))
    assert spin(executor, lambda: node.io_rejected == 2, TIMEOUT)
    io_pub.publish(io_msg('lights', ParameterValue(type=ParameterType.PARAMETER_NOT_SET)))
    assert spin(executor, lambda: node.io_rejected == 3, TIMEOUT)
    assert node.io_forwarded == 3

    # The failsafe (still active, goals keep coming) never emits io.
    n = len(goals)
    assert spin(executor, lambda: len(goals) >= n + 3, TIMEOUT)
    assert not np.any(goals[-1])
    assert len(ios) == 3


def test_command_receiver_failsafe_after_commands_stop(context, executor, spin):
    """A stream of commands, then silence: zero goal after `timeout`, and back on a new one."""
    node = add(executor, CommandReceiverNode(
        node_name='command_receiver', context=context, parameter_overrides=[
            Parameter('timeout', value=0.2), Parameter('max_age', value=5.0)]))
    surface = probe(context, executor, 'surface')
    twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                         topics.SURFACE_TWIST.qos)
    goals: list[np.ndarray] = []
    surface.create_topic_subscription(
        topics.TRAJECTORY_REQUEST, lambda m: goals.append(convert.twist_to_nu(m.twist)))
    # A plain ROS subscription (as `ros2 topic echo` would make) gets the link topic via DDS.
    echoed: list[TwistStamped] = []
    surface.create_subscription(TwistStamped, topics.TRAJECTORY_REQUEST.name, echoed.append,
                                topics.TRAJECTORY_REQUEST.qos)
    LinkBus.of(context).connect()
    assert spin(executor, lambda: twist_pub.get_subscription_count() > 0, TIMEOUT)
    assert spin(executor, lambda: len(echoed) >= 2, TIMEOUT)
    assert echoed[-1].header.frame_id == topics.BODY_FRAME
    wanted = [0.0, 0.0, -0.2, 0.0, 0.0, 0.1]
    for round_ in range(2):
        accepted = node.gate.counts[Verdict.ACCEPTED]
        n = len(goals)
        twist_pub.publish(twist(surface, wanted))
        assert spin(executor, lambda a=accepted: node.gate.counts[Verdict.ACCEPTED] > a,
                    TIMEOUT)
        assert any(np.allclose(g, wanted) for g in goals[n:])  # passed on at once
        n = len(goals)
        assert spin(executor, lambda n=n: len(goals) > n and not np.any(goals[-1]), TIMEOUT)
        assert node._failsafe
