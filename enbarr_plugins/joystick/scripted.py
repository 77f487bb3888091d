"""Scripted joystick: a DualShock 4 stand-in publishing ``sensor_msgs/Joy`` from a timed
script, so a run without a person exercises every mode. Lines, times in seconds from start::

    '0.0  sticks 0.5 0.0 0.0'   # surge, sway, yaw stick positions (-1..1), held
    '5.0  press triangle'       # press and release a button (triangle, square, cross, circle)
    '20.0 stop'                 # stop publishing: the joystick is lost

Axes and buttons are laid out as in ``Ds4Mapping`` (the ``joy_mapping`` parameters of the
controller must agree).
"""

from __future__ import annotations

import math
from typing import Any

from sensor_msgs.msg import Joy

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics

BUTTONS = {'cross': 0, 'circle': 1, 'triangle': 2, 'square': 3}
N_AXES, N_BUTTONS = 8, 13  # ds4_driver standard messages


def parse_joy_script(lines: list[str]) -> list[tuple[float, str, Any]]:
    out: list[tuple[float, str, Any]] = []
    for i, line in enumerate(lines):
        parts = line.split()
        if not parts:
            continue
        where = f'script[{i}] {line!r}'
        try:
            t = float(parts[0])
        except ValueError:
            raise ValueError(f'{where}: expected a time in seconds first') from None
        if not math.isfinite(t) or t < 0.0 or (out and t < out[-1][0]):
            raise ValueError(f'{where}: times must be finite, >= 0 and not decrease')
        kind = parts[1] if len(parts) > 1 else ''
        if kind == 'sticks' and len(parts) == 5:
            try:
                sticks = tuple(float(x) for x in parts[2:])
            except ValueError:
                raise ValueError(f'{where}: sticks takes 3 numbers') from None
            if not all(-1.0 <= x <= 1.0 for x in sticks):
                raise ValueError(f'{where}: stick positions are within -1..1')
            out.append((t, 'sticks', sticks))
        elif kind == 'press' and len(parts) == 3 and parts[2] in BUTTONS:
            out.append((t, 'press', BUTTONS[parts[2]]))
        elif kind == 'stop' and len(parts) == 2:
            out.append((t, 'stop', None))
        else:
            raise ValueError(f'{where}: expected "sticks S W Y", "press '
                             f'{"|".join(BUTTONS)}" or "stop"')
    return out


SPECS = [
    ParamSpec('script', [''], 'Timed joystick lines (see the module doc)', read_only=True,
              element=str),
    ParamSpec('rate', 20.0, 'Publication rate', 'Hz', 1.0, 1000.0, read_only=True),
]


class ScriptedJoyNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'joystick', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        v = self.bind_settings(SPECS, lambda v: (parse_joy_script(
            [x for x in v['script'] if x.strip()]), v['rate']), lambda _: None).settings
        self.script, rate = v
        self._next = 0
        self._sticks = (0.0, 0.0, 0.0)
        self._press: int | None = None
        self._stopped = False
        self._start_ns: int | None = None
        self._pub = self.create_topic_publisher(topics.JOY)
        self.create_timer(1.0 / rate, self._tick)

    def start(self) -> None:
        super().start()
        self._start_ns = self.get_clock().now().nanoseconds

    def _tick(self) -> None:
        if self._start_ns is None or self._stopped:
            return
        now = self.get_clock().now().nanoseconds
        elapsed = (now - self._start_ns) * 1e-9
        press = None
        while self._next < len(self.script) and self.script[self._next][0] <= elapsed:
            _, kind, value = self.script[self._next]
            self._next += 1
            if kind == 'sticks':
                self._sticks = value
            elif kind == 'press':
                press = value
            else:
                self._stopped = True
                return
        msg = Joy()
        convert.ns_to_stamp(now, msg.header.stamp)
        axes = [0.0] * N_AXES
        axes[1], axes[0], axes[3] = self._sticks  # surge, sway, yaw (Ds4Mapping defaults)
        msg.axes = axes
        buttons = [0] * N_BUTTONS
        if press is not None:
            buttons[press] = 1  # held for one sample: the next sample releases it
        msg.buttons = buttons
        self._pub.publish(msg)
