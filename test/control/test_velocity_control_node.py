"""Node tests: velocity control node."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.parameter import Parameter
from support.nodes import add, get_param, param_client, probe, set_param
from support.rov import imu_sample

from enbarr_core.control.velocity_control_node import VelocityControlNode
from enbarr_core.framework import registry
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

KP = [20.0, 20.0, 20.0, 4.0, 4.0, 4.0]


def test_default_node_name_is_the_registry_name():
    default = inspect.signature(VelocityControlNode).parameters['node_name'].default
    assert registry.resolve(default) is VelocityControlNode


class Loop:
    """The loop fed by hand: a surge goal, IMU samples with a yaw rate error of -0.5 rad/s."""

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, VelocityControlNode(context=context, parameter_overrides=[
            Parameter('ki', value=[0.0] * 6), Parameter('goal_timeout', value=60.0)]))
        feeder = probe(context, executor, 'feeder')
        self.imu_pub = feeder.create_topic_publisher(topics.IMU)
        goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.taus: list[np.ndarray] = []
        self.stamps: list[int] = []
        feeder.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        LinkBus.of(context).connect()
        self.client = param_client(executor, spin, context, 'velocity_control')
        goal = TwistStamped()
        goal.twist.linear.x = 0.2  # surge is not measured: feed-forward only
        goal_pub.publish(goal)
        self.t = 1_000_000_000

    def _on_tau(self, msg: WrenchStamped) -> None:
        self.taus.append(convert.wrench_to_tau(msg.wrench))
        self.stamps.append(convert.stamp_to_ns(msg.header.stamp))

    def sample(self) -> None:
        self.t += 10_000_000
        self.imu_pub.publish(imu_sample(self.t, rate_z=0.5))  # yaw rate error -0.5 rad/s

    def feed(self, count: int) -> np.ndarray:
        for _ in range(count):
            self.sample()
        assert self.stamps and self.stamps[-1] == self.t, 'no tau for the last IMU sample'
        return self.taus[-1]

    def set(self, name: str, value: Any) -> Any:
        return set_param(self.executor, self.spin, self.client, name, value)

    def get(self, name: str) -> Any:
        return get_param(self.executor, self.spin, self.client, name)


@pytest.fixture
def loop(context, executor, spin) -> Loop:
    return Loop(context, executor, spin)


def test_the_first_imu_sample_only_initializes(loop):
    loop.sample()
    assert not loop.taus


def test_goal_and_gains_reach_the_force(loop):
    loop.sample()
    tau = loop.feed(5)
    assert tau[0] > 0.0, 'the goal on trajectory_request did not reach the controller'
    assert tau[5] == pytest.approx(-4.0 * 0.5)  # kp_yaw 4, no ki: tau_N = kp e


@pytest.mark.parametrize('name, value, says', [
    # Out of range: an array element (checked by Enbarr) and a scalar (by rclpy).
    ('kp', [20.0, 20.0, 20.0, 4.0, 4.0, -1.0], ['kp[5]', '-1.0']),
    ('level_gain', 500.0, ['level_gain']),
    # Wrong length: refused by the settings build, naming the parameter.
    ('kp', [1.0, 2.0, 3.0], ['kp']),
    # Read-only.
    ('velocity_topic', 'dvl/odometry', []),
    # Wrong type.
    ('level_gain', 'high', []),
], ids=['kp element out of range', 'level_gain out of range', 'kp wrong length', 'read-only',
        'wrong type'])
def test_a_refused_change_says_why_and_keeps_the_old_values(loop, name, value, says):
    loop.sample()
    loop.feed(5)
    result = loop.set(name, value)
    assert not result.successful and result.reason
    for text in says:
        assert text in result.reason
    # The refusal kept the old values, in the node and its controller.
    assert loop.get('kp') == KP
    assert loop.get('level_gain') == 2.0
    assert loop.get('velocity_topic') == ''
    assert loop.node.controller.settings.kp == tuple(KP)
    assert loop.node.controller.settings.level_gain == 2.0
    assert loop.feed(1)[5] == pytest.approx(-2.0)


def test_a_valid_gain_acts_on_the_next_step(loop):
    loop.sample()
    loop.feed(5)
    result = loop.set('kp', [20.0, 20.0, 20.0, 4.0, 4.0, 8.0])
    assert result.successful, result.reason
    assert loop.node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 8.0)
    assert loop.get('kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 8.0]
    assert loop.feed(1)[5] == pytest.approx(-8.0 * 0.5)


def test_a_valid_scalar_is_applied(loop):
    result = loop.set('level_gain', 5.0)
    assert result.successful, result.reason
    assert loop.node.controller.settings.level_gain == 5.0
    assert loop.node.settings.controller.level_gain == 5.0


class Feeder:
    """The loop with default gains and a surge goal of 0.3 m/s stamped at 1 s."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.node = add(executor, VelocityControlNode(context=context))
        feeder = probe(context, executor, 'feeder')
        self.imu_pub = feeder.create_topic_publisher(topics.IMU)
        goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.taus: list[np.ndarray] = []
        feeder.create_topic_subscription(
            topics.FORCE_COMMAND, lambda m: self.taus.append(convert.wrench_to_tau(m.wrench)))
        LinkBus.of(context).connect()
        goal = TwistStamped()
        goal.twist.linear.x = 0.3
        self.t = 1_000_000_000
        convert.ns_to_stamp(self.t, goal.header.stamp)  # goal age: on the IMU time line
        goal_pub.publish(goal)

    def run(self, n: int) -> None:
        for _ in range(n):
            self.t += 10_000_000
            self.imu_pub.publish(imu_sample(self.t, rate_z=0.0))


@pytest.fixture
def feeder(context, executor) -> Feeder:
    return Feeder(context, executor)


def test_out_of_order_imu_is_dropped_and_the_state_kept(feeder):
    """A late or repeated IMU stamp is dropped and counted; the loop state is kept (a reset
    would drop the reference model's velocity and jolt the commanded force).
    """
    node, taus = feeder.node, feeder.taus
    feeder.run(50)
    ref_before = node.reference.nu_ref.copy()
    assert ref_before[0] > 0.1 and len(taus) == 49
    feeder.imu_pub.publish(imu_sample(feeder.t - 5_000_000, rate_z=0.0))  # from the past
    feeder.imu_pub.publish(imu_sample(feeder.t, rate_z=0.0))              # repeated
    assert node.rejected == 2 and len(taus) == 49
    np.testing.assert_array_equal(node.reference.nu_ref, ref_before)
    feeder.run(1)
    assert len(taus) == 50 and abs(taus[-1][0] - taus[-2][0]) < 0.5


def test_a_stale_goal_counts_as_zero(feeder):
    """A goal stamped more than goal_timeout before the IMU sample counts as zero."""
    node = feeder.node
    feeder.run(90)  # 0.9 s: the goal is fresh, the reference reaches it
    assert node.reference.nu_ref[0] > 0.25
    feeder.run(250)  # samples go on without a gap; from 2.0 s the goal is stale
    assert abs(node.reference.nu_ref[0]) < 1e-3
    assert node.rejected == 0  # no gap, no reset: the goal timed out
