"""Node tests: sim thrusters."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from support.nodes import TIMEOUT, add, probe
from support.rov import layout_overrides, sim_parameters

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.thrusters.sim import SimThrustersNode

NAMES = sim_parameters()['thruster_names']
CMD = [0.5, -0.5, 1.0, -1.0, 0.0, 0.25, -0.25, 0.1]


class Controller:
    """The thrusters (no motor lag, 0.1 s watchdog) and a controller commanding them."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.node = add(executor, SimThrustersNode(
            node_name='thruster_control', context=context,
            parameter_overrides=layout_overrides(time_constant=0.0, command_timeout=0.1)))
        self.probe = p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.outputs: list[JointState] = []
        self.thrusts: list[JointState] = []
        p.create_topic_subscription(topics.THRUSTER_OUTPUT, self.outputs.append)
        p.create_topic_subscription(topics.SIM_THRUST, self.thrusts.append)
        LinkBus.of(context).connect()

    def command(self, efforts: list[float], names: list[str] = NAMES) -> None:
        msg = JointState(name=list(names), effort=[float(e) for e in efforts])
        msg.header.stamp = self.probe.get_clock().now().to_msg()
        self.pub.publish(msg)


@pytest.fixture
def rig(context, executor) -> Controller:
    return Controller(context, executor)


def test_starts_neutral_with_the_profile_names(rig):
    assert rig.node.names == NAMES and rig.node.neutral


def test_command_becomes_output_and_thrust(rig):
    rig.command(CMD)
    assert len(rig.outputs) == 1 and len(rig.thrusts) == 1
    assert rig.outputs[-1].name == NAMES and rig.thrusts[-1].name == NAMES
    assert rig.outputs[-1].effort.tolist() == pytest.approx(CMD)
    expected = [c * (51.5 if c >= 0 else 40.2) for c in CMD]
    assert rig.thrusts[-1].effort.tolist() == pytest.approx(expected)
    assert not rig.node.neutral


def test_commands_go_by_name_and_missing_thrusters_are_zero(rig):
    rig.command([0.2, -0.3], ['vert_rear_left', 'front_right'])
    assert rig.outputs[-1].effort.tolist() == pytest.approx([-0.3, 0, 0, 0, 0, 0, 0, 0.2])
    assert rig.thrusts[-1].effort.tolist() == pytest.approx(
        [-0.3 * 40.2, 0, 0, 0, 0, 0, 0, 0.2 * 51.5])


def test_bad_commands_are_refused_and_counted(rig):
    # Refused: NaN, Inf, an unknown name, names/efforts of different lengths.
    rig.command(CMD)
    n, before = len(rig.outputs), rig.node.command.copy()
    rig.command([math.nan] + CMD[1:])
    rig.command([math.inf] + CMD[1:])
    rig.command([0.1], ['bow_thruster'])
    rig.pub.publish(JointState(name=NAMES, effort=[0.1, 0.2]))
    assert rig.node.refused == 4
    assert len(rig.outputs) == n and len(rig.thrusts) == n
    assert rig.node.command.tolist() == before.tolist()


def test_commands_beyond_one_are_clipped_and_counted(rig):
    rig.command([1.5, -2.0, 0, 0, 0, 0, 0, 0])
    assert rig.node.clipped == 1
    assert rig.outputs[-1].effort.tolist() == pytest.approx([1.0, -1.0, 0, 0, 0, 0, 0, 0])
    assert rig.thrusts[-1].effort.tolist() == pytest.approx([51.5, -40.2, 0, 0, 0, 0, 0, 0])


def test_watchdog_goes_neutral_once_when_commands_stop(executor, spin, rig):
    rig.command(CMD)
    n = len(rig.outputs)
    assert rig.node.timeouts == 0
    assert spin(executor, lambda: rig.node.timeouts == 1, TIMEOUT)
    assert len(rig.outputs) == n + 1
    assert not np.any(rig.outputs[-1].effort) and not np.any(rig.thrusts[-1].effort)
    assert rig.node.neutral
    ticks = [0]
    rig.node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert rig.node.timeouts == 1 and len(rig.outputs) == n + 1  # neutral is not repeated


def test_safe_state_zeroes_every_thruster_at_once(rig):
    rig.command(CMD)
    assert np.any(rig.outputs[-1].effort)
    rig.node.safe_state()
    assert rig.outputs[-1].name == NAMES
    assert not np.any(rig.outputs[-1].effort) and not np.any(rig.thrusts[-1].effort)
    assert rig.node.neutral


def test_time_constant_ramps_thrust(context, executor):
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


def test_needs_thruster_names(context):
    with pytest.raises(ConfigurationError, match='thruster_names'):
        SimThrustersNode(node_name='thruster_control', context=context)
