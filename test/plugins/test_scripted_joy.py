"""Node tests: the scripted joystick publishes in the profile's layout."""

from __future__ import annotations

import re

from typing import Any

import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Joy
from support.nodes import TIMEOUT, add, probe
from support.saucer import SimClock

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import topics
from enbarr_plugins.joystick.scripted import parse_joy_script, ScriptedJoyNode

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
    with pytest.raises(ConfigurationError, match=f"parameter '{missing}' is not set"):
        joystick(context, **params)


def test_a_button_the_layout_lacks_is_refused(context):
    with pytest.raises(ConfigurationError, match='script'):
        joystick(context, **{'script': ['1.0 press options'], 'joy.buttons': ROS_JOY,
                             'joy.axis_surge': 1, 'joy.axis_sway': 0, 'joy.axis_yaw': 3})


BUTTONS = {'cross': 0, 'circle': 1, 'triangle': 2, 'square': 3}


def test_joy_script_parses_into_typed_steps():
    steps = parse_joy_script(['0.0 sticks 0.5 0.0 -1.0', '', '2.0 press square', '3.5 stop'],
                             BUTTONS)
    assert [(s.time, s.verb, s.value, s.line) for s in steps] == [
        (0.0, 'sticks', (0.5, 0.0, -1.0), 0), (2.0, 'press', 3, 2), (3.5, 'stop', None, 3)]


@pytest.mark.parametrize('line, reason', [
    ('1.0 sticks 0.5 0.0', 'sticks takes 3'),
    ('1.0 sticks 0.5 0.0 1.5', 'within -1.0..1.0'),
    ('1.0 press start', 'press takes one button name of cross|circle|triangle|square'),
    ('1.0 stop now', 'stop takes no arguments'),
    ('1.0 wave', 'expected "sticks", "press", "stop"'),
])
def test_joy_script_errors_name_the_line_and_the_fault(line, reason):
    with pytest.raises(ValueError, match=re.escape(f"script[1] '{line}'") + '.*'
                       + re.escape(reason)):
        parse_joy_script(['0.0 stop', line], BUTTONS)
