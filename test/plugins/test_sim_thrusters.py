"""Node tests: sim thrusters."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from support.nodes import TIMEOUT, add, probe
from support.rov import layout_overrides, sim_parameters

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.thrusters.sim import SimThrustersNode


def test_sim_thrusters_output_watchdog_refusals_and_safe_state(context, executor, spin):
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=0.0, command_timeout=0.1)))
    names = sim_parameters()['thruster_names']
    assert node.names == names and node.neutral
    p = probe(context, executor, 'controller')
    cmd_pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
    outputs: list[JointState] = []
    thrusts: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_OUTPUT, outputs.append)
    p.create_topic_subscription(topics.SIM_THRUST, thrusts.append)
    LinkBus.of(context).connect()

    def command(efforts: list[float], names_: list[str] = names) -> None:
        msg = JointState(name=list(names_), effort=[float(e) for e in efforts])
        msg.header.stamp = p.get_clock().now().to_msg()
        cmd_pub.publish(msg)

    cmd = [0.5, -0.5, 1.0, -1.0, 0.0, 0.25, -0.25, 0.1]
    command(cmd)
    assert len(outputs) == 1 and len(thrusts) == 1
    assert outputs[-1].name == names and thrusts[-1].name == names
    assert outputs[-1].effort.tolist() == pytest.approx(cmd)
    expected = [c * (51.5 if c >= 0 else 40.2) for c in cmd]
    assert thrusts[-1].effort.tolist() == pytest.approx(expected)
    assert not node.neutral

    # Commands in another order (by name), partial commands: missing thrusters are zero.
    command([0.2, -0.3], ['vert_rear_left', 'front_right'])
    assert outputs[-1].effort.tolist() == pytest.approx([-0.3, 0, 0, 0, 0, 0, 0, 0.2])
    assert thrusts[-1].effort.tolist() == pytest.approx(
        [-0.3 * 40.2, 0, 0, 0, 0, 0, 0, 0.2 * 51.5])

    # Refused: NaN, Inf, an unknown name, names/efforts of different lengths.
    command(cmd)
    n, before = len(outputs), node.command.copy()
    command([math.nan] + cmd[1:])
    command([math.inf] + cmd[1:])
    command([0.1], ['bow_thruster'])
    bad = JointState(name=names, effort=[0.1, 0.2])
    cmd_pub.publish(bad)
    assert node.refused == 4
    assert len(outputs) == n and len(thrusts) == n
    assert node.command.tolist() == before.tolist()

    # |cmd| > 1: clipped to the limits and counted.
    command([1.5, -2.0, 0, 0, 0, 0, 0, 0])
    assert node.clipped == 1
    assert outputs[-1].effort.tolist() == pytest.approx([1.0, -1.0, 0, 0, 0, 0, 0, 0])
    assert thrusts[-1].effort.tolist() == pytest.approx([51.5, -40.2, 0, 0, 0, 0, 0, 0])

    # Commands stop: the watchdog goes neutral by itself, once.
    n = len(outputs)
    assert node.timeouts == 0
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(outputs) == n + 1
    assert not np.any(outputs[-1].effort) and not np.any(thrusts[-1].effort)
    assert node.neutral
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert node.timeouts == 1 and len(outputs) == n + 1  # neutral is not repeated

    # safe_state(): all zeros at once.
    command(cmd)
    assert np.any(outputs[-1].effort)
    node.safe_state()
    assert outputs[-1].name == names
    assert not np.any(outputs[-1].effort) and not np.any(thrusts[-1].effort)
    assert node.neutral


def test_sim_thrusters_time_constant_ramps_thrust(context, executor):
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=5.0, command_timeout=10.0)))
    names = node.names
    msg = JointState(name=names, effort=[1.0] * len(names))
    LinkBus.of(context).connect()
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
    pub.publish(msg)        # from neutral: no lag on the first command
    assert node.thrust == pytest.approx([51.5] * len(names))
    pub.publish(JointState(name=names, effort=[-1.0] * len(names)))
    assert np.all(node.thrust > -40.2) and np.all(node.thrust < 51.5)  # lags


def test_sim_thrusters_needs_thruster_names(context):
    with pytest.raises(ConfigurationError, match='thruster_names'):
        SimThrustersNode(node_name='thruster_control', context=context)
