"""The ROV gamepad mapping: every control, the dead band, press edges, a lost pad is silent."""

from __future__ import annotations

from dataclasses import replace

import pytest

from enbarr_core.control.rov_gamepad import (
    dead_band, GamepadMapper, GamepadSettings, IoRequest)

pytestmark = pytest.mark.unit

# The enbarr_ds4 layout (ds4_driver's order, typed from its controller_ros.py): axes
# [lx, ly, rx, ry, l2, r2]; buttons [square, triangle, circle, cross, l1, l2, r1, r2, share,
# options, ps, trackpad, l3, r3, dpad left, up, right, down].
LX, LY, RX, RY = 0, 1, 2, 3
BUTTON = {'square': 0, 'triangle': 1, 'circle': 2, 'cross': 3, 'l1': 4, 'r1': 6,
          'options': 9, 'r3': 13, 'dpad_up': 15, 'dpad_down': 17}


def axes(lx=0.0, ly=0.0, rx=0.0, ry=0.0):
    return [lx, ly, rx, ry, 0.0, 0.0]


def buttons(*names):
    out = [0] * 18
    for name in names:
        out[BUTTON[name]] = 1
    return out


def connected(settings=GamepadSettings(), t=0.0):
    pad = GamepadMapper(settings)
    pad.on_connection(True, t)
    pad.on_joy(axes(), buttons(), t)   # arms the buttons
    return pad


def press(pad, name, t):
    """Press and release ``name``; return what the press fired."""
    fired = pad.on_joy(axes(), buttons(name), t)
    assert pad.on_joy(axes(), buttons(), t + 0.01) == []
    return fired


@pytest.mark.parametrize('stick, kwargs, dof, full', [
    ('right_y up: surge ahead', {'ry': 1.0}, 0, 0.5),
    ('right_x left: sway left', {'rx': 1.0}, 1, 0.5),
    ('left_y up: heave up', {'ly': 1.0}, 2, 0.5),
    ('left_x left: yaw left', {'lx': 1.0}, 5, 1.0),
])
def test_each_stick_drives_its_axis_at_full_speed_at_the_stop(stick, kwargs, dof, full):
    pad = connected()
    pad.on_joy(axes(**kwargs), buttons(), 0.1)
    expected = [0.0] * 6
    expected[dof] = full
    assert pad.twist(0.1) == pytest.approx(expected), stick
    pad.on_joy(axes(**{k: -v for k, v in kwargs.items()}), buttons(), 0.2)
    expected[dof] = -full
    assert pad.twist(0.2) == pytest.approx(expected), stick


def test_full_stick_speeds_and_signs_come_from_the_settings():
    s = replace(GamepadSettings(), sticks=(('surge', '-left_y'), ('sway', ''), ('heave', ''),
                                           ('yaw', 'right_x')),
                full_stick=(('surge', 0.2), ('sway', 0.5), ('heave', 0.5), ('yaw', 0.3)))
    pad = connected(s)
    pad.on_joy(axes(ly=1.0, rx=-1.0, ry=1.0), buttons(), 0.1)
    assert pad.twist(0.1) == pytest.approx([-0.2, 0.0, 0.0, 0.0, 0.0, -0.3])


def test_dead_band_is_zero_inside_continuous_at_its_edge_and_one_at_the_stop():
    assert dead_band(0.1, 0.1) == 0.0
    assert dead_band(-0.09, 0.1) == 0.0
    assert dead_band(0.1 + 1e-9, 0.1) == pytest.approx(0.0, abs=1e-8)
    assert dead_band(0.55, 0.1) == pytest.approx(0.5)
    assert dead_band(-0.55, 0.1) == pytest.approx(-0.5)
    assert dead_band(1.0, 0.1) == pytest.approx(1.0)
    assert dead_band(1.3, 0.1) == pytest.approx(1.0)     # a driver that overshoots
    assert dead_band(float('nan'), 0.1) == 0.0


def test_a_stick_resting_in_the_dead_band_commands_nothing():
    pad = connected()
    pad.on_joy(axes(0.08, -0.09, 0.05, -0.1), buttons(), 0.1)
    assert pad.twist(0.1) == (0.0,) * 6


@pytest.mark.parametrize('name, request_', [
    ('square', IoRequest('pilot_mode', 'manual')),
    ('triangle', IoRequest('pilot_mode', 'stabilize')),
    ('cross', IoRequest('pilot_mode', 'depth_hold')),
    ('circle', IoRequest('pilot_mode', 'velocity')),
    ('r1', IoRequest('manipulator', 50)),
    ('l1', IoRequest('manipulator', -50)),
    ('options', IoRequest('gpio_12', True)),
    ('dpad_up', IoRequest('camera_tilt', 10.0)),
    ('dpad_down', IoRequest('camera_tilt', -10.0)),
    ('r3', IoRequest('camera_tilt', 0.0)),
])
def test_each_button_sends_its_request_once_on_the_press_edge(name, request_):
    pad = connected()
    assert pad.on_joy(axes(), buttons(name), 0.1) == [request_]
    assert pad.on_joy(axes(), buttons(name), 0.15) == []    # held: nothing more
    assert pad.on_joy(axes(), buttons(), 0.2) == []         # released: nothing


def test_lights_toggle_and_tilt_steps_are_clamped_and_centred():
    pad = connected()
    assert press(pad, 'options', 0.1) == [IoRequest('gpio_12', True)]
    assert press(pad, 'options', 0.2) == [IoRequest('gpio_12', False)]
    tilts = [press(pad, 'dpad_up', 0.3 + 0.1 * i)[0].value for i in range(6)]
    assert tilts == [10.0, 20.0, 30.0, 40.0, 45.0, 45.0]
    assert press(pad, 'r3', 1.0) == [IoRequest('camera_tilt', 0.0)]
    tilts = [press(pad, 'dpad_down', 1.1 + 0.1 * i)[0].value for i in range(6)]
    assert tilts == [-10.0, -20.0, -30.0, -40.0, -45.0, -45.0]


def test_two_buttons_pressed_together_send_both():
    pad = connected()
    assert pad.on_joy(axes(), buttons('cross', 'options'), 0.1) == [
        IoRequest('pilot_mode', 'depth_hold'), IoRequest('gpio_12', True)]


def test_nothing_is_sent_before_a_sample_and_the_first_sample_fires_no_button():
    pad = GamepadMapper(GamepadSettings())
    pad.on_connection(True, 0.0)
    assert pad.twist(0.0) is None
    assert pad.on_joy(axes(ry=1.0), buttons('cross'), 0.05) == []
    assert pad.twist(0.05) == pytest.approx([0.5, 0, 0, 0, 0, 0])


def test_a_stale_joy_silences_the_twist_it_never_republishes_frozen_axes():
    pad = connected()
    pad.on_joy(axes(ry=1.0), buttons(), 1.0)
    assert pad.twist(1.5) == pytest.approx([0.5, 0, 0, 0, 0, 0])     # at joy_timeout
    assert pad.twist(1.5001) is None
    assert pad.lost(1.6) is not None


def test_a_disconnect_silences_at_once_and_drops_samples_until_reconnected():
    pad = connected()
    pad.on_joy(axes(ry=1.0), buttons(), 1.0)
    pad.on_connection(False, 1.01)
    assert pad.twist(1.01) is None
    assert pad.on_joy(axes(ry=1.0), buttons('cross'), 1.02) == []
    assert pad.twist(1.02) is None
    pad.on_connection(True, 1.1)
    # A button held through the reconnect is armed, not pressed.
    assert pad.on_joy(axes(), buttons('cross'), 1.11) == []
    assert pad.twist(1.11) == (0.0,) * 6
    assert pad.on_joy(axes(), buttons(), 1.12) == []
    assert pad.on_joy(axes(), buttons('cross'), 1.13) == [IoRequest('pilot_mode', 'depth_hold')]


def test_a_button_held_through_a_stale_gap_is_not_a_press():
    pad = connected()
    pad.on_joy(axes(), buttons(), 1.0)
    assert pad.on_joy(axes(), buttons('cross'), 2.0) == []
    assert pad.on_joy(axes(), buttons(), 2.01) == []
    assert pad.on_joy(axes(), buttons('cross'), 2.02) == [IoRequest('pilot_mode', 'depth_hold')]


def test_a_driver_that_publishes_on_change_is_judged_by_its_heartbeat():
    pad = connected(replace(GamepadSettings(), layout='ds4_driver'), t=0.0)
    pad.on_joy(axes(ry=1.0), buttons(), 0.1)
    pad.on_connection(True, 2.0)
    # The stick held still for 2 s: silent driver, but the pad is there.
    assert pad.twist(2.2) == pytest.approx([0.5, 0, 0, 0, 0, 0])
    assert pad.twist(2.6) is None     # the heartbeat is late


@pytest.mark.parametrize('change, message', [
    ({'layout': 'xbox'}, 'layout: unknown layout'),
    ({'sticks': (('surge', 'right_z'),)}, 'sticks.surge'),
    ({'sticks': (('roll', 'right_x'),)}, "'roll' is not one of"),
    ({'buttons': (('lights', 'x'),)}, 'buttons.lights'),
    ({'buttons': (('lights', 'cross'), ('manual', 'cross'))}, "'cross' is given to two"),
    ({'deadzone': 1.0}, 'deadzone'),
    ({'tilt_min': 5.0}, 'tilt_min'),
    ({'joy_timeout': 0.0}, 'joy_timeout'),
    ({'full_stick': (('yaw', -1.0),)}, 'full_stick.yaw'),
    ({'full_stick': (('yaw', 1.0),)}, 'full_stick.surge: needed for sticks.surge'),
])
def test_bad_settings_are_refused_naming_the_setting(change, message):
    with pytest.raises(ValueError, match=message):
        GamepadMapper(replace(GamepadSettings(), **change))
