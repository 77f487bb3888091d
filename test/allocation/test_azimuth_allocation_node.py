"""Node tests: azimuth allocation node."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from support.nodes import add, probe
from support.saucer import (
    MAX_FORWARD, MAX_REVERSE, NAMES, POSITIONS, SERVO_LIMIT, overrides, tau_of)

from enbarr_core.allocation.azimuth_allocation_node import AzimuthAllocationNode
from enbarr_core.framework.errors import AllocationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_azimuth_allocation(context, executor):
    node = add(executor, AzimuthAllocationNode(node_name='allocation', context=context,
                                               parameter_overrides=overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    delivered: list[WrenchStamped] = []
    p.create_topic_subscription(topics.AZIMUTH_COMMANDS, commands.append)
    p.create_topic_subscription(topics.ALLOCATION_DELIVERED, delivered.append)
    LinkBus.of(context).connect()

    def send(tau: list[float], ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench_tau3(w.wrench, tau)
        n = len(commands)
        pub.publish(w)
        assert len(commands) == n + 1 and len(delivered) == n + 1
        out = commands[-1]
        assert list(out.name) == NAMES
        assert convert.stamp_to_ns(out.header.stamp) == ns
        assert convert.stamp_to_ns(delivered[-1].header.stamp) == ns
        thrust, angle = np.array(out.effort), np.array(out.position)
        assert np.all(np.abs(angle) <= SERVO_LIMIT + 1e-9)
        assert np.all(thrust <= MAX_FORWARD + 1e-12) and np.all(-thrust <= MAX_REVERSE + 1e-12)
        return thrust, angle, convert.wrench_to_tau3(delivered[-1].wrench)

    for i, tau in enumerate(([0.5, -0.3, 0.05], [-1.0, 0.0, 0.0], [0.0, 1.2, -0.1],
                             [0.0, 0.0, 0.1], [0.0, 0.0, 0.0])):
        thrust, angle, got = send(tau, 1_000_000_000 + i)
        assert got == pytest.approx(tau, abs=1e-9)
        assert tau_of(POSITIONS, thrust, angle) == pytest.approx(tau, abs=1e-9)
    assert node.infeasible == 0

    # Far beyond the azimuths: the delivered force is parallel to the request and smaller.
    huge = np.array([20.0, -10.0, 1.0])
    thrust, angle, got = send(huge.tolist(), 2_000_000_000)
    assert node.infeasible == 1
    assert np.linalg.norm(got) < np.linalg.norm(huge)
    assert got / huge == pytest.approx(np.full(3, got[0] / huge[0]), rel=1e-9)
    assert 0.0 < got[0] / huge[0] < 1.0
    assert tau_of(POSITIONS, thrust, angle) == pytest.approx(got, abs=1e-9)
    at_limit = np.isclose(thrust, MAX_FORWARD) | np.isclose(-thrust, MAX_REVERSE)
    assert at_limit.any()  # scaled until one azimuth is at its limit

    # A non-finite request is refused, nothing published.
    n = len(commands)
    w = WrenchStamped()
    w.wrench.torque.z = math.inf
    pub.publish(w)
    assert node.rejected == 1 and len(commands) == n


def test_azimuth_allocation_refuses_layout_that_cannot_yaw(context):
    centre = {f'azimuths.{n}.position': [0.0, 0.0] for n in NAMES}
    with pytest.raises(AllocationError, match='yaw') as info:
        AzimuthAllocationNode(node_name='allocation', context=context,
                              parameter_overrides=overrides(centre))
    assert 'allocation' in str(info.value)
    assert 'surge' not in str(info.value).split('cannot produce')[1].split('(')[0]
