"""Scripted surface commands: an operator stand-in for runs without a person.

The ``script`` parameter is a list of timed lines, times in seconds from the start::

    '0.0  twist 0.0 0.0 -0.2 0.0 0.0 0.0'    # velocity goal u v w p q r [m/s, rad/s]
    '4.0  io gpio_12 true'                   # io request: executor, value (YAML scalar)
    '9.0  stop'                              # stop sending velocity commands

An io value is read as a profile's values are (YAML 1.2: ``1e3`` is a number). A line's note
(``# text`` after the step, ``operator.script``) is logged with the step when it plays.

The current velocity goal is sent at ``rate`` with a fresh stamp, as a surface station does;
after ``stop`` nothing more is sent, so the command receiver's failsafe takes over.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter

from enbarr_interfaces import convert, topics

from enbarr_core.framework import yaml12
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.operator.script import Step, no_arguments, numbers, parse_script


@dataclass(frozen=True)
class IoRequest:
    """What an ``io`` line asks: set ``executor`` to ``value``."""

    executor: str
    value: Any  # bool, int, float or str


def _io(args: Sequence[str]) -> IoRequest:
    if len(args) != 2:
        raise ValueError('takes an executor and one value')
    value = yaml12.load(args[1])   # as a profile or --set reads a value: 1e3 is a number
    try:
        convert.python_to_parameter_value(value)
    except TypeError:
        raise ValueError(f'value {args[1]!r} is not a bool, int, float or string') from None
    return IoRequest(args[0], value)


#: The verbs of a surface script and the typed value each step carries.
VERBS = {
    'twist': lambda args: numbers(args, 6, 'u v w p q r'),  # velocity goal [m/s, rad/s]
    'io': _io,                                              # IoRequest
    'stop': no_arguments,                                   # None
}


@dataclass(frozen=True)
class ScriptedCommandsSettings:
    """Settings of ``ScriptedCommandsNode`` (see ``SPECS``)."""

    script: tuple[Step, ...]  # parsed, in time order
    rate: float               # rate of the velocity goal [Hz]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> ScriptedCommandsSettings:
        """Build from the declared parameters' values; ``ValueError`` names the line."""
        return cls(script=parse_script(v['script'], VERBS), rate=v['rate'])


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
        self.settings: ScriptedCommandsSettings
        self.bind_settings(SPECS, ScriptedCommandsSettings.from_params, self._apply)
        self.script = self.settings.script
        self._next = 0
        self._nu: tuple[float, ...] | None = None
        self._start_ns: int | None = None
        self._twist_pub = self.create_topic_publisher(topics.SURFACE_TWIST)
        self._io_pub = self.create_topic_publisher(topics.SURFACE_IO)
        self.create_source_timer(1.0 / self.settings.rate, self._tick)

    def _apply(self, settings: ScriptedCommandsSettings) -> None:
        self.settings = settings

    @property
    def finished(self) -> bool:
        """Whether every step was played and no goal is being sent."""
        return self._next >= len(self.script) and self._nu is None

    def start(self) -> None:
        """Start the script clock."""
        super().start()
        self._start_ns = self.now_ns()

    def _tick(self) -> None:
        if self._start_ns is None:
            return
        now = self.now_ns()
        elapsed = (now - self._start_ns) * 1e-9
        while self._next < len(self.script) and self.script[self._next].time <= elapsed:
            step = self.script[self._next]
            self._next += 1
            note = f' ({step.note})' if step.note else ''
            if step.verb == 'twist':
                self._nu = step.value
            elif step.verb == 'stop':
                self._nu = None
            else:
                io: IoRequest = step.value
                self._io_pub.publish(Parameter(
                    name=io.executor, value=convert.python_to_parameter_value(io.value)))
                self.get_logger().info(f'io request {io.executor} = {io.value!r}{note}')
                continue
            if note:
                self.get_logger().info(f'{step.verb} at {step.time:g} s{note}')
        if self._nu is not None:
            msg = TwistStamped()
            convert.ns_to_stamp(now, msg.header.stamp)
            msg.header.frame_id = topics.BODY_FRAME
            convert.set_twist(msg.twist, self._nu)
            self._twist_pub.publish(msg)
