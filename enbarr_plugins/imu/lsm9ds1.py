"""ST LSM9DS1 9-DOF IMU over I2C: ``imu/data_raw`` + ``imu/mag`` (the ROV's IMU).

Two I2C devices in one package: accelerometer + gyroscope at 0x6B (0x6A with SDO_AG low) and
magnetometer at 0x1E (0x1C with SDO_M low); registers, codes and sensitivities in
``lsm9ds1_protocol.py`` (ST DocID025715 Rev 3). The driver configures both devices (block
data update, auto-increment, all axes, the ranges and rates of the parameters, the
magnetometer in ultra-high performance continuous conversion), reads them back, then polls:
one 23-byte burst from STATUS_REG_G (0x17) reads status, gyro, (control registers), status
and accel; the magnetometer is read from STATUS_REG_M with the sub-address MSB set (its only
way to auto-increment).

Axes (imu_link = FLU). The driver's imu_link is the accel/gyro frame printed on the chip
(data sheet figure 2, "pin 1 indicator"): mount the board with the chip's X forward and Z up,
or put the mounting rotation in the TF from base_link to imu_link. Accelerometer and gyroscope
share those axes (chip -> FLU unchanged). The magnetometer's axes as the datasheet draws them
differ: its X points the other way (the figure's X_M is opposite X_AG, Y and Z agree), so
m_FLU = (-m_x, m_y, m_z). A left-handed triad, hence no rotation can express it; the same
reading is in kriswiner/LSM9DS1 LSM9DS1_BasicAHRS_Nano33.ino ("the magnetometer x-axis is
aligned with the -x axis of the gyro and the magnetometer y axis is aligned with the y axis").
The emulator uses the same mapping, so the node tests cannot prove it: check a real board
by pointing +x north (m_x > 0 after the mapping) before trusting the heading.

Noise (covariances): the LSM9DS1 datasheet states no noise density. The defaults below are
assumptions typical of its class (comparable ST parts: gyro 0.015 dps/sqrt(Hz), accel
200 ug/sqrt(Hz), magnetometer 3.2 mgauss RMS at 16 gauss ultra-high performance, LIS3MDL
datasheet); set ``*_noise_density``/``mag_noise`` from a bench measurement of your unit.
The published variance is (density * sqrt(ODR / 2))^2.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu.common import (
    Bus, check_address, common_settings, choice, DEG, G, I2cImuNode, I2cImuSettings, ImuChips,
    ImuSample, noise_specs, Noise, parameter_defaults)
from enbarr_plugins.imu.lsm9ds1_protocol import (
    ACCEL_RANGE, ADDRESS_AG, ADDRESS_M, AUTO_INCREMENT_M, BDU, CTRL_REG1_G, CTRL_REG1_M,
    CTRL_REG2_M, CTRL_REG3_M, CTRL_REG4, CTRL_REG4_M, CTRL_REG5_M, CTRL_REG5_XL, CTRL_REG6_XL,
    CTRL_REG8, GAUSS, GDA, GYRO_ODR, GYRO_RANGE, IF_ADD_INC, MAG_AXES, MAG_ODR, MAG_RANGE,
    MD_CONTINUOUS, OM_ULTRA_HIGH, OUT_X_L_G, OUT_X_L_XL, STATUS_REG, STATUS_REG_G,
    STATUS_REG_M, WHO_AM_I, WHO_AM_I_AG_VALUE, WHO_AM_I_M_VALUE, XLDA, XYZ_ENABLED, ZYXDA)

SPECS = [
    ParamSpec('address', ADDRESS_AG, 'I2C address of the accelerometer/gyroscope (0x6b, or '
              '0x6a with SDO_AG low)', '', 3, 0x77, read_only=True),
    ParamSpec('mag_address', ADDRESS_M, 'I2C address of the magnetometer (0x1e, or 0x1c with '
              'SDO_M low)', '', 3, 0x77, read_only=True),
    ParamSpec('odr', 238.0, 'Accelerometer/gyroscope output data rate: 14.9, 59.5, 119, 238, '
              '476 or 952', 'Hz', read_only=True),
    ParamSpec('gyro_range', 500.0, 'Gyroscope full scale: 245, 500 or 2000', 'deg/s',
              read_only=True),
    ParamSpec('accel_range', 4.0, 'Accelerometer full scale: 2, 4, 8 or 16', 'g',
              read_only=True),
    ParamSpec('mag_odr', 80.0, 'Magnetometer output data rate: 0.625, 1.25, 2.5, 5, 10, 20, '
              '40 or 80', 'Hz', read_only=True),
    ParamSpec('mag_range', 4.0, 'Magnetometer full scale: 4, 8, 12 or 16', 'gauss',
              read_only=True),
    *noise_specs(gyro=0.015, accel=200e-6, mag=4e-7),
]


@dataclass(frozen=True)
class Lsm9ds1Settings(I2cImuSettings):
    """Settings of ``Lsm9ds1ImuNode`` (the common ones of ``I2cImuSettings`` + ``SPECS``)."""

    address: int
    mag_address: int
    odr: float                  # [Hz]
    gyro_range: float           # [dps]
    accel_range: float          # [g]
    mag_odr: float              # [Hz]
    mag_range: float            # [gauss]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Lsm9ds1Settings:
        """Build from the parameters; ``ValueError`` names the parameter and the allowed set."""
        odr = choice('odr', v['odr'], list(GYRO_ODR))
        return cls(**common_settings(v, odr, f'odr {odr:g} Hz'),
                   address=check_address('address', v['address']),
                   mag_address=check_address('mag_address', v['mag_address']),
                   odr=odr, gyro_range=choice('gyro_range', v['gyro_range'], list(GYRO_RANGE)),
                   accel_range=choice('accel_range', v['accel_range'], list(ACCEL_RANGE)),
                   mag_odr=choice('mag_odr', v['mag_odr'], list(MAG_ODR)),
                   mag_range=choice('mag_range', v['mag_range'], list(MAG_RANGE)))


def default_settings(**changes: Any) -> Lsm9ds1Settings:
    """Return the settings of the parameter defaults and ``changes`` (check-device, tests)."""
    return parameter_defaults(SPECS, Lsm9ds1Settings.from_params, **changes)


class Lsm9ds1Chips(ImuChips):
    """The two I2C devices of an LSM9DS1 and how they are configured and read."""

    def __init__(self, bus: Bus, s: Lsm9ds1Settings) -> None:
        super().__init__(bus, s)
        self.ag = bus.device(s.address)
        self.m = bus.device(s.mag_address)
        self._odr_code = GYRO_ODR[s.odr]
        self._fs_g, gyro_lsb = GYRO_RANGE[s.gyro_range]
        self._fs_xl, accel_lsb = ACCEL_RANGE[s.accel_range]
        self._do, self._fs_m = MAG_ODR[s.mag_odr], MAG_RANGE[s.mag_range][0]
        self._gyro_scale = gyro_lsb * DEG                            # rad/s per LSB
        self._accel_scale = accel_lsb * G                            # m/s^2 per LSB
        self._mag_scale = MAG_RANGE[s.mag_range][1] * GAUSS * MAG_AXES  # T per LSB, FLU

    @staticmethod
    def addresses(s: Lsm9ds1Settings) -> tuple[int, int]:
        """Return the accelerometer/gyroscope and magnetometer addresses."""
        return s.address, s.mag_address

    def identities(self) -> list[tuple[Any, int, int, str]]:
        """Return both WHO_AM_Is."""
        return [(self.ag, WHO_AM_I, WHO_AM_I_AG_VALUE, 'LSM9DS1 accelerometer/gyroscope'),
                (self.m, WHO_AM_I, WHO_AM_I_M_VALUE, 'LSM9DS1 magnetometer')]

    def config(self) -> list[tuple[Any, int, int]]:
        """Return the (device, register, value) writes of the configuration, in order."""
        ag, m = self.ag, self.m
        return [
            (ag, CTRL_REG8, BDU | IF_ADD_INC),
            (ag, CTRL_REG4, XYZ_ENABLED),
            (ag, CTRL_REG5_XL, XYZ_ENABLED),
            (ag, CTRL_REG1_G, self._odr_code << 5 | self._fs_g << 3),
            (ag, CTRL_REG6_XL, self._odr_code << 5 | self._fs_xl << 3),
            (m, CTRL_REG1_M, OM_ULTRA_HIGH << 5 | self._do << 2),
            (m, CTRL_REG2_M, self._fs_m << 5),
            (m, CTRL_REG4_M, OM_ULTRA_HIGH << 2),
            (m, CTRL_REG5_M, BDU),
            (m, CTRL_REG3_M, MD_CONTINUOUS),
        ]

    def describe(self) -> list[str]:
        """Return both devices and the configuration."""
        s = self.s
        return [f'LSM9DS1 accel/gyro at {self.ag.name} (WHO_AM_I 0x{WHO_AM_I_AG_VALUE:02x}), '
                f'magnetometer at {self.m.name} (WHO_AM_I 0x{WHO_AM_I_M_VALUE:02x})',
                f'odr {s.odr:g} Hz, +-{s.gyro_range:g} dps, +-{s.accel_range:g} g, mag '
                f'{s.mag_odr:g} Hz +-{s.mag_range:g} gauss']

    def read(self) -> ImuSample | None:
        """Read status + gyro + accel in one burst, the magnetometer when it has news."""
        block = self.ag.read_block(STATUS_REG_G, OUT_X_L_XL + 6 - STATUS_REG_G)
        self.status = status = block[STATUS_REG - STATUS_REG_G]
        self.corrupt = status == 0xFF
        if self.corrupt or (status & (XLDA | GDA)) != (XLDA | GDA):
            return None
        gyro = np.frombuffer(block, '<i2', 3, OUT_X_L_G - STATUS_REG_G) * self._gyro_scale
        accel = np.frombuffer(block, '<i2', 3, OUT_X_L_XL - STATUS_REG_G) * self._accel_scale
        mblock = self.m.read_block(STATUS_REG_M | AUTO_INCREMENT_M, 7)
        mag = None
        if mblock[0] != 0xFF and mblock[0] & ZYXDA:
            mag = np.frombuffer(mblock, '<i2', 3, 1) * self._mag_scale
        return ImuSample(gyro, accel, mag)

    def noise(self) -> Noise:
        """Return the noise per sample of the configuration."""
        return self.s.noise(self.s.odr, self.s.odr)


class Lsm9ds1ImuNode(I2cImuNode):
    """LSM9DS1 driver: the chain's source (see ``common.I2cImuNode``)."""

    def __init__(self, node_name: str = 'imu', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Lsm9ds1Settings.from_params, Lsm9ds1Chips,
                         **kwargs)
