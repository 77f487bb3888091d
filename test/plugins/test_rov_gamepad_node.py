"""The rov_gamepad node in process: joy in, stamped surface commands out, silent when lost."""

from __future__ import annotations

from geometry_msgs.msg import TwistStamped
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter
from sensor_msgs.msg import Joy
from std_msgs.msg import Bool

from enbarr_interfaces import convert, topics
from enbarr_plugins.operator.gamepad import RovGamepadNode
from support.nodes import add, probe

pytestmark = pytest.mark.node

CROSS, RY = 3, 3   # enbarr_ds4: button cross, axis right_y (typed from ds4_driver's order)


@pytest.fixture
def pad(context, executor):
    node = add(executor, RovGamepadNode(context=context, parameter_overrides=[
        Parameter('rate', value=50.0), Parameter('joy_timeout', value=0.3)]))
    listener = probe(context, executor)
    seen = {'twists': [], 'ios': []}
    listener.create_subscription(
        TwistStamped, topics.SURFACE_TWIST.name,
        lambda m: seen['twists'].append((m.header, list(convert.twist_to_nu(m.twist)))),
        topics.SURFACE_TWIST.qos)
    listener.create_subscription(
        ParameterMsg, topics.SURFACE_IO.name,
        lambda m: seen['ios'].append((m.name, convert.parameter_value_to_python(m.value))),
        topics.SURFACE_IO.qos)
    joy = listener.create_publisher(Joy, topics.JOY.name, topics.JOY.qos)
    conn = listener.create_publisher(Bool, topics.JOY_CONNECTED.name, topics.JOY_CONNECTED.qos)
    node.start()
    return node, seen, joy, conn


def sample(ry=0.0, cross=0):
    msg = Joy()
    msg.axes = [0.0, 0.0, 0.0, ry, 0.0, 0.0]
    msg.buttons = [0] * 18
    msg.buttons[CROSS] = cross
    return msg


def assert_silent(node):
    """The node's send step publishes nothing (checked at the publisher, no waiting)."""
    sent = []
    node._twist_pub.publish = sent.append
    for _ in range(3):
        node._send()
    assert sent == []


def test_sticks_become_a_stamped_twist_and_a_press_an_io_request(pad, executor, spin):
    node, seen, joy, conn = pad
    conn.publish(Bool(data=True))
    joy.publish(sample())                       # arms the buttons
    assert spin(executor, lambda: seen['twists'], 10.0)
    joy.publish(sample(ry=1.0, cross=1))
    assert spin(executor, lambda: seen['twists'][-1][1][0] == pytest.approx(0.5)
                and ('pilot_mode', 'depth_hold') in seen['ios'], 10.0)
    header = seen['twists'][-1][0]
    assert header.frame_id == topics.BODY_FRAME
    assert header.stamp.sec > 0 or header.stamp.nanosec > 0
    assert seen['ios'].count(('pilot_mode', 'depth_hold')) == 1


def test_a_disconnected_pad_goes_silent(pad, executor, spin):
    node, seen, joy, conn = pad
    conn.publish(Bool(data=True))
    joy.publish(sample(ry=1.0))
    assert spin(executor, lambda: seen['twists'], 10.0)
    conn.publish(Bool(data=False))
    assert spin(executor, lambda: node.mapper.lost(node._now()) is not None, 10.0)
    assert_silent(node)


def test_a_stale_joy_goes_silent(pad, executor, spin):
    node, seen, joy, conn = pad
    joy.publish(sample(ry=1.0))
    assert spin(executor, lambda: seen['twists'], 10.0)
    assert spin(executor, lambda: node.mapper.lost(node._now()) is not None, 10.0)
    assert_silent(node)
