"""Orientation filter node: ``imu/data_raw`` (+ ``imu/mag``) -> ``imu/data``.

An error-state Kalman filter on filterpy (``enbarr_core.estimation.attitude_filter``). dt comes
from the sample stamps. A sample with NaN/Inf, a stamp that does not advance, or a gap longer
than ``max_gap`` is dropped and counted (a gap re-initializes the filter from the next sample).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu, MagneticField

from enbarr_interfaces import convert, topics

from enbarr_core.estimation.attitude_filter import AttitudeFilter, AttitudeFilterSettings
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec

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

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> AttitudeFilterNodeSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        settings = AttitudeFilterSettings(**{k: v[k] for k in _FIELDS})
        settings.validate()
        return cls(filter=settings, max_gap=v['max_gap'], mag_max_age=v['mag_max_age'])


class AttitudeFilterNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'filtering', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.filter = AttitudeFilter()
        self.rejected = 0
        self.samples = 0
        self._last_ns: int | None = None
        self._mag: np.ndarray | None = None
        self._mag_ns = 0
        self.settings: AttitudeFilterNodeSettings
        self.bind_settings(SPECS, AttitudeFilterNodeSettings.from_params, self._apply)
        self._pub = self.create_topic_publisher(topics.IMU)
        self.create_topic_subscription(topics.IMU_MAG, self._on_mag)
        self.create_topic_subscription(topics.IMU_RAW, self._on_imu)
        self.create_timer(1.0, self._report)

    def _apply(self, settings: AttitudeFilterNodeSettings) -> None:
        self.settings = settings
        self.filter.settings = settings.filter
        self._max_gap_ns = int(settings.max_gap * 1e9)
        self._mag_age_ns = int(settings.mag_max_age * 1e9)

    def _on_mag(self, msg: MagneticField) -> None:
        m = convert.vector3_to_array(msg.magnetic_field)
        if np.all(np.isfinite(m)):
            self._mag, self._mag_ns = m, convert.stamp_to_ns(msg.header.stamp)

    def _on_imu(self, msg: Imu) -> None:
        t = convert.stamp_to_ns(msg.header.stamp)
        gyro = convert.vector3_to_array(msg.angular_velocity)
        accel = convert.vector3_to_array(msg.linear_acceleration)
        if not convert.all_finite(gyro, accel):
            self.rejected += 1
            return
        last, self._last_ns = self._last_ns, t
        if last is None or t - last > self._max_gap_ns:
            if last is not None:  # a gap (not the first sample): dropped and counted
                self.rejected += 1
            self.filter.reset()
            return
        if t <= last:
            self.rejected += 1
            self._last_ns = last
            return
        mag = self._mag if abs(t - self._mag_ns) <= self._mag_age_ns else None
        est = self.filter.step(gyro, accel, mag, (t - last) * 1e-9)
        self.samples += 1
        out = Imu()
        out.header = msg.header
        convert.set_quaternion(out.orientation, est.q)
        convert.set_covariance3(out.orientation_covariance, est.orientation_cov)
        convert.set_vector3(out.angular_velocity, est.omega)
        convert.set_covariance3(out.angular_velocity_covariance, est.omega_cov)
        out.linear_acceleration = msg.linear_acceleration
        out.linear_acceleration_covariance = msg.linear_acceleration_covariance
        self._pub.publish(out)

    def _report(self) -> None:
        self.publish_diagnostics(0, 'ok', {'samples': self.samples, 'rejected': self.rejected})
