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


@pytest.mark.parametrize('missing, match', [
    ('joy.buttons', 'joy.layout: name a layout, or give joy.buttons'),
    ('joy.axis_yaw', 'joy.axis_yaw: required without joy.layout')])
def test_the_layout_is_required(context, missing, match):
    params = {'joy.buttons': ROS_JOY, 'joy.axis_surge': 1, 'joy.axis_sway': 0,
              'joy.axis_yaw': 3}
    params.pop(missing)
    with pytest.raises(ConfigurationError, match=match) as info:
        joystick(context, **params)
    assert info.value.parameter == match.split(':')[0]


@pytest.mark.parametrize('layout', ['enbarr_ds4', 'ds4_driver', 'joy', 'joydev'])
def test_a_named_layout_places_buttons_and_signed_sticks(context, executor, spin, layout):
    """The profile's named layout: triangle where that driver puts it, the sticks where
    its axis names say (with the sign), the other axes at rest; joy/connected True with it.
    """
    from std_msgs.msg import Bool

    from enbarr_core.control.joy_layouts import get_layout
    lay = get_layout(layout)
    node = add(executor, joystick(context, **{
        'script': ['0.0 sticks 0.5 -0.25 0.75', '0.0 press triangle'], 'joy.layout': layout,
        'joy.surge': 'left_y', 'joy.sway': 'left_x', 'joy.yaw': '-right_x'}))
    clock = SimClock(node)
    got: list[Joy] = []
    connected: list[bool] = []
    p = probe(context, executor, 'listener')
    p.create_subscription(Joy, topics.JOY.name, got.append, topics.JOY.qos)
    p.create_subscription(Bool, topics.JOY_CONNECTED.name, lambda m: connected.append(m.data),
                          topics.JOY_CONNECTED.qos)
    node.start()
    for _ in range(3):
        clock.advance(0.05)
        spin(executor, lambda: bool(got), 0.2)
    assert spin(executor, lambda: bool(got) and bool(connected), TIMEOUT)
    first = got[0]
    assert [lay.buttons[i] for i, b in enumerate(first.buttons) if b] == ['triangle']
    assert len(first.axes) == len(lay.axes)
    want = dict(zip(lay.axes, lay.rest))
    want.update(left_y=0.5, left_x=-0.25, right_x=-0.75)
    assert list(first.axes) == [want[name] for name in lay.axes]
    assert connected[0] is True


def test_stop_says_the_joystick_is_disconnected(context, executor, spin):
    from std_msgs.msg import Bool
    node = add(executor, joystick(context, **{
        'script': ['0.0 sticks 0.5 0.0 0.0', '0.1 stop'], 'joy.layout': 'enbarr_ds4',
        'joy.surge': 'left_y', 'joy.sway': 'left_x', 'joy.yaw': 'right_x'}))
    clock = SimClock(node)
    connected: list[bool] = []
    p = probe(context, executor, 'listener')
    p.create_subscription(Bool, topics.JOY_CONNECTED.name, lambda m: connected.append(m.data),
                          topics.JOY_CONNECTED.qos)
    node.start()
    for _ in range(6):
        clock.advance(0.05)
        spin(executor, lambda: False in connected, 0.2)
    assert spin(executor, lambda: False in connected, TIMEOUT)
    assert connected[0] is True and connected[-1] is False


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


def test_nothing_is_published_before_start_or_after_stop(context, executor, spin):
    """Stopped (bringup putting the safe state in place), the stand-in no longer drives the
    chain, as the real driver's reader stops; not started, its timer does not even wake."""
    node = add(executor, joystick(context, **{
        'script': ['0.0 sticks 0.5 0.0 0.0'], 'rate': 20.0, 'joy.layout': 'joy',
        'joy.surge': 'left_y', 'joy.sway': 'left_x', 'joy.yaw': 'right_x'}))
    clock = SimClock(node)
    got: list[Joy] = []
    p = probe(context, executor, 'listener')
    p.create_subscription(Joy, topics.JOY.name, got.append, topics.JOY.qos)

    def run(seconds: float) -> None:
        for _ in range(round(seconds / 0.05)):
            clock.advance(0.05)
            spin(executor, lambda: False, 0.02)
    run(0.3)
    assert got == []
    node.start()
    run(0.3)
    assert spin(executor, lambda: len(got) >= 2, TIMEOUT)
    node.stop()
    spin(executor, lambda: False, 0.2)               # what was in flight is delivered
    stopped_at = len(got)
    run(0.5)
    assert len(got) == stopped_at
