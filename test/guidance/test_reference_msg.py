"""Unit tests: the ``guidance/reference`` message (reference -> message -> reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from std_msgs.msg import Header

from enbarr_core.guidance.guidance import Reference
from enbarr_core.guidance.guidance_node import msg_to_reference, reference_to_msg
from enbarr_interfaces import convert, topics

T0_NS = 1_700_000_000_123_456_789
HEADER = Header(stamp=convert.ns_to_stamp(T0_NS), frame_id=topics.WORLD_FRAME)  # the estimate's


def ref_of(mask: tuple[bool, bool, bool]) -> Reference:
    return Reference(np.array([1.0, 2.0, 0.3]), np.array([0.2, -0.1, 0.05]),
                     np.array([0.01, -0.02, 0.003]), mask)


@pytest.mark.parametrize('mask', [(True, True, True), (False, False, True),
                                  (True, False, False), (False, False, False)])
def test_round_trip_keeps_every_field_and_the_mask(mask):
    ref = ref_of(mask)
    back = msg_to_reference(reference_to_msg(ref, HEADER))
    assert back.position_mask == mask
    expected = np.where(mask, ref.eta_d, np.nan)  # not fed back: no position reference
    np.testing.assert_allclose(back.eta_d, expected, atol=1e-12)  # NaN == NaN here
    np.testing.assert_allclose(back.nu_d, ref.nu_d, atol=1e-12)
    np.testing.assert_allclose(back.nu_d_dot, ref.nu_d_dot, atol=1e-12)


def test_the_message_says_what_it_carries():
    msg = reference_to_msg(ref_of((False, False, True)), HEADER)
    assert convert.stamp_to_ns(msg.header.stamp) == T0_NS  # the estimate it was made for
    assert msg.header.frame_id == topics.WORLD_FRAME
    assert list(msg.joint_names) == [topics.BODY_FRAME] and len(msg.points) == 1
    p = msg.points[0]
    tf, vel, acc = p.transforms[0], p.velocities[0], p.accelerations[0]
    assert math.isnan(tf.translation.x) and math.isnan(tf.translation.y)
    assert convert.quaternion_to_yaw(tf.rotation) == pytest.approx(0.3)
    assert (vel.linear.x, vel.linear.y, vel.angular.z) == pytest.approx((0.2, -0.1, 0.05))
    assert (acc.linear.x, acc.linear.y, acc.angular.z) == pytest.approx((0.01, -0.02, 0.003))
    heading_free = reference_to_msg(ref_of((True, True, False)), HEADER).points[0].transforms[0]
    q = heading_free.rotation
    assert all(math.isnan(c) for c in (q.x, q.y, q.z, q.w))


def test_a_malformed_reference_is_refused_with_what_was_expected():
    msg = reference_to_msg(ref_of((True, True, True)), HEADER)
    msg.joint_names = ['thruster']
    with pytest.raises(ValueError, match="guidance/reference: expected one point of joint "
                       "'base_link'"):
        msg_to_reference(msg)
    msg = reference_to_msg(ref_of((True, True, True)), HEADER)
    msg.points[0].accelerations = []
    with pytest.raises(ValueError, match='one transform, velocity and acceleration'):
        msg_to_reference(msg)


def test_the_message_is_byte_for_byte_the_one_the_generated_constructors_build():
    """``reference_to_msg`` builds with ``fastmsg.new``: the same message as the classes'."""
    from geometry_msgs.msg import Transform, Twist
    from rclpy.serialization import serialize_message
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
    ref = ref_of((True, False, True))
    pose, vel, acc = Transform(), Twist(), Twist()
    convert.set_transform_eta(pose, [1.0, math.nan, 0.3])
    convert.set_twist_nu3(vel, ref.nu_d)
    convert.set_twist_nu3(acc, ref.nu_d_dot)
    expected = MultiDOFJointTrajectory(
        header=HEADER, joint_names=[topics.BODY_FRAME], points=[MultiDOFJointTrajectoryPoint(
            transforms=[pose], velocities=[vel], accelerations=[acc])])
    assert serialize_message(reference_to_msg(ref, HEADER)) == serialize_message(expected)
