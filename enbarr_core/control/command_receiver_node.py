"""Command receiver: surface commands -> velocity goal and io requests.

Surface commands become ``trajectory_request`` (the velocity goal) and ``io_request``.

Velocity commands (``surface_command/twist``) pass through ``CommandGate``: non-finite,
out-of-range, stale, future-stamped, out-of-order ones and those in a frame other than
``base_link`` (an empty ``frame_id`` counts as ``base_link``) are refused and counted, never
passed on. The goal is republished at ``rate`` and falls to zero after ``timeout`` without an
accepted command (a ``timeout`` shorter than two measured command periods is refused when set
live, and an ERROR on ``/diagnostics`` when it was the start value). IO requests
(``surface_command/io``) are forwarded when they name an executor and carry a finite typed
value; the failsafe does not touch IO (lights and manipulator hold).

One source at a time (``framework.sources``): while more than one publisher is matched on
``surface_command/twist`` or ``surface_command/io``, their messages are refused and counted as
``contested``, a contested twist drops the goal to zero at once, and ``/diagnostics`` says
ERROR naming the publishers. Counters go to ``/diagnostics`` every second; the node is
degraded when it refuses more than 5 % of a second's commands.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import re
from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter, ParameterType

from enbarr_interfaces import convert, topics

from enbarr_core.control.command_gate import CommandGate, GateSettings, Verdict
from enbarr_core.framework.health import (
    ERROR, InputHealth, IntervalMeter, too_short_for_rate, worst)
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.sources import SourceGuard

SPECS = [
    ParamSpec('max_linear', 1.0, 'Largest accepted linear velocity component', 'm/s', 0.0,
              20.0),
    ParamSpec('max_angular', 1.0, 'Largest accepted angular velocity component', 'rad/s',
              0.0, 20.0),
    ParamSpec('timeout', 0.5, 'No accepted command for this long -> zero velocity goal', 's',
              0.01, 60.0),
    ParamSpec('max_age', 0.5, 'Commands stamped earlier than this are stale', 's', 0.0, 60.0),
    ParamSpec('max_future', 0.05, 'Commands stamped later than now + this are refused', 's',
              0.0, 60.0),
    ParamSpec('rate', 10.0, 'Rate at which the goal is republished', 'Hz', 1.0, 1000.0,
              read_only=True),
]
#: Goal stamps that would repeat (or go back by at most this, [ns]) are bumped by 1 ns.
_BUMP_NS = 1_000_000
_EXECUTOR = re.compile(r'^[A-Za-z][A-Za-z0-9_/]*$')
#: Window of the diagnostics report [s].
REPORT_PERIOD = 1.0


@dataclass(frozen=True)
class CommandReceiverSettings:
    """Settings of ``CommandReceiverNode`` (see ``SPECS``)."""

    gate: GateSettings  # limits, staleness and failsafe timeout of velocity commands
    rate: float         # goal republishing rate [Hz]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> CommandReceiverSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        gate = GateSettings(max_linear=v['max_linear'], max_angular=v['max_angular'],
                            timeout=v['timeout'], max_age=v['max_age'],
                            max_future=v['max_future'])
        gate.validate()
        return cls(gate=gate, rate=v['rate'])


class CommandReceiverNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'command_receiver', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.gate = CommandGate()
        self.io_forwarded = 0
        self.io_rejected = 0
        self.io_contested = 0
        self.health = InputHealth()
        self.period = IntervalMeter()  # of accepted surface_command/twist stamps
        self._failsafe = True
        self._last_goal_ns = -1
        self.settings: CommandReceiverSettings
        self.bind_settings(SPECS, self._build, self._apply)
        self._goal_pub = self.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self._io_pub = self.create_topic_publisher(topics.IO_REQUEST)
        # One-argument callbacks: the EventsExecutor of bringup (rclpy 7.1) passes no
        # MessageInfo, so the guards judge by the matched publisher count (framework.sources).
        self.twist_guard = SourceGuard(self, self.create_topic_subscription(
            topics.SURFACE_TWIST, self._on_twist))
        self.io_guard = SourceGuard(self, self.create_topic_subscription(
            topics.SURFACE_IO, self._on_io))
        self.create_timer(1.0 / self.settings.rate, self._publish_goal)
        self.create_periodic(REPORT_PERIOD, self._report)

    def _build(self, v: Mapping[str, Any]) -> CommandReceiverSettings:
        settings = CommandReceiverSettings.from_params(v)
        reason = self._timeout_too_short(settings.gate.timeout)
        if reason:
            raise ValueError(reason)
        return settings

    def _timeout_too_short(self, timeout: float) -> str | None:
        """Why ``timeout`` [s] is too short for the measured command period, or None."""
        return too_short_for_rate('timeout', timeout, topics.SURFACE_TWIST.name,
                                  self.period.period, 'the goal would drop to zero between '
                                  'commands')

    def _apply(self, settings: CommandReceiverSettings) -> None:
        self.settings = settings
        self.gate.settings = settings.gate

    def _now(self) -> int:
        return self.now_ns()

    def _on_twist(self, msg: TwistStamped) -> None:
        if self.twist_guard.contested():
            self.gate.withdraw(Verdict.CONTESTED)  # zero goal now, not after the timeout
            self.health.refused('surface_command/twist', Verdict.CONTESTED.value)
            self.get_logger().error(self.twist_guard.status()[1], throttle_duration_sec=1.0)
            self._publish_goal()
            return
        now = self._now()
        verdict = self.gate.offer(convert.twist_to_nu(msg.twist),
                                  convert.stamp_to_ns(msg.header.stamp), now,
                                  msg.header.frame_id)
        if verdict is not Verdict.ACCEPTED:
            self.health.refused('surface_command/twist', verdict.value)
            why = (f'frame {msg.header.frame_id!r}, expected {topics.BODY_FRAME!r}'
                   if verdict is Verdict.WRONG_FRAME else verdict.value)
            self.get_logger().warn(f'refused surface command ({why})',
                                   throttle_duration_sec=1.0)
            return
        self.health.accepted('surface_command/twist')
        self.period.add(convert.stamp_to_ns(msg.header.stamp))
        self._publish_goal()

    def _on_io(self, msg: Parameter) -> None:
        reason = None
        if self.io_guard.contested():
            self.io_contested += 1
            self.health.refused('surface_command/io', 'contested')
            self.get_logger().error(self.io_guard.status()[1], throttle_duration_sec=1.0)
            return
        if not _EXECUTOR.match(msg.name):
            reason = f'executor name {msg.name!r} is not valid'
        elif msg.value.type == ParameterType.PARAMETER_NOT_SET:
            reason = 'value is not set'
        elif not convert.parameter_value_is_finite(msg.value):
            reason = 'value is not finite'
        if reason:
            self.io_rejected += 1
            self.health.refused('surface_command/io', 'invalid')
            self.get_logger().warn(f'refused io request: {reason}', throttle_duration_sec=1.0)
            return
        self.health.accepted('surface_command/io')
        self.io_forwarded += 1
        self._io_pub.publish(msg)

    def _publish_goal(self) -> None:
        now = self._now()
        goal = self.gate.current_goal(now)
        failsafe = self.gate.failsafe(now)
        if failsafe and not self._failsafe:
            self.get_logger().warn('surface commands lost: velocity goal set to zero')
        self._failsafe = failsafe
        # Goal stamps strictly increase: the controller's time policy refuses a repeat, and at
        # a standing simulated clock the timer and an accepted command publish at one instant.
        # A clock that went back (a restarted simulation) starts the stamps over.
        last = self._last_goal_ns
        stamp = last + 1 if last - _BUMP_NS <= now <= last else now
        self._last_goal_ns = stamp
        msg = TwistStamped()
        convert.ns_to_stamp(stamp, msg.header.stamp)
        msg.header.frame_id = topics.BODY_FRAME
        convert.set_twist(msg.twist, goal)
        self._goal_pub.publish(msg)

    def _report(self) -> None:
        counts = {v.value: n for v, n in self.gate.counts.items()}
        health = self.health.report(REPORT_PERIOD)
        failsafe = (1, 'failsafe: no surface command') if self._failsafe else (0, 'ok')
        reason = self._timeout_too_short(self.gate.settings.timeout)
        rate = (ERROR, reason) if reason else (0, 'ok')
        level, message = worst(self.twist_guard.status(), self.io_guard.status(),
                               failsafe, health[:2], rate)
        self.publish_diagnostics(level, message, {
            **counts, 'io_forwarded': self.io_forwarded, 'io_rejected': self.io_rejected,
            'io_contested': self.io_contested, 'failsafe': self._failsafe, **health[2]})
