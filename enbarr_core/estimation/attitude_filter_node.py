"""Orientation filter node: ``imu/data_raw`` (+ ``imu/mag``) -> ``imu/data``.

An error-state Kalman filter on filterpy (``enbarr_core.estimation.attitude_filter``). dt comes
from the sample stamps, and only stamps the time policy accepts (``framework.stamps``) become
the filter's time base: a sample stamped more than ``max_future`` ahead of the node's clock, or
not later than the last accepted one, is refused and counted, so one bad sample (another
computer's clock, a stray publisher) costs at most itself. A sample with NaN/Inf, or after a
gap longer than ``max_gap``, is dropped and counted (a gap re-initializes the filter from the
next sample).

``/diagnostics`` tells the truth: the node is degraded when it refuses more than 5 % of a
second's samples or re-initializes the filter, and says why. ``max_gap`` must be at least two
sample periods of ``imu/data_raw`` as measured (one lost sample must not re-initialize the
filter): a live change below that is refused with the measured period, and a start value
below it (nothing is measured before samples flow) is reported as soon as it is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu, MagneticField

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.estimation.attitude_filter import AttitudeFilter, AttitudeFilterSettings
from enbarr_core.framework.health import (
    ERROR, future_tolerance_problem, InputHealth, IntervalMeter, too_short_for_rate, worst)
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import (
    SAME_CLOCK_MAX_FUTURE, StampGate, StampPolicy, StampVerdict)

#: Window of the diagnostics report [s].
REPORT_PERIOD = 1.0

_D = AttitudeFilterSettings()
SPECS = [
    ParamSpec('gyro_noise', _D.gyro_noise, 'Gyro white-noise density', 'rad/s/sqrt(Hz)',
              1e-9, 10.0),
    ParamSpec('gyro_bias_walk', _D.gyro_bias_walk, 'Gyro bias random-walk density',
              'rad/s^2/sqrt(Hz)', 1e-12, 1.0),
    ParamSpec('accel_noise', _D.accel_noise, 'Accelerometer noise, std per sample', 'm/s^2',
              1e-6, 100.0),
    ParamSpec('mag_noise', _D.mag_noise, 'Heading noise of the magnetometer', 'rad', 1e-6,
              10.0),
    ParamSpec('accel_gate', _D.accel_gate, 'Skip the gravity update when | |a| - g | exceeds '
              'this', 'm/s^2', 1e-3, 100.0),
    ParamSpec('use_innovation_gate', _D.use_innovation_gate, 'Also gate the gravity update '
              'on its tilt innovation (off by default: it can lock a fresh filter out of '
              'gravity on a hull that leans into its acceleration)'),
    ParamSpec('accel_innovation_gate', _D.accel_innovation_gate, 'With use_innovation_gate, '
              'skip the gravity update when its tilt innovation (normalized, chi-square with 2 '
              'degrees of freedom) exceeds this: the vehicle is accelerating sideways', '', 1.0,
              1e6),
    ParamSpec('accel_gate_timeout', _D.accel_gate_timeout, 'After the innovation gate has '
              'failed this long in a row, use gravity again', 's', 1e-3, 3600.0),
    ParamSpec('use_magnetometer', _D.use_magnetometer, 'Correct heading from imu/mag'),
    ParamSpec('initial_bias_std', _D.initial_bias_std, 'Gyro bias std at initialization',
              'rad/s', 1e-9, 10.0),
    ParamSpec('gravity', _D.gravity, 'Magnitude of gravity', 'm/s^2', 1.0, 30.0),
    ParamSpec('max_gap', 0.5, 'A gap between samples longer than this re-initializes', 's',
              1e-3, 60.0),
    ParamSpec('max_future', SAME_CLOCK_MAX_FUTURE,
              'Samples stamped further ahead of the node clock are '
              'refused (time policy; the clock offset tolerated between machines)', 's', 0.0,
              1.0),
    ParamSpec('mag_max_age', 0.05, 'Use imu/mag only when its stamp is this close to the '
              'IMU sample', 's', 0.0, 10.0),
]
_FIELDS = [f.name for f in fields(AttitudeFilterSettings)]


@dataclass(frozen=True)
class AttitudeFilterNodeSettings:
    """Settings of ``AttitudeFilterNode`` (see ``SPECS``)."""

    filter: AttitudeFilterSettings  # noise model and gates of the filter
    max_gap: float                  # a longer gap between samples re-initializes [s]
    mag_max_age: float              # largest |IMU stamp - mag stamp| for a heading update [s]
    max_future: float               # time policy: stamps further ahead are refused [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> AttitudeFilterNodeSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        settings = AttitudeFilterSettings(**{k: v[k] for k in _FIELDS})
        settings.validate()
        return cls(filter=settings, max_gap=v['max_gap'], mag_max_age=v['mag_max_age'],
                   max_future=v['max_future'])

    def check_rate(self, period: float | None) -> None:
        """Raise ValueError when ``max_gap`` is too short for the measured ``period`` [s]."""
        for problem in (too_short_for_rate('max_gap', self.max_gap, 'imu/data_raw', period,
                                           'every lost sample, or every sample, would count '
                                           'as a gap'),
                        future_tolerance_problem(self.max_future, period, 'imu/data_raw')):
            if problem:
                raise ValueError(problem)


class AttitudeFilterNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'filtering', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.filter = AttitudeFilter()
        self.rejected = 0
        self.samples = 0
        self.health = InputHealth()
        self.period = IntervalMeter()  # of accepted imu/data_raw stamps
        self.raw_gate = StampGate()
        self.mag_gate = StampGate()
        self._last_ns: int | None = None
        self._mag: np.ndarray | None = None
        self._mag_ns = 0
        self.settings: AttitudeFilterNodeSettings
        self.bind_settings(SPECS, self._build, self._apply)
        self._pub = self.create_topic_publisher(topics.IMU)
        self.create_topic_subscription(topics.IMU_MAG, self._on_mag)
        self.create_topic_subscription(topics.IMU_RAW, self._on_imu)
        self.create_periodic(REPORT_PERIOD, self._report)

    def _build(self, v: Mapping[str, Any]) -> AttitudeFilterNodeSettings:
        settings = AttitudeFilterNodeSettings.from_params(v)
        settings.check_rate(self.period.period)
        return settings

    def _apply(self, settings: AttitudeFilterNodeSettings) -> None:
        self.settings = settings
        self.filter.settings = settings.filter
        self._max_gap_ns = int(settings.max_gap * 1e9)
        self._mag_age_ns = int(settings.mag_max_age * 1e9)
        policy = StampPolicy(max_future=settings.max_future)
        self.raw_gate.policy = self.mag_gate.policy = policy

    def _now(self) -> int:
        return self.now_ns()

    def _on_mag(self, msg: MagneticField) -> None:
        m = convert.vector3_to_array(msg.magnetic_field)
        if not convert.all_finite(m):
            self.health.refused('imu/mag', 'non_finite')
            return
        t = convert.stamp_to_ns(msg.header.stamp)
        verdict = self.mag_gate.offer(t, self._now())
        if verdict is not StampVerdict.ACCEPTED:
            self.health.refused('imu/mag', verdict.value)
            return
        self.health.accepted('imu/mag')
        self._mag, self._mag_ns = m, t

    def _on_imu(self, msg: Imu) -> None:
        t = convert.stamp_to_ns(msg.header.stamp)
        gyro = convert.vector3_to_array(msg.angular_velocity)
        accel = convert.vector3_to_array(msg.linear_acceleration)
        if not convert.all_finite(gyro, accel):
            self.rejected += 1
            self.health.refused('imu/data_raw', 'non_finite')
            return
        # The time policy first: only an accepted stamp may become the time base.
        verdict = self.raw_gate.offer(t, self._now())
        if verdict is not StampVerdict.ACCEPTED:
            self.rejected += 1
            self.health.refused('imu/data_raw', verdict.value)
            return
        self.period.add(t)
        last, self._last_ns = self._last_ns, t
        if last is None or not 0 < t - last <= self._max_gap_ns:
            # The first sample, a gap, or the clock went back (the gate started over).
            if last is not None:  # not the first sample: dropped and counted
                self.rejected += 1
                self.health.refused('imu/data_raw', 'gap')
                self.health.reset('filter')
            self.filter.reset()
            return
        self.health.accepted('imu/data_raw')
        mag = self._mag if abs(t - self._mag_ns) <= self._mag_age_ns else None
        est = self.filter.step(gyro, accel, mag, (t - last) * 1e-9)
        self.samples += 1
        out = new(Imu)
        out.header = msg.header
        convert.set_quaternion(out.orientation, est.q)
        convert.set_covariance3(out.orientation_covariance, est.orientation_cov)
        convert.set_vector3(out.angular_velocity, est.omega)
        convert.set_covariance3(out.angular_velocity_covariance, est.omega_cov)
        out.linear_acceleration = msg.linear_acceleration
        out.linear_acceleration_covariance = msg.linear_acceleration_covariance
        self._pub.publish(out)

    def _report(self) -> None:
        level, message, values = self.health.report(REPORT_PERIOD)
        try:
            self.settings.check_rate(self.period.period)
        except ValueError as err:  # a start value the measured rate shows to be wrong
            level, message = worst((level, message), (ERROR, str(err)))
        self.publish_diagnostics(level, message, {
            'samples': self.samples, 'rejected': self.rejected, **values})
