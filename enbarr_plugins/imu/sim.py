"""Simulated 9-DOF IMU: measures the simulated vehicle (``sim/imu``) with sensor errors.

What a real IMU plugin (LSM9DS1, BNO055, ...) publishes, from the true motion instead of a
chip: gyro = omega + b_g + n_g, accelerometer = f + b_a + n_a (specific force, +9.81 m/s^2 on
z at rest, REP-145), magnetometer = R^T m_world + n_m. Noise is white Gaussian with the given
standard deviation per sample, from a seeded generator so runs repeat.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu, MagneticField

from enbarr_core.framework.checks import floats
from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.kinematics import quat_to_rotmat
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

SPECS = [
    ParamSpec('gyro_noise', 0.002, 'Gyro white noise, std per sample', 'rad/s', 0.0, 1.0),
    ParamSpec('gyro_bias', [0.004, -0.003, 0.002], 'Constant gyro bias', 'rad/s', -0.5, 0.5),
    ParamSpec('accel_noise', 0.03, 'Accelerometer white noise, std per sample', 'm/s^2', 0.0,
              10.0),
    ParamSpec('accel_bias', [0.0, 0.0, 0.0], 'Constant accelerometer bias', 'm/s^2', -5.0,
              5.0),
    ParamSpec('mag_noise', 5e-7, 'Magnetometer white noise, std per sample', 'T', 0.0, 1e-3),
    ParamSpec('magnetic_field', [0.0, 1.8e-5, -4.8e-5], 'Earth field in odom (ENU): north '
              '= +y, inclination down', 'T', -1e-3, 1e-3),
    ParamSpec('seed', 1, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
]


@dataclass(frozen=True)
class SimImuSettings:
    """Settings of ``SimImuNode`` (see ``SPECS``): the error model of the simulated chip."""

    gyro_noise: float                  # std per sample [rad/s]
    gyro_bias: tuple[float, ...]       # constant bias [rad/s]
    accel_noise: float                 # std per sample [m/s^2]
    accel_bias: tuple[float, ...]      # constant bias [m/s^2]
    mag_noise: float                   # std per sample [T]
    magnetic_field: tuple[float, ...]  # Earth field in odom (ENU) [T]
    seed: int                          # seed of the noise generator

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimImuSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        return cls(gyro_noise=v['gyro_noise'], gyro_bias=floats('gyro_bias', v['gyro_bias'], 3),
                   accel_noise=v['accel_noise'],
                   accel_bias=floats('accel_bias', v['accel_bias'], 3),
                   mag_noise=v['mag_noise'],
                   magnetic_field=floats('magnetic_field', v['magnetic_field'], 3),
                   seed=v['seed'])


class SimImuNode(SensorDriver):
    """Publishes ``imu/mag`` then ``imu/data_raw`` for every ``sim/imu`` truth sample."""

    def __init__(self, node_name: str = 'imu', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimImuSettings
        self.bind_settings(SPECS, SimImuSettings.from_params, self._apply)
        self._rng = np.random.default_rng(self.settings.seed)
        self._raw_pub = self.create_topic_publisher(topics.IMU_RAW)
        self._mag_pub = self.create_topic_publisher(topics.IMU_MAG)
        self.create_topic_subscription(topics.SIM_IMU, self._on_truth)

    def _apply(self, settings: SimImuSettings) -> None:
        self.settings = settings
        # The per-sample arithmetic wants arrays; made once per settings change.
        self._gyro_bias = tuple(float(b) for b in settings.gyro_bias)
        self._accel_bias = tuple(float(b) for b in settings.accel_bias)
        self._magnetic_field = np.array(settings.magnetic_field)

    def _on_truth(self, truth: Imu) -> None:
        s = self.settings
        rng = self._rng
        q = convert.quaternion_to_array(truth.orientation)
        omega, f = truth.angular_velocity, truth.linear_acceleration
        mag = new(MagneticField)
        mag.header.stamp = truth.header.stamp
        mag.header.frame_id = topics.IMU_FRAME
        m = quat_to_rotmat(q).T @ self._magnetic_field + rng.normal(0.0, s.mag_noise, 3)
        convert.set_vector3(mag.magnetic_field, m)
        mag.magnetic_field_covariance[0] = mag.magnetic_field_covariance[4] = \
            mag.magnetic_field_covariance[8] = s.mag_noise ** 2
        self._mag_pub.publish(mag)
        raw = new(Imu)
        raw.header.stamp = truth.header.stamp
        raw.header.frame_id = topics.IMU_FRAME
        raw.orientation_covariance[0] = -1.0  # no orientation estimate (REP-145)
        # truth + bias + noise in Python floats: the same draws in the same order and the same
        # sums as with 3-element arrays, which cost more to build than the noise.
        bx, by, bz = self._gyro_bias
        nx, ny, nz = rng.normal(0.0, s.gyro_noise, 3).tolist()
        v = raw.angular_velocity
        v.x, v.y, v.z = omega.x + bx + nx, omega.y + by + ny, omega.z + bz + nz
        bx, by, bz = self._accel_bias
        nx, ny, nz = rng.normal(0.0, s.accel_noise, 3).tolist()
        v = raw.linear_acceleration
        v.x, v.y, v.z = f.x + bx + nx, f.y + by + ny, f.z + bz + nz
        g2, a2 = s.gyro_noise ** 2, s.accel_noise ** 2
        raw.angular_velocity_covariance[0] = raw.angular_velocity_covariance[4] = \
            raw.angular_velocity_covariance[8] = g2
        raw.linear_acceleration_covariance[0] = raw.linear_acceleration_covariance[4] = \
            raw.linear_acceleration_covariance[8] = a2
        self._raw_pub.publish(raw)
        self.sample_received()
