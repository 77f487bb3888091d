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

Named command sources (``sources.*`` parameters, ``control.arbitration``), in the manner of
ROS's ``twist_mux``: each source has its own topic (instead of ``surface_command/twist``),
priority and timeout, its own ``CommandGate`` (the node's limits, the source's timeout) and its
own single-source guard, so two publishers on one source's topic are refused as above (and
that source stops driving at once) while the others go on. The highest-priority live source
drives; when none is live the goal is zero (the failsafe; ``timeout`` is then unused, each
source's own applies). ``surface_command/stop`` (true) holds the goal at zero whatever any
source sends, until false. Which source drives (a name, ``stop`` or ``none``) is published on
``surface_command/active_source`` (latched) and in ``/diagnostics`` (``active_source``).
Without ``sources`` the node is as above: one source on ``surface_command/twist``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import re
from typing import Any

from geometry_msgs.msg import TwistStamped
import numpy as np
from rcl_interfaces.msg import Parameter, ParameterType
from std_msgs.msg import Bool, String

from enbarr_interfaces import convert, topics

from enbarr_core.control.arbitration import Arbiter, ArbiterSettings, STOPPED
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
    # Named command sources (control.arbitration), as parallel arrays: ROS 2 parameters hold
    # no list of records. Left at [''] (the default): one source on surface_command/twist.
    ParamSpec('sources.names', [''], 'Names of the command sources, one per entry of the '
              "other sources.* arrays; [''] = none (surface_command/twist alone)",
              read_only=True, element=str),
    ParamSpec('sources.topics', [''], 'Velocity command topic of each source (its own)',
              read_only=True, element=str),
    ParamSpec('sources.priorities', [0], 'Priority of each source: the highest live one '
              'drives', '', -1000, 1000, read_only=True, element=int),
    ParamSpec('sources.timeouts', [0.0], 'A source is live while its last accepted command '
              'is no older than this', 's', 0.0, 60.0, read_only=True, element=float),
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
    sources: ArbiterSettings | None = None  # named sources; None: surface_command/twist alone

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> CommandReceiverSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        gate = GateSettings(max_linear=v['max_linear'], max_angular=v['max_angular'],
                            timeout=v['timeout'], max_age=v['max_age'],
                            max_future=v['max_future'])
        gate.validate()
        sources = None
        if list(v['sources.names']) != [''] or list(v['sources.topics']) != ['']:
            sources = ArbiterSettings.from_arrays(
                v['sources.names'], v['sources.topics'], v['sources.priorities'],
                v['sources.timeouts'])
        return cls(gate=gate, rate=v['rate'], sources=sources)


class CommandReceiverNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'command_receiver', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.gate = CommandGate()  # surface_command/twist's, without named sources
        self.gates: dict[str, CommandGate] = {}  # each named source's
        self.source_guards: dict[str, SourceGuard] = {}
        self.arbiter: Arbiter | None = None
        self.io_forwarded = 0
        self.io_rejected = 0
        self.io_contested = 0
        self.health = InputHealth()
        self.period = IntervalMeter()  # of accepted surface_command/twist stamps
        self._failsafe = True
        self._last_goal_ns = -1
        self._active = ''
        self.settings: CommandReceiverSettings
        self.bind_settings(SPECS, self._build, self._apply)
        self._goal_pub = self.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self._io_pub = self.create_topic_publisher(topics.IO_REQUEST)
        # One-argument callbacks: the EventsExecutor of bringup (rclpy 7.1) passes no
        # MessageInfo, so the guards judge by the matched publisher count (framework.sources).
        sources = self.settings.sources
        if sources is None:
            self.twist_guard: SourceGuard | None = SourceGuard(
                self, self.create_topic_subscription(topics.SURFACE_TWIST, self._on_twist))
        else:
            self.twist_guard = None
            self.arbiter = arbiter = Arbiter(sources)
            for src in sources.sources:
                self.gates[src.name] = CommandGate(replace(self.settings.gate,
                                                           timeout=src.timeout))
                # Each source's topic has the contract of surface_command/twist (on DDS).
                sub = self.create_topic_subscription(
                    replace(topics.SURFACE_TWIST, name=src.topic),
                    lambda msg, name=src.name: self._on_source(arbiter, name, msg))
                self.source_guards[src.name] = SourceGuard(self, sub)
            self.stop_guard = SourceGuard(self, self.create_topic_subscription(
                topics.SURFACE_STOP, lambda msg: self._on_stop(arbiter, msg)))
            self._active_pub = self.create_topic_publisher(topics.SURFACE_ACTIVE_SOURCE)
        self.io_guard = SourceGuard(self, self.create_topic_subscription(
            topics.SURFACE_IO, self._on_io))
        self.create_timer(1.0 / self.settings.rate, self._publish_goal)
        self.create_periodic(REPORT_PERIOD, self._report)
        if self.arbiter is not None:
            self._publish_goal()  # a late joiner of active_source learns "none" at once

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
        for src in settings.sources.sources if settings.sources else ():
            if src.name in self.gates:  # sources are read-only: the same ones every time
                self.gates[src.name].settings = replace(settings.gate, timeout=src.timeout)

    def _now(self) -> int:
        return self.now_ns()

    def _on_twist(self, msg: TwistStamped) -> None:
        if self.twist_guard is None:  # not subscribed with named sources: never called
            return
        verdict = self._offer(msg, self.gate, self.twist_guard, topics.SURFACE_TWIST.name)
        if verdict is Verdict.ACCEPTED:
            self.period.add(convert.stamp_to_ns(msg.header.stamp))
        if verdict in (Verdict.ACCEPTED, Verdict.CONTESTED):
            self._publish_goal()

    def _on_source(self, arbiter: Arbiter, name: str, msg: TwistStamped) -> None:
        gate = self.gates[name]
        guard = self.source_guards[name]
        verdict = self._offer(msg, gate, guard, guard.topic)
        if verdict is Verdict.ACCEPTED and gate.last_accept_ns is not None:
            arbiter.offer(name, gate.last_accept_ns)  # the gate's time: one clock
        elif verdict is Verdict.CONTESTED:
            arbiter.withdraw(name)  # the next live source takes over now
        else:
            return
        self._publish_goal()

    def _offer(self, msg: TwistStamped, gate: CommandGate, guard: SourceGuard,
               topic: str) -> Verdict:
        """Judge one velocity command for ``gate``: contested (its goal dropped) or the verdict."""
        if guard.contested():
            gate.withdraw(Verdict.CONTESTED)  # zero goal now, not after the timeout
            self.health.refused(topic, Verdict.CONTESTED.value)
            self.get_logger().error(guard.status()[1], throttle_duration_sec=1.0)
            return Verdict.CONTESTED
        verdict = gate.offer(convert.twist_to_nu(msg.twist),
                             convert.stamp_to_ns(msg.header.stamp), self._now(),
                             msg.header.frame_id)
        if verdict is not Verdict.ACCEPTED:
            self.health.refused(topic, verdict.value)
            why = (f'frame {msg.header.frame_id!r}, expected {topics.BODY_FRAME!r}'
                   if verdict is Verdict.WRONG_FRAME else verdict.value)
            what = 'surface command' if self.arbiter is None else f'command on {topic}'
            self.get_logger().warn(f'refused {what} ({why})',
                                   throttle_duration_sec=1.0)
            return verdict
        self.health.accepted(topic)
        return verdict

    def _on_stop(self, arbiter: Arbiter, msg: Bool) -> None:
        # A stop is taken from anyone (two stations both stopping is still a stop); a release
        # only from a single publisher, as any command.
        if not msg.data and self.stop_guard.contested():
            self.health.refused(topics.SURFACE_STOP.name, Verdict.CONTESTED.value)
            self.get_logger().error(self.stop_guard.status()[1], throttle_duration_sec=1.0)
            return
        if msg.data != arbiter.stopped:
            self.get_logger().warn('station stop set: velocity goal held at zero' if msg.data
                                   else 'station stop released')
        arbiter.set_stop(msg.data)
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
        if self.arbiter is None:
            goal = self.gate.current_goal(now)
            failsafe = self.gate.failsafe(now)
        else:
            driving = self.arbiter.select(now)
            goal = self.gates[driving].current_goal(now) if driving else np.zeros(6)
            failsafe = driving is None
            label = self.arbiter.label(now)
            if label != self._active:
                self._active = label
                self.get_logger().info(f'command source driving: {label}')
                self._active_pub.publish(String(data=label))
        if failsafe and not self._failsafe and self._active != STOPPED:
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
        gates = list(self.gates.values()) or [self.gate]
        counts = {v.value: sum(g.counts[v] for g in gates) for v in Verdict}
        health = self.health.report(REPORT_PERIOD)
        failsafe = (1, 'failsafe: no surface command') if self._failsafe else (0, 'ok')
        if self._active == STOPPED:
            failsafe = (1, 'stopped by the station (surface_command/stop)')
        reason = self._timeout_too_short(self.gate.settings.timeout)
        rate = (ERROR, reason) if reason else (0, 'ok')
        guards = [self.twist_guard] if self.twist_guard else [*self.source_guards.values(),
                                                              self.stop_guard]
        level, message = worst(*(g.status() for g in guards), self.io_guard.status(),
                               failsafe, health[:2], rate)
        extra = {'active_source': self._active} if self.arbiter else {}
        self.publish_diagnostics(level, message, {
            **counts, 'io_forwarded': self.io_forwarded, 'io_rejected': self.io_rejected,
            'io_contested': self.io_contested, 'failsafe': self._failsafe, **extra,
            **health[2]})
