"""Node tests: velocity control node."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.parameter import Parameter
from support.nodes import add, get_param, param_client, probe, set_param
from support.rov import _imu

from enbarr_core.control.velocity_control_node import VelocityControlNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_velocity_control_live_tuning(context, executor, spin):
    node = add(executor, VelocityControlNode(
        node_name='control_loop', context=context, parameter_overrides=[
            Parameter('ki', value=[0.0] * 6), Parameter('goal_timeout', value=60.0)]))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    taus: list[np.ndarray] = []
    stamps: list[int] = []

    def on_tau(msg: WrenchStamped) -> None:
        taus.append(convert.wrench_to_tau(msg.wrench))
        stamps.append(convert.stamp_to_ns(msg.header.stamp))

    feeder.create_topic_subscription(topics.FORCE_COMMAND, on_tau)
    LinkBus.of(context).connect()
    client = param_client(executor, spin, context, 'control_loop')

    goal = TwistStamped()
    goal.twist.linear.x = 0.2  # surge is not measured: feed-forward only
    goal_pub.publish(goal)
    t = [1_000_000_000]

    def feed(count: int) -> np.ndarray:
        for _ in range(count):
            t[0] += 10_000_000
            imu_pub.publish(_imu(t[0], rate_z=0.5))  # yaw rate error -0.5 rad/s
        assert stamps and stamps[-1] == t[0], 'no tau for the last IMU sample'
        return taus[-1]

    t[0] += 10_000_000
    imu_pub.publish(_imu(t[0], rate_z=0.5))  # the first sample only initializes
    assert not taus
    tau = feed(5)
    assert tau[0] > 0.0, 'the goal on trajectory_request did not reach the controller'
    assert tau[5] == pytest.approx(-4.0 * 0.5)  # kp_yaw 4, no ki: tau_N = kp e

    # Out of range: an array element (checked by Enbarr) and a scalar (by rclpy).
    result = set_param(executor, spin, client, 'kp', [20.0, 20.0, 20.0, 4.0, 4.0, -1.0])
    assert not result.successful
    assert 'kp[5]' in result.reason and '-1.0' in result.reason
    result = set_param(executor, spin, client, 'level_gain', 500.0)
    assert not result.successful and 'level_gain' in result.reason
    # Wrong length: refused by the settings build, naming the parameter.
    result = set_param(executor, spin, client, 'kp', [1.0, 2.0, 3.0])
    assert not result.successful and 'kp' in result.reason
    # Read-only.
    result = set_param(executor, spin, client, 'velocity_topic', 'dvl/odometry')
    assert not result.successful and result.reason
    # Wrong type.
    result = set_param(executor, spin, client, 'level_gain', 'high')
    assert not result.successful and result.reason
    # Every refusal kept the old values, in the node and its controller.
    assert get_param(executor, spin, client, 'kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 4.0]
    assert get_param(executor, spin, client, 'level_gain') == 2.0
    assert get_param(executor, spin, client, 'velocity_topic') == ''
    assert node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 4.0)
    assert node.controller.settings.level_gain == 2.0
    assert feed(1)[5] == pytest.approx(-2.0)

    # A valid change is applied and acts on the next control step.
    result = set_param(executor, spin, client, 'kp', [20.0, 20.0, 20.0, 4.0, 4.0, 8.0])
    assert result.successful, result.reason
    assert node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 8.0)
    assert get_param(executor, spin, client, 'kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 8.0]
    assert feed(1)[5] == pytest.approx(-8.0 * 0.5)
    result = set_param(executor, spin, client, 'level_gain', 5.0)
    assert result.successful, result.reason
    assert node.controller.settings.level_gain == 5.0


def test_velocity_control_drops_out_of_order_imu(context, executor):
    """A late or repeated IMU stamp is dropped and counted; the loop state is kept (a reset
    would drop the reference model's velocity and jolt the commanded force).
    """
    node = add(executor, VelocityControlNode(node_name='control_loop', context=context))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    taus: list[np.ndarray] = []
    feeder.create_topic_subscription(
        topics.FORCE_COMMAND, lambda m: taus.append(convert.wrench_to_tau(m.wrench)))
    LinkBus.of(context).connect()
    goal = TwistStamped()
    goal.twist.linear.x = 0.3
    t = 1_000_000_000
    convert.ns_to_stamp(t, goal.header.stamp)  # goal age is measured on the IMU time line
    goal_pub.publish(goal)
    for _ in range(50):
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    ref_before = node.reference.nu_ref.copy()
    assert ref_before[0] > 0.1 and len(taus) == 49
    imu_pub.publish(_imu(t - 5_000_000, rate_z=0.0))  # from the past
    imu_pub.publish(_imu(t, rate_z=0.0))              # repeated
    assert node.rejected == 2 and len(taus) == 49
    np.testing.assert_array_equal(node.reference.nu_ref, ref_before)
    imu_pub.publish(_imu(t + 10_000_000, rate_z=0.0))
    assert len(taus) == 50 and abs(taus[-1][0] - taus[-2][0]) < 0.5


def test_velocity_control_ignores_a_stale_goal(context, executor):
    """A goal stamped more than goal_timeout before the IMU sample counts as zero."""
    node = add(executor, VelocityControlNode(node_name='control_loop', context=context))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    LinkBus.of(context).connect()
    goal = TwistStamped()
    goal.twist.linear.x = 0.3
    convert.ns_to_stamp(1_000_000_000, goal.header.stamp)
    goal_pub.publish(goal)
    t = 1_000_000_000
    for _ in range(90):  # 0.9 s: the goal is fresh, the reference reaches it
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    assert node.reference.nu_ref[0] > 0.25
    for _ in range(250):  # samples go on without a gap; from 2.0 s the goal is stale
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    assert abs(node.reference.nu_ref[0]) < 1e-3
    assert node.rejected == 0  # no gap, no reset: the goal timed out
