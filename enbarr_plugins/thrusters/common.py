"""What every thruster driver shares, real or simulated: how ``thruster_commands`` is taken.

``CommandFilter`` holds the checks a command passes before any driver applies it: -1..1 per
named thruster; a command with a name the profile does not have, a value that is not finite,
or names and values of different lengths is refused and counted; values outside -1..1 are
clipped and counted; then the time policy (``framework.stamps``): a command stamped more than
``max_future`` ahead of the node's clock, or not later than the last applied one (an old
command overtaking a newer one), is refused and counted. ``/diagnostics`` reports the driver
degraded when more than 5 % of a second's commands are refused (``InputHealth``).

``ThrusterDriver`` is the node side that every thruster plugin shares: the thrusters of the
profile (``thruster_names``, ``thrusters.<name>.*``), the subscription to ``thruster_commands``
through the filter, the command watchdog and safe state of an ``ActuatorDriver``, the
``thruster_output`` publisher (what was applied: neutral included) and the latency from a
command's stamp (the sensor time it was computed from) to its application. A plugin writes
``apply(command, now_ns)`` (called with the watchdog's lock held), ``is_neutral`` and
``write_neutral``, and publishes what it applied with ``publish_output``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Protocol

import numpy as np
from sensor_msgs.msg import JointState

from enbarr_core.allocation.layout_params import declare_thrusters
from enbarr_core.framework.driver import REPORT_PERIOD, ActuatorDriver
from enbarr_core.framework.health import InputHealth, worst
from enbarr_core.framework.node import LatencyLog
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import (
    SAME_CLOCK_MAX_FUTURE, StampGate, StampPolicy, StampVerdict)
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

#: The input's name in counters and ``/diagnostics``.
INPUT = 'thruster_commands'

#: The time policy's parameter, the same in every thruster plugin.
MAX_FUTURE_SPEC = ParamSpec('max_future', SAME_CLOCK_MAX_FUTURE, 'Commands stamped further '
                            'ahead of the node clock are refused (time policy)', 's', 0.0, 1.0)


class WarnLogger(Protocol):
    """The part of a node's logger that the filter uses (rclpy's ``RcutilsLogger.warn``)."""

    def warn(self, message: str, *, throttle_duration_sec: float) -> Any: ...  # noqa: D102


@dataclass(frozen=True)
class Command:
    """A command that passed the checks."""

    values: np.ndarray  # normalized, one per thruster in the driver's order, within -1..1
    stamp_ns: int       # its header stamp [ns]: when the data it was computed from was taken


class CommandFilter:
    """The checks of ``thruster_commands`` for one driver; see the module docstring."""

    def __init__(self, names: tuple[str, ...], logger: WarnLogger,
                 policy: StampPolicy = StampPolicy()) -> None:
        self.names = names
        self._index = {n: i for i, n in enumerate(names)}
        self._logger = logger
        self.gate = StampGate(policy)
        self.health = InputHealth()
        self.refused = 0  # commands refused (invalid, or by the time policy)
        self.clipped = 0  # commands with a value outside -1..1, clipped

    def set_max_future(self, seconds: float) -> None:
        """Set how far ahead of the node's clock a command's stamp may be [s]."""
        self.gate.policy = StampPolicy(seconds)

    def accept(self, msg: JointState, now_ns: int) -> Command | None:
        """Return ``msg`` as a ``Command`` at ``now_ns`` (node clock), or None when refused.

        Thrusters the message does not name are commanded to 0.
        """
        if len(msg.name) != len(msg.effort):
            self._refuse('invalid')
            return None
        # Python floats until the checks pass (numpy on 6-8 values costs more than the checks).
        values = [0.0] * len(self.names)
        for name, value in zip(msg.name, msg.effort):
            i = self._index.get(name)
            if i is None or not math.isfinite(value):
                self._refuse('invalid')
                self._logger.warn(f'refused thruster command {name}={value}',
                                  throttle_duration_sec=1.0)
                return None
            values[i] = value
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        verdict = self.gate.offer(stamp_ns, now_ns)
        if verdict is not StampVerdict.ACCEPTED:
            self._refuse(verdict.value)
            return None
        self.health.accepted(INPUT)
        if values and (max(values) > 1.0 or min(values) < -1.0):
            self.clipped += 1
            values = [min(max(v, -1.0), 1.0) for v in values]
        return Command(np.array(values, dtype=float), stamp_ns)

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self.health.refused(INPUT, reason)


class ThrusterDriver(ActuatorDriver):
    """Base of the thruster plugins; see the module docstring.

    ``neutral`` is True while every thruster is commanded to 0; ``command`` is the latest
    command applied (normalized, in ``names`` order).
    """

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        self.neutral = True  # before the watchdog exists: it asks is_neutral()
        self._health_values: dict[str, int] = {}
        super().__init__(node_name, timeout_message='thruster commands stopped: thrusters '
                         'neutral', **kwargs)
        self.thrusters = declare_thrusters(self)
        self.names = [t.name for t in self.thrusters]
        self.commands = CommandFilter(tuple(self.names), self.get_logger())
        self.command = np.zeros(len(self.names))
        self.latency = LatencyLog()  # command stamp -> command applied [ns]
        self._output_pub = self.create_topic_publisher(topics.THRUSTER_OUTPUT)

    def subscribe_commands(self) -> None:
        """Take ``thruster_commands`` (call once the plugin's settings are bound)."""
        self.create_topic_subscription(topics.THRUSTER_COMMANDS, self._on_command)

    @property
    def refused(self) -> int:
        """Commands refused so far."""
        return self.commands.refused

    @property
    def clipped(self) -> int:
        """Commands clipped to -1..1 so far."""
        return self.commands.clipped

    @property
    def gate(self) -> StampGate:
        """The time policy of ``thruster_commands`` and its counts."""
        return self.commands.gate

    def _on_command(self, msg: JointState) -> None:
        now_ns = self.now_ns()
        taken = self.commands.accept(msg, now_ns)
        if taken is None:
            return
        with self.commanding():
            self.apply(taken.values, now_ns)
        self.latency.add(now_ns - taken.stamp_ns)

    def apply(self, command: np.ndarray, now_ns: int) -> None:
        """Apply an accepted command at ``now_ns`` (the watchdog's lock held)."""
        raise NotImplementedError

    def is_neutral(self) -> bool:
        """Whether every thruster is commanded to neutral."""
        return self.neutral

    def publish_output(self, command: np.ndarray, now_ns: int) -> None:
        """Publish ``command`` on ``thruster_output``: what the thrusters were given."""
        out = new(JointState)
        out.name, out.effort = self.names, command.tolist()
        convert.ns_to_stamp(now_ns, out.header.stamp)
        out.header.frame_id = topics.BODY_FRAME
        self._output_pub.publish(out)

    def status(self) -> tuple[int, str]:
        """Return the driver's status, degraded while commands are refused.

        Closes the health window: called once per report, before ``status_values``.
        """
        level, message, self._health_values = self.commands.health.report(REPORT_PERIOD)
        return worst(super().status(), (level, message))

    def status_values(self) -> dict[str, Any]:
        """Return the driver counters plus refused and clipped commands."""
        return {**super().status_values(), 'refused': self.refused, 'clipped': self.clipped,
                **self._health_values}
