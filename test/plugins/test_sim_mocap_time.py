"""Node tests: the simulated motion capture under a truth stamped ahead."""

from __future__ import annotations

import math

import pytest

from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from support.nodes import add, probe
from support.saucer import SimClock, odometry_msg

from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.mocap.sim import SimMocapNode


def mocap_rig(context, executor, **params):
    """A 50 Hz sim mocap (``params`` set), its clock, a truth publisher and the poses out."""
    mocap = add(executor, SimMocapNode(node_name='mocap', context=context, parameter_overrides=[
        Parameter('rate', value=50.0), *(Parameter(k, value=v) for k, v in params.items())]))
    mocap.start()
    clock = SimClock(mocap)
    p = probe(context, executor, 'simulator')
    truth = p.create_topic_publisher(topics.SIM_ODOMETRY)
    poses: list[PoseStamped] = []
    p.create_topic_subscription(topics.MOCAP_POSE, poses.append)
    LinkBus.of(context).connect()
    return mocap, clock, truth, poses


def test_a_truth_stamped_ahead_does_not_silence_the_mocap(context, executor):
    # One sim/odometry stamped 20 s ahead moved the next measurement time 20 s ahead: the
    # motion capture fell silent for 20 s (the observer dead-reckoned, automatic fell back).
    mocap, clock, truth, poses = mocap_rig(context, executor, position_noise=0.0,
                                           heading_noise=0.0)
    for _ in range(10):
        truth.publish(odometry_msg(clock.advance(0.02), [0.0, 0.0, 0.0]))
    for ahead in (20.0, 5.0, 1.0):
        truth.publish(odometry_msg(clock.ns + round(ahead * 1e9), [0.0, 0.0, 0.0]))
    for _ in range(10):
        truth.publish(odometry_msg(clock.advance(0.02), [0.0, 0.0, 0.0]))
    assert len(poses) == 20, 'the mocap fell silent after a truth stamped ahead'
    assert mocap.status_values()['refused'] == 3
    level, message = mocap.status()
    assert level == 1 and 'sim/odometry: refused 3 of 23' in message, message


def test_the_noisy_pose_is_truth_plus_the_seeded_draws_bit_for_bit(context, executor):
    """The pose is truth + noise from the node's seeded generator, drawn in a fixed order
    (x and y together, then heading), heading wrapped: a seed gives the same poses."""
    import numpy as np

    from enbarr_core.framework.kinematics import ssa
    from enbarr_interfaces import convert
    mocap, clock, truth, poses = mocap_rig(context, executor, position_noise=0.01,
                                           heading_noise=0.02, seed=11)
    etas = [(0.1 * k, -0.3 + 0.05 * k, 3.13 + 0.002 * k) for k in range(12)]  # yaw near pi
    for eta in etas:
        truth.publish(odometry_msg(clock.advance(0.02), list(eta)))
    rng = np.random.default_rng(11)
    assert len(poses) == len(etas)
    for eta, pose in zip(etas, poses):
        truth_eta = convert.pose_to_eta(odometry_msg(0, list(eta)).pose.pose)
        xy = truth_eta[:2] + rng.normal(0.0, 0.01, 2)
        psi = ssa(truth_eta[2] + rng.normal(0.0, 0.02))
        assert (pose.pose.position.x, pose.pose.position.y) == (xy[0], xy[1])
        assert convert.quaternion_to_yaw(pose.pose.orientation) == pytest.approx(psi, abs=1e-12)
        assert pose.pose.orientation.z == math.sin(0.5 * psi)
