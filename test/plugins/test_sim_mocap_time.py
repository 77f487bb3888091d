"""Node tests: the simulated motion capture under a truth stamped ahead (issue 8, Time)."""

from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from support.nodes import add, probe
from support.saucer import SimClock, odometry_msg

from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.mocap.sim import SimMocapNode


def test_a_truth_stamped_ahead_does_not_silence_the_mocap(context, executor):
    # One sim/odometry stamped 20 s ahead moved the next measurement time 20 s ahead: the
    # motion capture fell silent for 20 s (the observer dead-reckoned, automatic fell back).
    mocap = add(executor, SimMocapNode(node_name='mocap', context=context, parameter_overrides=[
        Parameter('rate', value=50.0), Parameter('position_noise', value=0.0),
        Parameter('heading_noise', value=0.0)]))
    clock = SimClock(mocap)
    p = probe(context, executor, 'simulator')
    truth = p.create_topic_publisher(topics.SIM_ODOMETRY)
    poses: list[PoseStamped] = []
    p.create_topic_subscription(topics.MOCAP_POSE, poses.append)
    LinkBus.of(context).connect()
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
