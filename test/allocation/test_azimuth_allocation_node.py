"""Node tests: azimuth allocation node (one behaviour per test)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from support.nodes import add, probe
from support.saucer import (
    COMMON, MAX_FORWARD, MAX_REVERSE, NAMES, POSITIONS, SERVO_LIMIT, overrides, tau_of)

from enbarr_core.allocation.azimuth_allocation_node import AzimuthAllocationNode
from enbarr_core.framework.errors import AllocationError, ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


@dataclass
class Rig:
    node: AzimuthAllocationNode
    pub: Any
    commands: list[JointState]
    delivered: list[WrenchStamped]

    def send(self, tau: list[float], ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Publish tau; return the commanded thrust, angle and the delivered force."""
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench_tau3(w.wrench, tau)
        n = len(self.commands)
        self.pub.publish(w)
        assert len(self.commands) == n + 1 and len(self.delivered) == n + 1
        out = self.commands[-1]
        return (np.array(out.effort), np.array(out.position),
                convert.wrench_to_tau3(self.delivered[-1].wrench))


@pytest.fixture
def rig(context, executor) -> Rig:
    node = add(executor, AzimuthAllocationNode(node_name='allocation', context=context,
                                               parameter_overrides=overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    delivered: list[WrenchStamped] = []
    p.create_topic_subscription(topics.AZIMUTH_COMMANDS, commands.append)
    p.create_topic_subscription(topics.ALLOCATION_DELIVERED, delivered.append)
    LinkBus.of(context).connect()
    return Rig(node, pub, commands, delivered)


ATTAINABLE = ([0.5, -0.3, 0.05], [-1.0, 0.0, 0.0], [0.0, 1.2, -0.1], [0.0, 0.0, 0.1],
              [0.0, 0.0, 0.0])
HUGE = np.array([20.0, -10.0, 1.0])


def test_azimuth_allocation_keeps_names_and_stamps(rig):
    for i, tau in enumerate(ATTAINABLE + (HUGE.tolist(),)):
        ns = 1_000_000_000 + i
        rig.send(tau, ns)
        out = rig.commands[-1]
        assert list(out.name) == NAMES
        assert convert.stamp_to_ns(out.header.stamp) == ns
        assert convert.stamp_to_ns(rig.delivered[-1].header.stamp) == ns


def test_azimuth_allocation_stays_within_travel_and_thrust_limits(rig):
    for i, tau in enumerate(ATTAINABLE + (HUGE.tolist(),)):
        thrust, angle, _ = rig.send(tau, 1_000_000_000 + i)
        assert np.all(np.abs(angle) <= SERVO_LIMIT + 1e-9)
        assert np.all(thrust <= MAX_FORWARD + 1e-12) and np.all(-thrust <= MAX_REVERSE + 1e-12)


def test_azimuth_allocation_delivers_attainable_tau(rig):
    for i, tau in enumerate(ATTAINABLE):
        thrust, angle, got = rig.send(tau, 1_000_000_000 + i)
        assert got == pytest.approx(tau, abs=1e-9)
        assert tau_of(POSITIONS, thrust, angle) == pytest.approx(tau, abs=1e-9)
    assert rig.node.infeasible == 0


def test_azimuth_allocation_scales_unattainable_tau_along_its_direction(rig):
    # Far beyond the azimuths: the delivered force is parallel to the request and smaller.
    thrust, angle, got = rig.send(HUGE.tolist(), 2_000_000_000)
    assert rig.node.infeasible == 1
    assert np.linalg.norm(got) < np.linalg.norm(HUGE)
    assert got / HUGE == pytest.approx(np.full(3, got[0] / HUGE[0]), rel=1e-9)
    assert 0.0 < got[0] / HUGE[0] < 1.0
    assert tau_of(POSITIONS, thrust, angle) == pytest.approx(got, abs=1e-9)
    at_limit = np.isclose(thrust, MAX_FORWARD) | np.isclose(-thrust, MAX_REVERSE)
    assert at_limit.any()  # scaled until one azimuth is at its limit


def test_azimuth_allocation_refuses_non_finite_tau(rig):
    # A non-finite request is refused, nothing published.
    w = WrenchStamped()
    w.wrench.torque.z = math.inf
    rig.pub.publish(w)
    assert rig.node.rejected == 1 and len(rig.commands) == 0


def test_azimuth_allocation_refuses_layout_that_cannot_yaw(context):
    centre = {f'azimuths.{n}.position': [0.0, 0.0] for n in NAMES}
    with pytest.raises(AllocationError, match='yaw') as info:
        AzimuthAllocationNode(node_name='allocation', context=context,
                              parameter_overrides=overrides(centre))
    assert 'allocation' in str(info.value)
    assert 'surge' not in str(info.value).split('cannot produce')[1].split('(')[0]


@pytest.mark.parametrize('missing', ['azimuths.az_bow.angle_min', 'azimuths.az_bow.position',
                                     'azimuths.az_stbd_aft.time_constant'])
def test_azimuth_allocation_needs_every_azimuth_value(context, missing):
    # Vessel data has no default: a missing number is an error naming it.
    values = [Parameter(k, value=v) for k, v in COMMON.items() if k != missing]
    with pytest.raises(ConfigurationError, match=f"parameter '{missing}' is not set") as info:
        AzimuthAllocationNode(node_name='allocation', context=context,
                              parameter_overrides=values)
    assert info.value.parameter == missing


def test_azimuth_allocation_settings_are_typed_and_frozen(rig):
    s = rig.node.settings
    assert [a.name for a in s.azimuths] == NAMES
    assert [a.position for a in s.azimuths] == [tuple(p) for p in POSITIONS]
    with pytest.raises(AttributeError):
        s.azimuths = ()


def _force(tau: list[float], ns: int) -> WrenchStamped:
    w = WrenchStamped()
    convert.ns_to_stamp(ns, w.header.stamp)
    w.header.frame_id = topics.BODY_FRAME
    convert.set_wrench_tau3(w.wrench, tau)
    return w


def test_a_force_stamped_ahead_or_out_of_order_is_refused_and_reported(context, executor):
    # Before the time policy, one force_command stamped 20 s ahead (an outside publisher, the
    # allocation in its own process) was allocated and passed its stamp on to the PWM stage
    # and the observer.
    from support.saucer import SimClock
    node = add(executor, AzimuthAllocationNode(node_name='allocation', context=context,
                                               parameter_overrides=overrides()))
    clock = SimClock(node)
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    p.create_topic_subscription(topics.AZIMUTH_COMMANDS, commands.append)
    LinkBus.of(context).connect()
    for _ in range(10):
        pub.publish(_force([0.1, 0.0, 0.0], clock.advance(0.02)))
    pub.publish(_force([2.0, 0.0, 0.0], clock.ns + 20_000_000_000))
    pub.publish(_force([2.0, 0.0, 0.0], clock.ns - 1))
    assert len(commands) == 10, 'a force from the future or the past was allocated'
    pub.publish(_force([0.1, 0.0, 0.0], clock.advance(0.02)))
    assert len(commands) == 11
    level, message, values = node.diagnostic_status()
    assert level == 1 and 'force_command: refused 2 of 13' in message, message
    assert values['force_command.future'] == 1 and values['force_command.not_newer'] == 1
    result = node.set_parameters([Parameter('max_future', value=0.03)])[0]
    assert not result.successful and 'measured 0.02 s' in result.reason, result.reason
