"""Node tests: thruster converter node."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from support.nodes import add, probe
from support.saucer import SimClock
from support.rov import layout_overrides, overrides, sim_parameters, sim_thrusters

from enbarr_core.allocation.fixed import allocation_matrix
from enbarr_core.allocation.thruster_converter_node import ThrusterConverterNode
from enbarr_core.framework.errors import AllocationError, ConfigurationError
from enbarr_core.framework.stamps import StampVerdict
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


# Horizontal thrusters on lines through the centre: no moment about z from any of them.
NO_YAW_LAYOUT = {
    'surge_fwd': ([0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
    'surge_aft': ([-0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
    'sway_left': ([0.0, 0.2, 0.0], [0.0, 1.0, 0.0]),
    'sway_right': ([0.0, -0.2, 0.0], [0.0, -1.0, 0.0]),
    'v_fl': ([0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
    'v_fr': ([0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
    'v_rl': ([-0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
    'v_rr': ([-0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
}


def no_yaw_values() -> dict[str, Any]:
    values: dict[str, Any] = {'thruster_names': list(NO_YAW_LAYOUT)}
    for n, (pos, d) in NO_YAW_LAYOUT.items():
        values.update({f'thrusters.{n}.position': pos, f'thrusters.{n}.direction': d,
                       f'thrusters.{n}.max_forward': 40.0, f'thrusters.{n}.max_reverse': 30.0})
    return values


def test_thruster_converter_refuses_layout_that_cannot_yaw(context):
    with pytest.raises(AllocationError, match='yaw') as info:
        ThrusterConverterNode(node_name='thruster_converter', context=context,
                              parameter_overrides=overrides(no_yaw_values()))
    message = str(info.value)
    assert 'thruster_converter' in message
    for dof in ('surge', 'sway', 'heave'):
        assert f'produce {dof}' not in message


def test_thruster_converter_accepts_that_layout_without_yaw(context):
    # Without yaw in controlled_dofs the same layout is accepted.
    node = ThrusterConverterNode(
        node_name='thruster_converter_5dof', context=context, parameter_overrides=overrides(
            {**no_yaw_values(), 'controlled_dofs': ['surge', 'sway', 'heave', 'roll', 'pitch']}))
    assert node.settings.controlled_dofs == (0, 1, 2, 3, 4)
    node.destroy_node()


def test_thruster_converter_refuses_unknown_dof(context):
    with pytest.raises(ConfigurationError, match="controlled_dofs: unknown \\['wobble'\\]"):
        ThrusterConverterNode(node_name='thruster_converter', context=context,
                              parameter_overrides=layout_overrides(
                                  controlled_dofs=['surge', 'wobble']))


@pytest.mark.parametrize('missing', ['thrusters.front_right.direction',
                                     'thrusters.rear_left.max_reverse'])
def test_thruster_converter_needs_every_thruster_value(context, missing):
    values = {k: v for k, v in sim_parameters().items() if k != missing}
    with pytest.raises(ConfigurationError, match=f"parameter '{missing}' is not set") as info:
        ThrusterConverterNode(node_name='thruster_converter', context=context,
                              parameter_overrides=overrides(values))
    assert info.value.parameter == missing


@dataclass
class Rig:
    node: ThrusterConverterNode
    pub: Any
    commands: list[JointState]

    def send(self, tau: list[float], ns: int) -> JointState:
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench(w.wrench, tau)
        n = len(self.commands)
        self.pub.publish(w)
        assert len(self.commands) == n + 1
        return self.commands[-1]


@pytest.fixture
def rig(context, executor) -> Rig:
    node = add(executor, ThrusterConverterNode(
        node_name='thruster_converter', context=context, parameter_overrides=layout_overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_COMMANDS, commands.append)
    LinkBus.of(context).connect()
    return Rig(node, pub, commands)


T0 = 1_000 * 1_000_000_000  # a clock reading [ns]
THRUSTERS = sim_thrusters()
B = allocation_matrix(THRUSTERS)
FWD = np.array([t.max_forward for t in THRUSTERS])
REV = np.array([t.max_reverse for t in THRUSTERS])
TAU = np.array([10.0, -5.0, 8.0, 0.5, -0.3, 1.0])


def test_thruster_converter_keeps_names_and_stamp(rig):
    out = rig.send(TAU.tolist(), 1_234_567_890_123)
    assert list(out.name) == [t.name for t in THRUSTERS]
    assert convert.stamp_to_ns(out.header.stamp) == 1_234_567_890_123


def test_thruster_converter_allocates_wrench(rig):
    u = np.array(rig.send(TAU.tolist(), 1_234_567_890_123).effort)
    assert np.all(np.abs(u) <= 1.0) and np.any(u)
    thrust = np.where(u >= 0.0, u * FWD, u * REV)
    assert B @ thrust == pytest.approx(TAU, abs=1e-6)
    assert not rig.node.result.saturated and rig.node.saturated == 0


def test_thruster_converter_saturates_along_the_direction(rig):
    # Far beyond the thrusters: every command within [-1, 1], one at the limit, direction kept.
    big = np.array([500.0, 0.0, 300.0, 0.0, 0.0, 20.0])
    u = np.array(rig.send(big.tolist(), 1_234_567_890_124).effort)
    assert np.all(np.abs(u) <= 1.0 + 1e-12) and np.max(np.abs(u)) == pytest.approx(1.0)
    delivered = B @ np.where(u >= 0.0, u * FWD, u * REV)
    assert rig.node.saturated == 1
    assert np.cross(delivered[:3], big[:3]) == pytest.approx(np.zeros(3), abs=1e-6)
    assert delivered[0] / big[0] == pytest.approx(delivered[5] / big[5])


def test_thruster_converter_refuses_non_finite_wrench(rig):
    # A non-finite wrench is refused, nothing published.
    w = WrenchStamped()
    w.wrench.force.x = math.nan
    rig.pub.publish(w)
    assert rig.node.rejected == 1 and len(rig.commands) == 0


# -- the time policy ------------------------------------------------------------------------

def test_force_commands_stamped_ahead_or_out_of_order_are_refused_and_counted(rig):
    """A force_command stamped 20 s ahead (another process, another clock) was allocated and
    its stamp handed on to the thrusters; an out-of-order one replaced a newer command."""
    clock = SimClock(rig.node, t0_ns=T0)
    rig.send(TAU.tolist(), clock.ns)
    reports: list[Any] = []
    rig.node.publish_diagnostics = lambda *a: reports.append(a)
    for stamp in (clock.ns + 20_000_000_000, clock.ns - 1_000_000):
        n = len(rig.commands)
        w = WrenchStamped()
        convert.ns_to_stamp(stamp, w.header.stamp)
        convert.set_wrench(w.wrench, (2 * TAU).tolist())
        rig.pub.publish(w)
        assert len(rig.commands) == n
    assert rig.node.gate.counts[StampVerdict.FUTURE] == 1
    assert rig.node.gate.counts[StampVerdict.NOT_NEWER] == 1
    clock.advance(0.01)
    rig.send(TAU.tolist(), clock.ns)  # the next good one goes through
    rig.node._report()
    level, message, values = reports[-1]
    assert level == 1 and 'force_command' in message, message
    assert values['force_command.future'] == 1 and values['force_command.not_newer'] == 1
