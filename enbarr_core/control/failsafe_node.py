"""Failsafe supervisor: the ROV's inputs -> ``failsafe/action`` (``control.failsafes``).

Ten times a second (``rate``) it measures what the failsafes watch and publishes the most
severe action asked for on ``failsafe/action`` (latched; the velocity loop applies it) and the
active failsafes, each with its action, the time it tripped and why, on ``failsafe/active``
(latched) and ``/diagnostics``. Nothing here runs per IMU sample: the 200 Hz chain pays for
the failsafes only with one attribute test in the velocity loop.

What it reads, all low-rate:

- pilot input: ``surface_command/twist`` with finite values (the receiver judges staleness
  and range; its own 0.5 s zero goal acts first);
- surface link: any of ``surface_command/twist``, ``/io`` or ``/stop`` (the tree has no
  heartbeat of its own: a station that idles its sticks still sends twists at its rate);
- ``leak``, ``battery`` (voltage), ``depth`` with ``pilot_mode``, ``hull/pressure`` and
  ``hull/temperature`` (no driver publishes these yet: the failsafes are ready for one);
- the attitude filter's ``/diagnostics`` report (node ``attitude.node``): its level, and its
  ``samples`` count, which stands still when its IMU stops. So the attitude failsafe reacts
  within a report period (1 s) plus ``attitude.timeout``, at no per-sample cost; a filter
  that stops reporting trips after ``SILENT_REPORTS`` report periods.

Ages count on the node's clock from the last message received (from the node's start when
none was). The operator clears latched failsafes (leak, battery) with an ``io_request`` to
executor ``failsafe`` with the string ``clear``; the outcome goes to the log and
``failsafe/active``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
from rcl_interfaces.msg import Parameter
from sensor_msgs.msg import BatteryState, FluidPressure, Temperature
from std_msgs.msg import Bool, String

from enbarr_core.control.failsafes import (
    describe, FailsafeSetting, FailsafeSettings, KINDS, NEUTRAL, NONE,
    Observation, Supervisor, SURFACE, Verdict)
from enbarr_core.control.pilot_modes import DEPTH_HOLD
from enbarr_core.framework.health import DEGRADED, ERROR, OK
from enbarr_core.framework.node import EnbarrNode, TICK
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics

#: The executor name of an operator's clear on ``io_request`` (string_value ``clear``).
EXECUTOR = 'failsafe'
REPORT_PERIOD = 1.0
#: The attitude filter reports once a second (REPORT_PERIOD); a report late on a loaded
#: executor is not a silent filter: silence is this many periods without one.
SILENT_REPORTS = 3

#: name -> (default action, default threshold; NaN for a failsafe without one).
DEFAULTS: dict[str, tuple[str, float]] = {
    'pilot_input': (NEUTRAL, 3.0),        # ArduSub: FS_PILOT_INPUT disarm, FS_PILOT_TIMEOUT 3 s
    'surface_link': (NEUTRAL, 5.0),       # ArduSub: FS_GCS_ENABLE disarm, FS_GCS_TIMEOUT 5 s
    'leak': (SURFACE, math.nan),          # ArduSub: FS_LEAK_ENABLE warn only
    'battery_low': ('warn', 14.0),        # 4S at 3.5 V a cell
    'battery_critical': (SURFACE, 13.2),  # 4S at 3.3 V a cell
    'depth': ('stabilize', 0.5),          # as pilot.depth_timeout
    'attitude': (NEUTRAL, 2.0),           # ArduSub: FS_EKF_ACTION disabled
    'pressure': ('warn', 105000.0),       # ArduSub: FS_PRESS_MAX 105000 Pa, disabled
    'temperature': ('warn', 62.0),        # ArduSub: FS_TEMP_MAX 62 degC, disabled
}
_THRESHOLD_RANGES = {'timeout': (0.01, 600.0), 'voltage': (0.0, 100.0),
                     'limit': (-1e6, 1e7)}


def _specs() -> list[ParamSpec]:
    specs = [ParamSpec('rate', 10.0, 'Rate of the failsafe checks', 'Hz', 1.0, 10.0,
                       read_only=True),
             ParamSpec('attitude.node', 'filtering', 'Node name of the attitude filter whose '
                       '/diagnostics report the attitude failsafe reads', read_only=True),
             ParamSpec('battery.time', 10.0, 'The battery voltage must stay below a threshold '
                       'this long to trip (ArduSub BATT_LOW_TIMER)', 's', 0.0, 600.0)]
    for name, (action, threshold) in DEFAULTS.items():
        kind = KINDS[name]
        specs.append(ParamSpec(f'{name}.action', action, f'{name} failsafe ({kind.ardusub}): '
                               + ', '.join(kind.actions)))
        if kind.threshold:
            low, high = _THRESHOLD_RANGES[kind.threshold]
            specs.append(ParamSpec(f'{name}.{kind.threshold}', threshold,
                                   f'{name} failsafe threshold', kind.units, low, high))
    return specs


SPECS = _specs()


@dataclass(frozen=True)
class FailsafeNodeSettings:
    """Settings of ``FailsafeNode`` (``SPECS``)."""

    rate: float           # [Hz]
    attitude_node: str
    failsafes: FailsafeSettings

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> FailsafeNodeSettings:
        """Build from the declared parameters; ``ValueError`` names the parameter."""
        table = {}
        for name in DEFAULTS:
            kind = KINDS[name]
            threshold = float(v[f'{name}.{kind.threshold}']) if kind.threshold else math.nan
            time = float(v['battery.time']) if name.startswith('battery') else 0.0
            table[name] = FailsafeSetting(str(v[f'{name}.action']), threshold, time)
        failsafes = FailsafeSettings(table)
        failsafes.validate()
        return cls(rate=float(v['rate']), attitude_node=str(v['attitude.node']),
                   failsafes=failsafes)


class FailsafeNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'failsafe', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: FailsafeNodeSettings
        self.supervisor: Supervisor | None = None
        self.bind_settings(SPECS, FailsafeNodeSettings.from_params, self._apply)
        t0 = self._now()
        self._pilot_at = self._link_at = t0
        self._leak: bool | None = None
        self._voltage: float | None = None
        self._mode = ''
        self._left_depth_hold_at: float | None = None
        self._depth_at: float | None = None
        self._pressure: float | None = None
        self._temperature: float | None = None
        self._attitude_ok_at = t0
        self._attitude_problem: str | None = None
        self._attitude_report_at: float | None = None
        self._attitude_samples: int | None = None
        self.verdict = Verdict(NONE, ())
        self.clears = 0   # operator clears taken
        self._published: tuple[str, str] | None = None
        self._action_pub = self.create_topic_publisher(topics.FAILSAFE_ACTION)
        self._active_pub = self.create_topic_publisher(topics.FAILSAFE_ACTIVE)
        self.create_topic_subscription(topics.SURFACE_TWIST, self._on_twist)
        self.create_topic_subscription(topics.SURFACE_IO, self._on_link)
        self.create_topic_subscription(topics.SURFACE_STOP, self._on_link)
        self.create_topic_subscription(topics.LEAK, self._on_leak)
        self.create_topic_subscription(topics.BATTERY, self._on_battery)
        self.create_topic_subscription(topics.DEPTH, self._on_depth)
        self.create_topic_subscription(topics.PILOT_MODE, self._on_mode)
        self.create_topic_subscription(topics.HULL_PRESSURE, self._on_pressure)
        self.create_topic_subscription(topics.HULL_TEMPERATURE, self._on_temperature)
        self.create_topic_subscription(topics.DIAGNOSTICS, self._on_diagnostics)
        self.create_topic_subscription(topics.IO_REQUEST, self._on_io)

    def _apply(self, settings: FailsafeNodeSettings) -> None:
        self.settings = settings
        if self.supervisor is None:
            self.supervisor = Supervisor(settings.failsafes)
        else:   # new thresholds and actions; what is active stays active
            self.supervisor.settings = settings.failsafes

    def start(self) -> None:
        """Start the checks; say the action at once (latched: a late joiner learns it)."""
        super().start()
        t0 = self._now()
        self._pilot_at = self._link_at = self._attitude_ok_at = t0
        self._publish()
        # The ticker's periods are whole multiples of its tick.
        self.create_periodic(max(1, round(1.0 / (self.settings.rate * TICK))) * TICK, self.check)
        self.create_periodic(REPORT_PERIOD, self._report)

    def _now(self) -> float:
        return self.now_ns() * 1e-9

    # -- inputs -----------------------------------------------------------------------------
    def _on_twist(self, msg: TwistStamped) -> None:
        now = self._now()
        self._link_at = now
        if convert.all_finite(convert.twist_to_nu(msg.twist)):
            self._pilot_at = now

    def _on_link(self, _msg: Any) -> None:
        self._link_at = self._now()

    def _on_leak(self, msg: Bool) -> None:
        self._leak = bool(msg.data)
        if self._leak:
            self.check()   # a leak acts at once, not at the next tick

    def _on_battery(self, msg: BatteryState) -> None:
        self._voltage = float(msg.voltage)

    def _on_depth(self, _msg: PoseWithCovarianceStamped) -> None:
        self._depth_at = self._now()

    def _on_mode(self, msg: String) -> None:
        if self._mode == DEPTH_HOLD and msg.data != DEPTH_HOLD:
            self._left_depth_hold_at = self._now()
        self._mode = msg.data

    def _on_pressure(self, msg: FluidPressure) -> None:
        self._pressure = float(msg.fluid_pressure)

    def _on_temperature(self, msg: Temperature) -> None:
        self._temperature = float(msg.temperature)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id != self.settings.attitude_node:
                continue
            now = self._now()
            values = {kv.key: kv.value for kv in status.values}
            try:
                samples: int | None = int(values['samples'])
            except (KeyError, ValueError):
                samples = None
            level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
            if level >= ERROR:
                problem: str | None = f'attitude filter error: {status.message}'
            elif samples is not None and samples == self._attitude_samples:
                problem = 'attitude filter has no IMU samples'
            else:
                problem = None
            self._attitude_samples = samples
            self._attitude_report_at = now
            self._attitude_problem = problem
            if problem is None:
                self._attitude_ok_at = now

    def _on_io(self, msg: Parameter) -> None:
        if msg.name != EXECUTOR or self.supervisor is None:
            return
        if msg.value.string_value != 'clear':
            self.get_logger().warn(f'failsafe request {msg.value.string_value!r} refused: '
                                   "the only request is 'clear'")
            return
        self.verdict, said = self.supervisor.clear(self.observe(), self._now())
        self.clears += 1
        self.get_logger().warn(f'operator clear: {said}')
        self._publish()

    # -- the checks ---------------------------------------------------------------------------
    def observe(self) -> Observation:
        """Return what the failsafes watch, now."""
        now = self._now()
        problem = self._attitude_problem
        report_at = self._attitude_report_at
        # Never heard is not silent (as every input here): a filter still starting, on a
        # loaded start, tripped neutral before its first report.
        if report_at is not None and now - report_at > SILENT_REPORTS * REPORT_PERIOD:
            problem = f'no report from the attitude filter ({self.settings.attitude_node})'
        # The velocity loop leaves depth hold itself when the depth goes stale (on its own
        # timeout, as short as this one): a mode that left depth hold when the depth was
        # already older than the depth failsafe's timeout still counts as in it.
        left = self._left_depth_hold_at
        limit = self.settings.failsafes.failsafes['depth'].threshold
        depth_hold = self._mode == DEPTH_HOLD or (left is not None and (
            self._depth_at is None or left - self._depth_at > limit))
        return Observation(
            pilot_input_age=now - self._pilot_at, surface_link_age=now - self._link_at,
            leak=self._leak, battery_voltage=self._voltage, depth_hold=depth_hold,
            depth_age=None if self._depth_at is None else now - self._depth_at,
            attitude_problem=problem, attitude_age=now - self._attitude_ok_at,
            pressure=self._pressure, temperature=self._temperature)

    def check(self) -> None:
        """Evaluate the failsafes once; log what tripped or cleared, publish on a change."""
        if not self.started or self.supervisor is None:
            return
        verdict = self.supervisor.evaluate(self.observe(), self._now())
        for trip in verdict.tripped:
            self.get_logger().error(f'FAILSAFE {trip.name}: {trip.action} ({trip.reason})')
        for name in verdict.cleared:
            self.get_logger().warn(f'failsafe {name} cleared')
        self.verdict = verdict
        self._publish()

    def _publish(self) -> None:
        key = (self.verdict.action, ','.join(f'{t.name}:{t.since}' for t in self.verdict.active))
        if key == self._published:
            return
        self._published = key
        self._action_pub.publish(String(data=self.verdict.action))
        self._active_pub.publish(String(data=describe(self.verdict.active)))

    def _report(self) -> None:
        v = self.verdict
        level = OK if not v.active else (
            ERROR if v.action in (SURFACE, NEUTRAL) else DEGRADED)
        message = 'ok' if not v.active else 'failsafe: ' + describe(v.active)
        heard = {'leak': self._leak is not None, 'battery': self._voltage is not None,
                 'hull_pressure': self._pressure is not None,
                 'hull_temperature': self._temperature is not None}
        self.publish_diagnostics(level, message, {
            'action': v.action, 'clears': self.clears,
            **{f'heard.{k}': h for k, h in heard.items()},
            **{f'active.{t.name}': f'{t.action} since {t.since:.2f} s' for t in v.active}})

