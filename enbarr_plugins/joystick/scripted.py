"""Scripted joystick: a game-controller stand-in publishing ``sensor_msgs/Joy`` from a script.

A run without a person exercises every mode this way. Lines, times in seconds from start::

    '0.0  sticks 0.5 0.0 0.0'   # surge, sway, yaw stick positions (-1..1), held
    '5.0  press triangle'       # press and release a button named in ``buttons``
    '20.0 stop'                 # joy/connected False, then silence: the joystick is lost

It publishes in the profile's layout, shared with the controller (given once in the
profile): ``joy.layout`` names a preset of ``layouts`` (its button names, axis count and
rest values) and ``joy.surge``, ``joy.sway``, ``joy.yaw`` name the sticks (``-name``: the
other way). Without ``joy.layout``, ``joy.buttons`` names the button at each index and
``joy.axis_surge``, ``joy.axis_sway``, ``joy.axis_yaw`` give the stick indices. Like a
driver, it keeps ``joy/connected`` (latched) True with every sample, so the controller's
``connection`` loss rule works against it too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sensor_msgs.msg import Joy
from std_msgs.msg import Bool

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_core.control.joy_layouts import AXIS_CONTROLS, get_layout, LAYOUTS
from enbarr_plugins.operator.script import no_arguments, numbers, parse_script, Step

N_AXES, N_BUTTONS = 8, 13  # without joy.layout: at least this many (a DS4 via joydev)


def parse_joy_script(lines: Sequence[str], buttons: Mapping[str, int]) -> tuple[Step, ...]:
    """Parse ``lines`` into timed steps; ``buttons`` maps a button name to its index.

    Verbs: ``sticks S W Y`` (three positions within -1..1), ``press NAME`` (the button's
    index) and ``stop``; errors name the line (``operator.script.parse_script``).
    """
    def press(args: Sequence[str]) -> int:
        if len(args) != 1 or args[0] not in buttons:
            raise ValueError(f'takes one button name of {"|".join(buttons)}')
        return buttons[args[0]]

    return parse_script(lines, {
        'sticks': lambda args: numbers(args, 3, '(surge, sway, yaw)', -1.0, 1.0),
        'press': press,
        'stop': no_arguments,
    })


SPECS = [
    ParamSpec('script', [''], 'Timed joystick lines (see the module doc)', read_only=True,
              element=str),
    ParamSpec('rate', 20.0, 'Publication rate', 'Hz', 1.0, 1000.0, read_only=True),
    ParamSpec('joy.layout', '', 'Layout to publish in: ' + ', '.join(LAYOUTS)
              + ' (empty: joy.buttons and joy.axis_*)', read_only=True),
    *(ParamSpec(f'joy.{dof}', '', f'Axis name of the {dof} stick in joy.layout',
                read_only=True) for dof in AXIS_CONTROLS),
    ParamSpec('joy.buttons', [''], 'Name of the button at each index (without joy.layout)',
              read_only=True, element=str),
    *(ParamSpec(f'joy.axis_{dof}', -1, f'Axis of the {dof} stick (without joy.layout)', '',
                -1, 64, read_only=True) for dof in AXIS_CONTROLS),
]


@dataclass(frozen=True)
class ScriptedJoySettings:
    """Settings of ``ScriptedJoyNode`` (see ``SPECS``)."""

    script: tuple[Step, ...]                    # timed sticks/press/stop steps
    rate: float                                 # [Hz]
    buttons: tuple[str, ...]                    # name of each button index
    axes: tuple[int, int, int]                  # surge, sway, yaw axis indices
    signs: tuple[float, float, float]           # +1/-1: stick value -> axis value
    rest: tuple[float, ...]                     # every axis at rest (its length: the count)

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> ScriptedJoySettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if v['joy.layout']:
            try:
                layout = get_layout(v['joy.layout'])
            except ValueError as err:
                raise ValueError(f'joy.layout: {err}') from err
            axes, signs = [], []
            for dof in AXIS_CONTROLS:
                try:
                    index, sign = layout.axis(v[f'joy.{dof}'])
                except ValueError as err:
                    raise ValueError(f'joy.{dof}: {err}') from err
                axes.append(index)
                signs.append(sign)
            names, rest = list(layout.buttons), layout.rest
        else:
            names = [n for n in v['joy.buttons'] if n]
            if not names:
                raise ValueError('joy.layout: name a layout, or give joy.buttons and joy.axis_*')
            if len(names) != len(v['joy.buttons']) or len(set(names)) != len(names):
                raise ValueError(f'joy.buttons: expected distinct non-empty names, got '
                                 f'{list(v["joy.buttons"])}')
            axes = [v[f'joy.axis_{dof}'] for dof in AXIS_CONTROLS]
            for dof, index in zip(AXIS_CONTROLS, axes):
                if index < 0:
                    raise ValueError(f'joy.axis_{dof}: required without joy.layout')
            signs, rest = [1.0] * 3, (0.0,) * max(N_AXES, max(axes) + 1)
        if len(set(axes)) != 3:
            raise ValueError(f'joy.axis_surge, joy.axis_sway, joy.axis_yaw: expected 3 '
                             f'different axes, got {axes}')
        try:
            script = parse_joy_script([x for x in v['script'] if x.strip()],
                                      {n: i for i, n in enumerate(names)})
        except ValueError as err:
            raise ValueError(f'script: {err}') from err
        return cls(script, v['rate'], tuple(names), tuple(axes),  # type: ignore[arg-type]
                   tuple(signs), tuple(rest))  # type: ignore[arg-type]


class ScriptedJoyNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'joystick', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: ScriptedJoySettings
        self.bind_settings(SPECS, ScriptedJoySettings.from_params, self._apply)
        s = self.settings
        self.script = list(s.script)
        self._n_buttons = max(N_BUTTONS, len(s.buttons))
        self._next = 0
        self._sticks = (0.0, 0.0, 0.0)
        self._press: int | None = None
        self._stopped = False
        self._start_ns: int | None = None
        self._pub = self.create_topic_publisher(topics.JOY)
        self._connected_pub = self.create_topic_publisher(topics.JOY_CONNECTED)
        self.create_source_timer(1.0 / s.rate, self._tick)

    def _apply(self, settings: ScriptedJoySettings) -> None:
        self.settings = settings

    def start(self) -> None:
        """Start the script's clock now."""
        super().start()
        self._start_ns = self.now_ns()

    def _tick(self) -> None:
        if self._start_ns is None or self._stopped:
            return
        now = self.now_ns()
        elapsed = (now - self._start_ns) * 1e-9
        press = None
        while self._next < len(self.script) and self.script[self._next].time <= elapsed:
            step = self.script[self._next]
            self._next += 1
            if step.verb == 'sticks':
                self._sticks = step.value
            elif step.verb == 'press':
                press = step.value
            else:
                self._stopped = True
                self._connected_pub.publish(Bool(data=False))
                return
        self._connected_pub.publish(Bool(data=True))
        msg = Joy()
        convert.ns_to_stamp(now, msg.header.stamp)
        axes = list(self.settings.rest)
        for i, sign, value in zip(self.settings.axes, self.settings.signs, self._sticks):
            axes[i] = sign * value
        msg.axes = axes
        buttons = [0] * self._n_buttons
        if press is not None:
            buttons[press] = 1  # held for one sample: the next sample releases it
        msg.buttons = buttons
        self._pub.publish(msg)
