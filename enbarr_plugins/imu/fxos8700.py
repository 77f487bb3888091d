"""NXP FXOS8700CQ (accelerometer + magnetometer) + FXAS21002C (gyroscope) over I2C.

The pair the Enbarr README names, as on the Adafruit "Precision NXP 9-DOF" breakout: the
FXOS8700CQ at 0x1F (WHO_AM_I 0x0D = 0xC7), the FXAS21002C at 0x21 (WHO_AM_I 0x0C = 0xD7);
registers, codes and sensitivities in ``fxos8700_protocol.py`` (NXP data sheets).

The FXOS8700CQ changes every field but CTRL_REG1.ACTIVE only in standby, so the driver puts
it in standby, sets the range, high resolution, hybrid mode (accelerometer and magnetometer,
oversampling 7) with the hybrid auto-increment, then the rate and ACTIVE (low noise at 2 and
4 g); the FXAS21002C likewise (standby, range, rate and ACTIVE; it needs 1/ODR + 60 ms before
its first sample). Each poll reads the gyroscope (7 bytes from STATUS) and then the
accelerometer and magnetometer in one 13-byte burst from STATUS.

Axes (imu_link = FLU): both chips' axes as printed on the packages; on the Adafruit board
they are aligned with each other and with the silkscreen arrows. Mount the board with X
forward and Z up (or give the mounting in the TF base_link -> imu_link): chip -> FLU
unchanged for the accelerometer, the magnetometer and the gyroscope. Another board may turn
one chip: check the silkscreen.

Noise: FXAS21002C 0.025 dps/sqrt(Hz) (data sheet table 5, Nd); FXOS8700CQ accelerometer
126 ug/sqrt(Hz) (data sheet table 2, normal mode); magnetometer RMS noise depends on the
oversampling, 1 uT is an assumption (``mag_noise``; measure your unit). Variances are
(density * sqrt(ODR / 2))^2.
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
from enbarr_plugins.imu.fxos8700_protocol import (
    ACCEL_ODR, ACCEL_RANGE, ACTIVE, ADDRESS, CTRL_REG0, CTRL_REG1, CTRL_REG2, FXAS_WHO_AM_I,
    FXAS_WHO_AM_I_VALUE, FXOS_WHO_AM_I, FXOS_WHO_AM_I_VALUE, G_ACTIVE, G_CTRL_REG1,
    GYRO_ADDRESS, GYRO_ODR, GYRO_RANGE, HYB_AUTOINC_MODE, LNOISE, M_CTRL_REG1, M_CTRL_REG2,
    M_HYBRID_OS7, MAG_LSB, MODS_HIGH_RESOLUTION, STATUS, XYZ_DATA_CFG, ZYXDR)

SPECS = [
    ParamSpec('address', ADDRESS, 'I2C address of the FXOS8700CQ (0x1c..0x1f by SA0/SA1)', '',
              3, 0x77, read_only=True),
    ParamSpec('gyro_address', GYRO_ADDRESS, 'I2C address of the FXAS21002C (0x20 or 0x21)',
              '', 3, 0x77, read_only=True),
    ParamSpec('odr', 200.0, 'Accelerometer/magnetometer output data rate (hybrid mode): 400, '
              '200, 100, 50, 25, 6.25, 3.125 or 0.7813', 'Hz', read_only=True),
    ParamSpec('accel_range', 4.0, 'Accelerometer full scale: 2, 4 or 8', 'g', read_only=True),
    ParamSpec('gyro_odr', 200.0, 'Gyroscope output data rate: 800, 400, 200, 100, 50, 25 or '
              '12.5', 'Hz', read_only=True),
    ParamSpec('gyro_range', 500.0, 'Gyroscope full scale: 250, 500, 1000 or 2000', 'deg/s',
              read_only=True),
    *noise_specs(gyro=0.025, accel=126e-6, mag=1e-6),
]


@dataclass(frozen=True)
class Fxos8700Settings(I2cImuSettings):
    """Settings of ``Fxos8700ImuNode`` (the common ones of ``I2cImuSettings`` + ``SPECS``)."""

    address: int
    gyro_address: int
    odr: float                  # [Hz]
    accel_range: float          # [g]
    gyro_odr: float             # [Hz]
    gyro_range: float           # [dps]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Fxos8700Settings:
        """Build from the parameters; ``ValueError`` names the parameter and the allowed set."""
        odr = choice('odr', v['odr'], list(ACCEL_ODR))
        gyro_odr = choice('gyro_odr', v['gyro_odr'], list(GYRO_ODR))
        return cls(**common_settings(v, min(odr, gyro_odr),
                                  f'odr {odr:g} Hz, gyro_odr {gyro_odr:g} Hz'),
                   address=check_address('address', v['address']),
                   gyro_address=check_address('gyro_address', v['gyro_address']), odr=odr,
                   accel_range=choice('accel_range', v['accel_range'], list(ACCEL_RANGE)),
                   gyro_odr=gyro_odr,
                   gyro_range=choice('gyro_range', v['gyro_range'], list(GYRO_RANGE)))


def default_settings(**changes: Any) -> Fxos8700Settings:
    """Return the settings of the parameter defaults and ``changes`` (check-device, tests)."""
    return parameter_defaults(SPECS, Fxos8700Settings.from_params, **changes)


class Fxos8700Chips(ImuChips):
    """The FXOS8700CQ and FXAS21002C of one board: configuration and reads."""

    def __init__(self, bus: Bus, s: Fxos8700Settings) -> None:
        super().__init__(bus, s)
        self.am = bus.device(s.address)
        self.g = bus.device(s.gyro_address)
        self._fs, accel_lsb = ACCEL_RANGE[s.accel_range]
        self._gfs, gyro_lsb = GYRO_RANGE[s.gyro_range]
        self._accel_scale = accel_lsb * G
        self._gyro_scale = gyro_lsb * DEG
        self._gyro: np.ndarray | None = None

    @staticmethod
    def addresses(s: Fxos8700Settings) -> tuple[int, int]:
        """Return the FXOS8700CQ and FXAS21002C addresses."""
        return s.address, s.gyro_address

    def identities(self) -> list[tuple[Any, int, int, str]]:
        """Return both WHO_AM_Is."""
        return [(self.am, FXOS_WHO_AM_I, FXOS_WHO_AM_I_VALUE, 'FXOS8700CQ'),
                (self.g, FXAS_WHO_AM_I, FXAS_WHO_AM_I_VALUE, 'FXAS21002C')]

    def config(self) -> list[tuple[Any, int, int]]:
        """Return the (device, register, value) writes, standby first (data sheets)."""
        lnoise = LNOISE if self.s.accel_range <= 4.0 else 0
        return [
            (self.am, CTRL_REG1, 0x00),  # standby: the other fields change only there
            (self.am, XYZ_DATA_CFG, self._fs),
            (self.am, CTRL_REG2, MODS_HIGH_RESOLUTION),
            (self.am, M_CTRL_REG1, M_HYBRID_OS7),
            (self.am, M_CTRL_REG2, HYB_AUTOINC_MODE),
            (self.am, CTRL_REG1, ACCEL_ODR[self.s.odr] << 3 | lnoise | ACTIVE),
            (self.g, G_CTRL_REG1, 0x00),
            (self.g, CTRL_REG0, self._gfs),
            (self.g, G_CTRL_REG1, GYRO_ODR[self.s.gyro_odr] << 2 | G_ACTIVE),
        ]

    def describe(self) -> list[str]:
        """Return both chips and the configuration."""
        s = self.s
        return [f'FXOS8700CQ at {self.am.name} (WHO_AM_I 0x{FXOS_WHO_AM_I_VALUE:02x}), '
                f'FXAS21002C at {self.g.name} (WHO_AM_I 0x{FXAS_WHO_AM_I_VALUE:02x})',
                f'accel/mag {s.odr:g} Hz hybrid, +-{s.accel_range:g} g; gyro '
                f'{s.gyro_odr:g} Hz, +-{s.gyro_range:g} dps']

    def read(self) -> ImuSample | None:
        """One burst per chip; a sample when the accelerometer/magnetometer has a new one.

        The gyroscope's latest value is kept (it may run faster than the accelerometer).
        """
        gblock = self.g.read_block(STATUS, 7)
        if gblock[0] != 0xFF and gblock[0] & ZYXDR:
            self._gyro = np.frombuffer(gblock, '>i2', 3, 1) * self._gyro_scale
        block = self.am.read_block(STATUS, 13)
        self.status = status = block[0]
        self.corrupt = status == 0xFF or gblock[0] == 0xFF
        if self.corrupt or not status & ZYXDR or self._gyro is None:
            return None
        accel = (np.frombuffer(block, '>i2', 3, 1) >> 2) * self._accel_scale
        mag = np.frombuffer(block, '>i2', 3, 7) * MAG_LSB
        return ImuSample(self._gyro, accel, mag)

    def noise(self) -> Noise:
        """Return the noise per sample of the configuration."""
        return self.s.noise(self.s.gyro_odr, self.s.odr)


class Fxos8700ImuNode(I2cImuNode):
    """FXOS8700CQ + FXAS21002C driver: the chain's source (see ``common.I2cImuNode``)."""

    def __init__(self, node_name: str = 'imu', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Fxos8700Settings.from_params, Fxos8700Chips,
                         **kwargs)
