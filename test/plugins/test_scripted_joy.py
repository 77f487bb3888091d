"""Node tests: the scripted joystick publishes in the profile's layout."""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Joy
from support.nodes import TIMEOUT, add, probe
from support.saucer import SimClock

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import topics
from enbarr_plugins.joystick.scripted import ScriptedJoyNode

ROS_JOY = ['cross', 'circle', 'square', 'triangle']  # ROS joy game-controller layout


def joystick(context: Any, **params: Any) -> ScriptedJoyNode:
    return ScriptedJoyNode(node_name='joystick', context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])


def test_presses_and_sticks_land_where_the_layout_says(context, executor, spin):
    node = add(executor, joystick(context, **{
        'script': ['0.0 sticks 0.5 -0.25 0.75', '0.0 press square'], 'rate': 20.0,
        'joy.buttons': ROS_JOY, 'joy.axis_surge': 4, 'joy.axis_sway': 3, 'joy.axis_yaw': 0}))
    clock = SimClock(node)
    got: list[Joy] = []
    p = probe(context, executor, 'listener')
    p.create_subscription(Joy, topics.JOY.name, got.append, topics.JOY.qos)
    node.start()
    for _ in range(3):
        clock.advance(0.05)
        spin(executor, lambda: bool(got), 0.2)
    assert spin(executor, lambda: bool(got), TIMEOUT)
    first = got[0]
    assert list(first.buttons[:4]) == [0, 0, 1, 0]  # square is button 2 in this layout
    assert first.axes[4] == 0.5 and first.axes[3] == -0.25 and first.axes[0] == 0.75


@pytest.mark.parametrize('missing', ['joy.buttons', 'joy.axis_yaw'])
def test_the_layout_is_required(context, missing):
    params = {'joy.buttons': ROS_JOY, 'joy.axis_surge': 1, 'joy.axis_sway': 0,
              'joy.axis_yaw': 3}
    params.pop(missing)
    with pytest.raises(ConfigurationError, match=f'{missing} is not set'):
        joystick(context, **params)


def test_a_button_the_layout_lacks_is_refused(context):
    with pytest.raises(ConfigurationError, match='script'):
        joystick(context, **{'script': ['1.0 press options'], 'joy.buttons': ROS_JOY,
                             'joy.axis_surge': 1, 'joy.axis_sway': 0, 'joy.axis_yaw': 3})
