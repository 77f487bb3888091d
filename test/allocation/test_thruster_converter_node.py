"""Node tests: thruster converter node."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from support.nodes import add, probe
from support.rov import layout_overrides, overrides, sim_thrusters

from enbarr_core.allocation.fixed import allocation_matrix
from enbarr_core.allocation.thruster_converter_node import ThrusterConverterNode
from enbarr_core.framework.errors import AllocationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_thruster_converter_refuses_layout_that_cannot_yaw(context):
    # Horizontal thrusters on lines through the centre: no moment about z from any of them.
    layout = {
        'surge_fwd': ([0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
        'surge_aft': ([-0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
        'sway_left': ([0.0, 0.2, 0.0], [0.0, 1.0, 0.0]),
        'sway_right': ([0.0, -0.2, 0.0], [0.0, -1.0, 0.0]),
        'v_fl': ([0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_fr': ([0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_rl': ([-0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_rr': ([-0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
    }
    values: dict[str, Any] = {'thruster_names': list(layout)}
    for n, (pos, d) in layout.items():
        values.update({f'thrusters.{n}.position': pos, f'thrusters.{n}.direction': d,
                       f'thrusters.{n}.max_forward': 40.0, f'thrusters.{n}.max_reverse': 30.0})
    with pytest.raises(AllocationError, match='yaw') as info:
        ThrusterConverterNode(node_name='thruster_converter', context=context,
                              parameter_overrides=overrides(values))
    message = str(info.value)
    assert 'thruster_converter' in message
    for dof in ('surge', 'sway', 'heave'):
        assert f'produce {dof}' not in message
    # Without yaw in controlled_dofs the same layout is accepted.
    node = ThrusterConverterNode(
        node_name='thruster_converter_5dof', context=context, parameter_overrides=overrides(
            {**values, 'controlled_dofs': ['surge', 'sway', 'heave', 'roll', 'pitch']}))
    node.destroy_node()


def test_thruster_converter_allocates_wrench(context, executor):
    node = add(executor, ThrusterConverterNode(
        node_name='thruster_converter', context=context, parameter_overrides=layout_overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_COMMANDS, commands.append)
    LinkBus.of(context).connect()
    thrusters = sim_thrusters()
    names = [t.name for t in thrusters]
    B = allocation_matrix(thrusters)
    fwd = np.array([t.max_forward for t in thrusters])
    rev = np.array([t.max_reverse for t in thrusters])

    def send(tau: list[float], ns: int) -> JointState:
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench(w.wrench, tau)
        n = len(commands)
        pub.publish(w)
        assert len(commands) == n + 1
        return commands[-1]

    tau = np.array([10.0, -5.0, 8.0, 0.5, -0.3, 1.0])
    out = send(tau.tolist(), 1_234_567_890_123)
    assert list(out.name) == names
    assert convert.stamp_to_ns(out.header.stamp) == 1_234_567_890_123
    u = np.array(out.effort)
    assert np.all(np.abs(u) <= 1.0) and np.any(u)
    thrust = np.where(u >= 0.0, u * fwd, u * rev)
    assert B @ thrust == pytest.approx(tau, abs=1e-6)
    assert not node.result.saturated and node.saturated == 0

    # Far beyond the thrusters: every command within [-1, 1], one at the limit, direction kept.
    big = np.array([500.0, 0.0, 300.0, 0.0, 0.0, 20.0])
    u = np.array(send(big.tolist(), 1_234_567_890_124).effort)
    assert np.all(np.abs(u) <= 1.0 + 1e-12) and np.max(np.abs(u)) == pytest.approx(1.0)
    delivered = B @ np.where(u >= 0.0, u * fwd, u * rev)
    assert node.saturated == 1
    assert np.cross(delivered[:3], big[:3]) == pytest.approx(np.zeros(3), abs=1e-6)
    assert delivered[0] / big[0] == pytest.approx(delivered[5] / big[5])

    # A non-finite wrench is refused, nothing published.
    n = len(commands)
    w = WrenchStamped()
    w.wrench.force.x = math.nan
    pub.publish(w)
    assert node.rejected == 1 and len(commands) == n
