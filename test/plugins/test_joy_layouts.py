"""Joystick layout presets (``enbarr_core.control.joy_layouts``): for every preset, every
button pressed in that layout and every stick moved, through the mode manager with the CS
Saucer's named controls (manual section 3.2.5: triangle automatic, square guidance, cross
manual; left stick surge/sway, right stick yaw). No ROS.
"""

from __future__ import annotations

import pytest

from enbarr_core.bringup.profile import load_profile
from enbarr_core.control.modes import ModeManager
from enbarr_interfaces.modes import Mode
from enbarr_core.control.joy_layouts import get_layout, LAYOUTS, mapping_from_params

SAUCER = {k: v for k, v in
          load_profile('saucer_core', allow_fragment=True).parameters.items()
          if k.startswith('joy.')}
TAU_MAX = (1.0, 2.0, 0.5)
EXPECTED = {'triangle': Mode.AUTOMATIC, 'square': Mode.GUIDANCE}


def manager(layout: str) -> ModeManager:
    mapping, _ = mapping_from_params({**SAUCER, 'joy.layout': layout})
    return ModeManager(mapping, TAU_MAX)


def rest(layout: str) -> tuple[list[float], list[int]]:
    lay = get_layout(layout)
    return list(lay.rest), [0] * len(lay.buttons)


def test_the_saucer_names_its_layout_and_the_manuals_buttons():
    mapping, rule = mapping_from_params(SAUCER)
    assert SAUCER['joy.layout'] == 'enbarr_ds4' and rule == 'connection'
    lay = get_layout('enbarr_ds4')
    assert lay.buttons[mapping.button_automatic] == 'triangle'
    assert lay.buttons[mapping.button_guidance] == 'square'
    assert lay.buttons[mapping.button_manual] == 'cross'


def test_verified_orders():
    """The orders the drivers' sources give (see the module doc of layouts)."""
    assert get_layout('joydev').buttons[:4] == ('cross', 'circle', 'triangle', 'square')
    assert get_layout('ds4_driver').buttons[:4] == ('square', 'triangle', 'circle', 'cross')
    assert get_layout('joy').buttons[:4] == ('cross', 'circle', 'square', 'triangle')
    assert get_layout('enbarr_ds4') .buttons == get_layout('ds4_driver').buttons
    assert get_layout('ds4_driver').axes == ('left_x', 'left_y', 'right_x', 'right_y', 'l2',
                                             'r2')
    assert get_layout('joydev').axes[:6] == ('left_x', 'left_y', 'l2', 'right_x', 'right_y',
                                             'r2')
    assert get_layout('ds4_driver').publishes_on_change
    assert not get_layout('joy').publishes_on_change


@pytest.mark.parametrize('layout', list(LAYOUTS))
def test_every_button_of_every_layout(layout):
    """Only triangle, square and cross change the mode, each to its own."""
    names = get_layout(layout).buttons
    for i, name in enumerate(names):
        for start in (Mode.MANUAL, Mode.AUTOMATIC):
            m = manager(layout)
            axes, buttons = rest(layout)
            if start is Mode.AUTOMATIC:
                m.mode = Mode.AUTOMATIC
            m.on_joy(axes, buttons, 0.0, True, True)
            buttons[i] = 1
            m.on_joy(axes, buttons, 0.1, True, True)
            if name == 'cross':
                want = Mode.MANUAL
            else:
                want = EXPECTED.get(name, start)
            assert m.mode is want, f'{layout}: {name} (button {i}) from {start.value}'


@pytest.mark.parametrize('layout', list(LAYOUTS))
def test_every_axis_of_every_layout(layout):
    """Stick up/left is +1 in every preset: up = surge ahead, left = port, right stick left =
    counter-clockwise; the other axes (and a fully pressed trigger) drive nothing.
    """
    lay = get_layout(layout)
    want = {'left_y': [1.0 * 0.5, 0.0, 0.0], 'left_x': [0.0, 2.0 * 0.5, 0.0],
            'right_x': [0.0, 0.0, 0.5 * 0.5]}
    for i, name in enumerate(lay.axes):
        for value in (0.5, -1.0):
            m = manager(layout)
            axes, buttons = rest(layout)
            axes[i] = value
            m.on_joy(axes, buttons, 0.0, True, False)
            if name in want and value == 0.5:
                assert m.tau_manual.tolist() == pytest.approx(want[name]), f'{layout}: {name}'
            elif name in want:
                assert m.tau_manual.tolist() == pytest.approx(
                    [-2 * x for x in want[name]]), f'{layout}: {name}'
            else:
                assert not m.tau_manual.any(), f'{layout}: {name} drives something'


def test_a_minus_sign_flips_an_axis():
    mapping, _ = mapping_from_params({**SAUCER, 'joy.yaw': '-right_x'})
    m = ModeManager(mapping, TAU_MAX)
    axes, buttons = rest('enbarr_ds4')
    axes[2] = 0.5
    m.on_joy(axes, buttons, 0.0, True, False)
    assert m.tau_manual.tolist() == pytest.approx([0.0, 0.0, -0.25])


@pytest.mark.parametrize('dof, control', list(enumerate(('surge', 'sway', 'yaw'))))
def test_a_minus_sign_flips_its_own_axis_only(dof, control):
    mapping, _ = mapping_from_params({**SAUCER, f'joy.{control}': '-' + SAUCER[f'joy.{control}']})
    assert mapping.signs == tuple(-1.0 if i == dof else 1.0 for i in range(3))


@pytest.mark.parametrize('change, match', [
    ({'joy.layout': 'xbox'}, r"joy.layout: unknown layout 'xbox'; known: joydev, ds4_driver"),
    ({'joy.automatic': 'x'}, r"joy.automatic: 'x' is no button of layout enbarr_ds4"),
    ({'joy.yaw': 'right_z'}, r"joy.yaw: 'right_z' is no axis of layout enbarr_ds4"),
    ({'joy.guidance': ''}, r'joy.guidance: required with joy.layout'),
    ({'joy.guidance': 'triangle'}, r'joy: mode buttons must differ'),
    ({'joy.loss': 'rate'}, r'joy.loss: one of timeout, connection'),
    ({'joy.button_manual': 3}, r'joy.button_manual: give either joy.layout'),
    ({'joy.layout': ''}, r'joy.layout: name a layout'),
])
def test_bad_names_are_refused_naming_the_parameter(change, match):
    with pytest.raises(ValueError, match=match):
        mapping_from_params({**SAUCER, **change})


def test_the_index_form_still_works_for_pads_without_a_preset():
    mapping, rule = mapping_from_params({
        'joy.axis_surge': 1, 'joy.axis_sway': 0, 'joy.axis_yaw': 3, 'joy.button_automatic': 3,
        'joy.button_guidance': 2, 'joy.button_manual': 0})
    assert rule == 'timeout' and mapping.button_automatic == 3 and mapping.axis_yaw == 3
