"""Joystick layouts as data: which ``sensor_msgs/Joy`` index carries which control of a pad.

Joystick drivers number the same DualShock 4 differently, so a profile names its driver's
layout and says which *named* control does what (``joy.layout: enbarr_ds4``,
``joy.automatic: triangle``, ``joy.surge: left_y`` ...). The presets, each checked in the
driver's source:

- ``joydev``: the kernel joydev API (``/dev/input/jsN``, read by ROS ``joy_linux``) over
  hid-playstation. joydev numbers axes by ABS code and buttons by key code starting at
  BTN_JOYSTICK (linux ``drivers/input/joydev.c``, ``joydev_connect``); hid-playstation gives
  the DS4 gamepad ABS_X, ABS_Y, ABS_Z (L2), ABS_RX, ABS_RY, ABS_RZ (R2), ABS_HAT0X/Y and
  BTN_SOUTH cross, BTN_EAST circle, BTN_NORTH triangle, BTN_WEST square, BTN_TL/TR,
  BTN_TL2/TR2, BTN_SELECT share, BTN_START options, BTN_MODE ps, BTN_THUMBL/R
  (``drivers/hid/hid-playstation.c``, ``ps_gamepad_buttons``, ``ps_gamepad_create``; the
  touchpad click is on the separate touchpad node). joy_linux scales by -1/32767
  (``joy_linux/src/joy_linux_node.cpp``), so up/left read +1 and a released trigger +1.
  It republishes at ``autorepeat_rate`` (20 Hz by default), stamped anew.
- ``ds4_driver``: naoki-mizuno/ds4_driver with ``use_standard_msgs``
  (``ds4_driver/ds4_driver/controller_ros.py``, ``_status_to_joy_``, humble-devel): axes
  [lx, ly, rx, ry, l2, r2], sticks negated "for consistency with other joypads" (up/left
  +1), triggers 0 (released) .. 1; 18 buttons [square, triangle, circle, cross, l1, l2, r1,
  r2, share, options, ps, trackpad, l3, r3, dpad left, up, right, down]. It publishes a
  ``Joy`` only when axes or buttons change (``autorepeat_rate`` 0 by default; a non-zero
  rate republishes the previous message with its old stamp), and has no connection state in a
  standard message: it needs the ``connection`` loss rule (see ``enbarr_core.control.modes``).
- ``joy``: ROS 2 ``joy`` ``game_controller_node`` (SDL game-controller mapping;
  ``joy/src/game_controller.cpp`` and ``joy/README.md``): axes [LEFTX, LEFTY, RIGHTX, RIGHTY,
  TRIGGERLEFT, TRIGGERRIGHT] scaled by -1/32767 (up/left +1, a pressed trigger -1), 21
  buttons [A cross, B circle, X square, Y triangle, BACK share, GUIDE ps, START options, L3,
  R3, L1, R1, dpad up, down, left, right, MISC1, PADDLE1-4, TOUCHPAD]; republished at
  ``autorepeat_rate`` (20 Hz by default), stamped anew.
- ``enbarr_ds4``: this package's evdev driver (``ds4_evdev``): ds4_driver's order and signs
  (so one profile serves both), the trackpad click always 0 (it is on the touchpad node),
  published at a steady heartbeat rate and on change, with ``joy/connected``.

Stick names are the same in every layout: ``left_x``, ``left_y``, ``right_x``, ``right_y``
(+1 = left/up in all four), ``l2``, ``r2`` (triggers; their range differs, see ``rest``).
A profile's axis name may carry a sign: ``-right_x`` makes stick right the positive way.
Pure data: no ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from enbarr_core.control.modes import JoyMapping, LOSS_RULES


@dataclass(frozen=True)
class JoyLayout:
    """The ``Joy`` layout one driver publishes for a DualShock 4."""

    name: str
    driver: str                         # who publishes it
    axes: tuple[str, ...]               # name of each axis index
    buttons: tuple[str, ...]            # name of each button index
    rest: tuple[float, ...]             # value of each axis at rest (triggers released)
    publishes_on_change: bool           # silent while nothing moves (no steady rate)
    loss_rule: str                      # default joystick-loss rule (modes.LOSS_RULES)

    def axis(self, spec: str) -> tuple[int, float]:
        """Return (index, sign) of an axis name, ``-name`` for the opposite sign."""
        sign = -1.0 if spec.startswith('-') else 1.0
        name = spec.lstrip('-+')
        if name not in self.axes:
            raise ValueError(f'{spec!r} is no axis of layout {self.name} (axes: '
                             f'{", ".join(self.axes)})')
        return self.axes.index(name), sign

    def button(self, name: str) -> int:
        """Return the index of a button name."""
        if name not in self.buttons:
            raise ValueError(f'{name!r} is no button of layout {self.name} (buttons: '
                             f'{", ".join(self.buttons)})')
        return self.buttons.index(name)


_DS4_DRIVER_BUTTONS = ('square', 'triangle', 'circle', 'cross', 'l1', 'l2', 'r1', 'r2',
                       'share', 'options', 'ps', 'trackpad', 'l3', 'r3', 'dpad_left',
                       'dpad_up', 'dpad_right', 'dpad_down')
_DS4_DRIVER_AXES = ('left_x', 'left_y', 'right_x', 'right_y', 'l2', 'r2')

LAYOUTS: dict[str, JoyLayout] = {layout.name: layout for layout in (
    JoyLayout(
        'joydev', 'joy_linux on the kernel joydev API (/dev/input/jsN)',
        ('left_x', 'left_y', 'l2', 'right_x', 'right_y', 'r2', 'dpad_x', 'dpad_y'),
        ('cross', 'circle', 'triangle', 'square', 'l1', 'r1', 'l2', 'r2', 'share', 'options',
         'ps', 'l3', 'r3'),
        (0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0), False, 'timeout'),
    JoyLayout(
        'ds4_driver', 'naoki-mizuno/ds4_driver (use_standard_msgs)', _DS4_DRIVER_AXES,
        _DS4_DRIVER_BUTTONS, (0.0,) * 6, True, 'connection'),
    JoyLayout(
        'joy', 'ROS 2 joy game_controller_node (SDL game controller)',
        ('left_x', 'left_y', 'right_x', 'right_y', 'l2', 'r2'),
        ('cross', 'circle', 'square', 'triangle', 'share', 'ps', 'options', 'l3', 'r3', 'l1',
         'r1', 'dpad_up', 'dpad_down', 'dpad_left', 'dpad_right', 'misc1', 'paddle1',
         'paddle2', 'paddle3', 'paddle4', 'trackpad'),
        (0.0,) * 6, False, 'timeout'),
    JoyLayout(
        'enbarr_ds4', 'enbarr ds4_evdev (Linux evdev)', _DS4_DRIVER_AXES, _DS4_DRIVER_BUTTONS,
        (0.0,) * 6, False, 'connection'),
)}


def get_layout(name: str) -> JoyLayout:
    """Return the preset ``name``; ValueError listing the known ones."""
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f'unknown layout {name!r}; known: {", ".join(LAYOUTS)}') from None


#: Controls a profile names (``joy.<control>``) in the layout form.
AXIS_CONTROLS = ('surge', 'sway', 'yaw')
BUTTON_CONTROLS = ('automatic', 'guidance', 'manual')
#: The index form (a pad no preset describes): ``joy.axis_<dof>`` / ``joy.button_<mode>``.
INDEX_PARAMETERS = ('axis_surge', 'axis_sway', 'axis_yaw', 'button_automatic',
                    'button_guidance', 'button_manual')


def mapping_from_params(v: Mapping[str, Any], deadzone: float = 0.05) -> tuple[JoyMapping, str]:
    """Build the ``JoyMapping`` and loss rule from a node's ``joy.*`` parameter values.

    Either the layout form (``joy.layout`` with ``joy.surge/sway/yaw`` axis names and
    ``joy.automatic/guidance/manual`` button names) or the index form (``joy.axis_*`` and
    ``joy.button_*``, -1 = unset); ``joy.loss`` ('' = the layout's rule, ``timeout`` for the
    index form). ValueError naming the parameter.
    """
    name = v.get('joy.layout', '')
    indices = {k: v.get(f'joy.{k}', -1) for k in INDEX_PARAMETERS}
    given = [k for k, i in indices.items() if i is not None and i >= 0]
    if name:
        if given:
            raise ValueError(f'joy.{given[0]}: give either joy.layout with named controls or '
                             'the joy.axis_*/joy.button_* indices, not both')
        try:
            layout = get_layout(name)
        except ValueError as err:
            raise ValueError(f'joy.layout: {err}') from err
        axes, signs, buttons = [], [], []
        for control in AXIS_CONTROLS + BUTTON_CONTROLS:
            spec = v.get(f'joy.{control}', '')
            if not spec:
                kind = 'an axis' if control in AXIS_CONTROLS else 'a button'
                raise ValueError(f'joy.{control}: required with joy.layout ({kind} of {name})')
            try:
                if control in AXIS_CONTROLS:
                    index, sign = layout.axis(spec)
                    axes.append(index)
                    signs.append(sign)
                else:
                    buttons.append(layout.button(spec))
            except ValueError as err:
                raise ValueError(f'joy.{control}: {err}') from err
        mapping = JoyMapping(**dict(zip(INDEX_PARAMETERS, axes + buttons)), deadzone=deadzone,
                             signs=(signs[0], signs[1], signs[2]))
        default_rule = layout.loss_rule
    else:
        missing = [k for k in INDEX_PARAMETERS if k not in given]
        if missing:
            raise ValueError(f'joy.layout: name a layout ({", ".join(LAYOUTS)}) with '
                             f'joy.{", joy.".join(AXIS_CONTROLS + BUTTON_CONTROLS)}, or give '
                             f'the indices (joy.{missing[0]} is missing)')
        mapping = JoyMapping(**indices, deadzone=deadzone)
        default_rule = 'timeout'
    rule = v.get('joy.loss', '') or default_rule
    if rule not in LOSS_RULES:
        raise ValueError(f'joy.loss: one of {", ".join(LOSS_RULES)} (or empty), got {rule!r}')
    try:
        mapping.validate()
    except ValueError as err:
        raise ValueError(f'joy: {err}') from err
    return mapping, rule
