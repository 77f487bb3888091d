"""Unit tests: ``fastmsg.new(cls)`` builds what ``cls()`` builds, independent objects."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from support.cdr_bytes import same_cdr

from enbarr_interfaces import fastmsg, topics
from enbarr_interfaces.topics import TopicSpec

pytestmark = pytest.mark.unit

CONTRACT = sorted({s.msg_type for s in vars(topics).values() if isinstance(s, TopicSpec)},
                  key=lambda c: f'{c.__module__}.{c.__name__}')


def _extra():
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Polygon
    from sensor_msgs.msg import CameraInfo, LaserScan
    return [DiagnosticArray, Polygon, CameraInfo, LaserScan]


@pytest.mark.parametrize('cls', sorted(set(CONTRACT + _extra()), key=lambda c: c.__name__),
                         ids=lambda c: c.__name__)
def test_new_equals_the_generated_constructor_field_by_field_and_byte_for_byte(cls):
    from rclpy.serialization import deserialize_message
    built = fastmsg.new(cls)
    assert type(built) is cls
    assert built == cls()
    assert deserialize_message(serialize_message(built), cls) == cls()
    # Byte for byte up to the end of the CDR data: Fast-DDS sizes the buffer of types with
    # strings inside sequences by its estimate and leaves what follows undefined.
    # Padding bytes are left as the buffer held them (CDR leaves them unspecified): compared
    # as zeros, where the padding-marking encoder says they are.
    reference, ours = serialize_message(cls()), serialize_message(built)
    assert same_cdr(ours, reference, cls())


def test_the_contract_has_the_hot_types():
    names = {c.__name__ for c in CONTRACT}
    assert {'Imu', 'Odometry', 'WrenchStamped', 'JointState', 'PoseStamped',
            'MultiDOFJointTrajectory'} <= names


def test_every_message_is_its_own_down_to_nested_fields_and_arrays():
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState
    a, b = fastmsg.new(Odometry), fastmsg.new(Odometry)
    a.header.frame_id = 'odom'
    a.pose.pose.position.x = 1.0
    a.pose.covariance[0] = 2.0
    assert b.header.frame_id == '' and b.pose.pose.position.x == 0.0
    assert b.pose.covariance[0] == 0.0 and isinstance(b.pose.covariance, np.ndarray)
    assert fastmsg.new(Odometry) == Odometry()         # the prototype is untouched
    i = fastmsg.new(Imu)
    i.orientation_covariance[4] = 1.0
    assert fastmsg.new(Imu).orientation_covariance[4] == 0.0
    j, k = fastmsg.new(JointState), fastmsg.new(JointState)
    j.position.append(1.0)
    j.name.append('x')
    assert list(k.position) == [] and k.name == []


def test_fields_are_set_as_on_any_message():
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    m = fastmsg.new(JointState)
    m.name, m.effort = ['a', 'b'], [1.0, 2.0]
    assert m == JointState(name=['a', 'b'], effort=[1.0, 2.0])
    f = fastmsg.new(Float64)
    f.data = 3.5
    assert serialize_message(f) == serialize_message(Float64(data=3.5))


def test_not_a_message_is_refused_by_name():
    with pytest.raises(TypeError, match='not a ROS message class'):
        fastmsg.new(dict)
