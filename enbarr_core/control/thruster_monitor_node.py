"""Thruster monitor node: commanded against measured shaft speed, failed thrusters reported.

Takes what each thruster plugin applied (``thruster_output``: the command it was actually
given, neutral on its timeout included) and what the thrusters report
(``thruster_sensors``: shaft speed), and judges them with ``control.thruster_health``: a
thruster commanded at least ``min_command`` that turns slower than ``ratio`` of the expected
speed for ``hold_time`` is failed (blocked or tangled) and stays failed until the operator
clears it (``thruster_monitor/clear``: a thruster's name, or empty for all).

A failure is reported at once and then every second on ``/diagnostics``: level ERROR, the
message naming the thrusters, one ``failed_thruster`` value per failed thruster (its name: the
convention of ``allocation.failures``, which the thruster converter and the azimuth
allocation listen for) and ``failed.<name>`` why. The allocation takes the thruster out from
there, so that it is commanded zero and the others make up for it; clearing the failure here
gives it back. A thruster whose speed stops arriving is not
judged (the monitor cannot tell); the message then says the feedback is stale.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensor_msgs.msg import JointState
from std_msgs.msg import String

from enbarr_interfaces import convert, topics
from enbarr_core.allocation.failures import DIAGNOSTIC_KEY
from enbarr_core.control.thruster_health import HealthSettings, ThrusterHealth
from enbarr_core.framework.health import DEGRADED, ERROR, OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec

CLEAR_TOPIC = 'thruster_monitor/clear'

SPECS = [
    ParamSpec('full_speed', 320.0, "Shaft speed at full throttle (the thrusters' data sheet "
              "at the supply voltage; the simulated thrusters' full_speed)", 'rad/s', 1.0,
              10000.0),
    ParamSpec('min_command', 0.2, 'Below this |command| a thruster is not judged', '', 0.01,
              1.0),
    ParamSpec('ratio', 0.5, 'Failed below this fraction of the expected speed', '', 0.05,
              0.95),
    ParamSpec('hold_time', 0.5, "For this long without a break (longer than the motor's "
              'spin-up)', 's', 0.05, 10.0),
    ParamSpec('stale_after', 1.0, 'Feedback older than this is reported stale', 's', 0.05,
              60.0),
]


@dataclass(frozen=True)
class MonitorSettings:
    """Settings of :class:`ThrusterMonitorNode` (see ``SPECS``)."""

    health: HealthSettings
    stale_after: float   # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> MonitorSettings:
        """Build from the declared parameters' values; ValueError names a bad field."""
        health = HealthSettings(v['full_speed'], v['min_command'], v['ratio'], v['hold_time'])
        health.validate()
        return cls(health, v['stale_after'])


class ThrusterMonitorNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_monitor', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.health: ThrusterHealth | None = None
        self.settings: MonitorSettings
        self.bind_settings(SPECS, MonitorSettings.from_params, self._apply)
        self.last_feedback_ns: int | None = None
        self.create_topic_subscription(topics.THRUSTER_OUTPUT, self._on_output)
        self.create_topic_subscription(topics.THRUSTER_SENSORS, self._on_sensors)
        self.create_subscription(String, CLEAR_TOPIC, self._on_clear, 10)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: MonitorSettings) -> None:
        self.settings = settings
        if self.health is not None:
            self.health.settings = settings.health

    def _tracker(self, names: list[str]) -> ThrusterHealth:
        if self.health is None or set(names) - set(self.health.names):
            old = self.health
            self.health = ThrusterHealth(sorted(set(names) | set(old.names if old else ())),
                                         self.settings.health)
            if old is not None:   # a new thruster appeared: the latched ones stay latched
                self.health.failed.update(old.failed)
        return self.health

    def _on_output(self, msg: JointState) -> None:
        health = self._tracker(list(msg.name))
        for name, value in zip(msg.name, msg.effort):
            health.commanded(name, value)

    def _on_sensors(self, msg: JointState) -> None:
        health = self._tracker(list(msg.name))
        now_ns = convert.stamp_to_ns(msg.header.stamp) or self.now_ns()
        self.last_feedback_ns = self.now_ns()
        newly = []
        for name, speed in zip(msg.name, msg.velocity):
            why = health.measured(name, speed, now_ns)
            if why is not None:
                newly.append(name)
                self.get_logger().error(f'thruster {name} failed: {why}')
        if newly:
            self._report()

    def _on_clear(self, msg: String) -> None:
        if self.health is None:
            return
        name = msg.data.strip()
        if name and name not in self.health.names:
            self.get_logger().warn(f'{CLEAR_TOPIC}: no thruster named {name!r} '
                                   f'(thrusters: {", ".join(self.health.names)})')
            return
        self.health.clear(name or None)
        self.get_logger().info(f'thruster {name or "(all)"} trusted again by the operator')
        self._report()

    def diagnostic_status(self) -> tuple[int, str, list[tuple[str, Any]]]:
        """(level, message, values) for ``/diagnostics``; ``failed_thruster`` may repeat."""
        failed = dict(self.health.failed) if self.health is not None else {}
        values: list[tuple[str, Any]] = [(DIAGNOSTIC_KEY, n) for n in sorted(failed)]
        values += [(f'failed.{n}', why) for n, why in sorted(failed.items())]
        if failed:
            return ERROR, f'thruster(s) failed: {", ".join(sorted(failed))}', values
        last = self.last_feedback_ns
        if last is None or (self.now_ns() - last) * 1e-9 > self.settings.stale_after:
            age = 'none yet' if last is None else f'{(self.now_ns() - last) * 1e-9:.1f} s old'
            return DEGRADED, f'thruster feedback stale ({age}): not judged', values
        return OK, 'ok', values

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())

