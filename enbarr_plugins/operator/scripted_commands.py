"""Scripted surface commands: an operator stand-in for runs without a person.

The ``script`` parameter is a list of timed lines, times in seconds from the start::

    '0.0  twist 0.0 0.0 -0.2 0.0 0.0 0.0'    # velocity goal u v w p q r [m/s, rad/s]
    '4.0  io gpio_12 true'                   # io request: executor, value (YAML scalar)
    '9.0  stop'                              # stop sending velocity commands

The current velocity goal is sent at ``rate`` with a fresh stamp, as a surface station does;
after ``stop`` nothing more is sent, so the command receiver's failsafe takes over.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter
import yaml

from enbarr_interfaces import convert, topics

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec


@dataclass(frozen=True)
class ScriptLine:
    time: float
    kind: str  # 'twist', 'io' or 'stop'
    nu: tuple[float, ...] = ()
    executor: str = ''
    value: Any = None


def parse_script(lines: list[str]) -> list[ScriptLine]:
    """Parse and check a script; ``ValueError`` names the entry and what is wrong."""
    out: list[ScriptLine] = []
    for i, line in enumerate(lines):
        where = f'script[{i}] {line!r}'
        parts = line.split()
        if not parts:
            continue
        try:
            t = float(parts[0])
        except ValueError:
            raise ValueError(f'{where}: expected a time in seconds first') from None
        if not math.isfinite(t) or t < 0.0:
            raise ValueError(f'{where}: time must be finite and >= 0')
        if out and t < out[-1].time:
            raise ValueError(f'{where}: times must not decrease')
        kind = parts[1] if len(parts) > 1 else ''
        if kind == 'twist':
            try:
                nu = tuple(float(x) for x in parts[2:])
            except ValueError:
                raise ValueError(f'{where}: twist takes 6 numbers u v w p q r') from None
            if len(nu) != 6 or not all(math.isfinite(x) for x in nu):
                raise ValueError(f'{where}: twist takes 6 finite numbers u v w p q r')
            out.append(ScriptLine(t, 'twist', nu=nu))
        elif kind == 'io':
            if len(parts) != 4:
                raise ValueError(f'{where}: io takes an executor and one value')
            value = yaml.safe_load(parts[3])
            try:
                convert.python_to_parameter_value(value)
            except TypeError:
                raise ValueError(f'{where}: value {parts[3]!r} is not a bool, int, float or '
                                 'string') from None
            out.append(ScriptLine(t, 'io', executor=parts[2], value=value))
        elif kind == 'stop' and len(parts) == 2:
            out.append(ScriptLine(t, 'stop'))
        else:
            raise ValueError(f'{where}: expected "twist", "io" or "stop" after the time')
    return out


SPECS = [
    ParamSpec('script', [''], 'Timed command lines (see the module doc)', read_only=True,
              element=str),
    ParamSpec('rate', 10.0, 'Rate at which the current velocity goal is sent', 'Hz', 0.1,
              1000.0, read_only=True),
]


class ScriptedCommandsNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'surface', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        v = self.bind_settings(SPECS, self._build, lambda _: None).settings
        self.script: list[ScriptLine] = v[0]
        self._next = 0
        self._nu: tuple[float, ...] | None = None
        self._start_ns: int | None = None
        self._twist_pub = self.create_topic_publisher(topics.SURFACE_TWIST)
        self._io_pub = self.create_topic_publisher(topics.SURFACE_IO)
        self.create_timer(1.0 / v[1], self._tick)

    @staticmethod
    def _build(v: dict[str, Any]) -> tuple[list[ScriptLine], float]:
        return parse_script([line for line in v['script'] if line.strip()]), v['rate']

    @property
    def finished(self) -> bool:
        return self._next >= len(self.script) and self._nu is None

    def start(self) -> None:
        super().start()
        self._start_ns = self.get_clock().now().nanoseconds

    def _tick(self) -> None:
        if self._start_ns is None:
            return
        now = self.get_clock().now().nanoseconds
        elapsed = (now - self._start_ns) * 1e-9
        while self._next < len(self.script) and self.script[self._next].time <= elapsed:
            line = self.script[self._next]
            self._next += 1
            if line.kind == 'twist':
                self._nu = line.nu
            elif line.kind == 'stop':
                self._nu = None
            else:
                self._io_pub.publish(Parameter(
                    name=line.executor, value=convert.python_to_parameter_value(line.value)))
                self.get_logger().info(f'io request {line.executor} = {line.value!r}')
        if self._nu is not None:
            msg = TwistStamped()
            convert.ns_to_stamp(now, msg.header.stamp)
            msg.header.frame_id = topics.BODY_FRAME
            convert.set_twist(msg.twist, self._nu)
            self._twist_pub.publish(msg)
