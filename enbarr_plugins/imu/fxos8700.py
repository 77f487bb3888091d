"""NXP FXOS8700CQ (accelerometer + magnetometer) + FXAS21002C (gyroscope) over I2C.

The pair the Enbarr README names, as on the Adafruit "Precision NXP 9-DOF" breakout: the
FXOS8700CQ at 0x1F (WHO_AM_I 0x0D = 0xC7), the FXAS21002C at 0x21 (WHO_AM_I 0x0C = 0xD7).

FXOS8700CQ (NXP FXOS8700CQ data sheet Rev 8, sections 14-15; Linux
drivers/iio/imu/fxos8700_core.c):
  STATUS 0x00          DR_STATUS with the FIFO off: ZYXDR bit 3 (new X, Y and Z data)
  OUT_X_MSB 0x01..06   accelerometer, 14-bit left-justified two's complement, big-endian
  XYZ_DATA_CFG 0x0E    FS [1:0] 2/4/8 g = 0/1/2 (0.244/0.488/0.976 mg/LSB of the 14-bit value)
  CTRL_REG1 0x2A       ACTIVE bit 0, LNOISE bit 2 (2 and 4 g only), DR [5:3]; every field but
                       ACTIVE changes only in standby. Hybrid mode (accel + mag) halves the
                       ODR: DR 0..7 = 400, 200, 100, 50, 25, 6.25, 3.125, 0.7813 Hz
  CTRL_REG2 0x2B       MODS [1:0] 2 = high resolution
  M_OUT_X_MSB 0x33..38 magnetometer, 16-bit big-endian, 0.1 uT/LSB (fixed +-1200 uT)
  M_CTRL_REG1 0x5B     M_OS [4:2] oversampling, M_HMS [1:0] 3 = hybrid (accel + mag)
  M_CTRL_REG2 0x5C     HYB_AUTOINC_MODE bit 5: a burst read goes on from 0x06 to 0x33, so one
                       13-byte read from 0x00 returns status, accel and magnetometer
FXAS21002C (NXP FXAS21002C data sheet Rev 2.1, section 13; Linux
drivers/iio/gyro/fxas21002c_core.c):
  STATUS 0x00          DR_STATUS copy with the FIFO off: ZYXDR bit 3
  OUT_X_MSB 0x01..06   16-bit big-endian
  CTRL_REG0 0x0D       FS [1:0] 2000/1000/500/250 dps = 0..3 (62.5 mdps/LSB >> FS)
  CTRL_REG1 0x13       DR [4:2] 800 >> DR Hz (6, 7: 12.5 Hz), ACTIVE bit 1; the change from
                       standby to active takes 1/ODR + 60 ms (no data until then)

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
import math
from typing import Any

import numpy as np

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu.common import (
    Bus, check_address, check_identity, check_imu, choice, DEG, G, I2cImuNode, ImuChips,
    ImuSample, Noise, parse_bus)

# FXOS8700CQ
STATUS = 0x00
OUT_X_MSB = 0x01
FXOS_WHO_AM_I = 0x0D
FXOS_WHO_AM_I_VALUE = 0xC7
XYZ_DATA_CFG = 0x0E
CTRL_REG1 = 0x2A
CTRL_REG2 = 0x2B
M_DR_STATUS = 0x32
M_OUT_X_MSB = 0x33
M_CTRL_REG1 = 0x5B
M_CTRL_REG2 = 0x5C
ACTIVE, LNOISE = 0x01, 0x04
MODS_HIGH_RESOLUTION = 0x02
M_HYBRID_OS7 = 0x1F      # M_OS = 7, M_HMS = 3 (hybrid)
HYB_AUTOINC_MODE = 0x20
ZYXDR = 0x08
MAG_LSB = 0.1e-6         # [T]
# FXAS21002C
FXAS_WHO_AM_I = 0x0C
FXAS_WHO_AM_I_VALUE = 0xD7
CTRL_REG0 = 0x0D
G_CTRL_REG1 = 0x13
G_CTRL_REG3 = 0x15
G_ACTIVE = 0x02
WRAPTOONE = 0x08

ADDRESS = 0x1F
GYRO_ADDRESS = 0x21

#: Hybrid-mode ODR [Hz] -> CTRL_REG1 DR code.
ACCEL_ODR = {400.0: 0, 200.0: 1, 100.0: 2, 50.0: 3, 25.0: 4, 6.25: 5, 3.125: 6, 0.7813: 7}
#: Accelerometer full scale [g] -> (FS code, sensitivity [g/LSB] of the 14-bit value).
ACCEL_RANGE = {2.0: (0, 0.244e-3), 4.0: (1, 0.488e-3), 8.0: (2, 0.976e-3)}
#: Gyro ODR [Hz] -> CTRL_REG1 DR code.
GYRO_ODR = {800.0: 0, 400.0: 1, 200.0: 2, 100.0: 3, 50.0: 4, 25.0: 5, 12.5: 6}
#: Gyro full scale [dps] -> (FS code, sensitivity [dps/LSB]).
GYRO_RANGE = {2000.0: (0, 62.5e-3), 1000.0: (1, 31.25e-3), 500.0: (2, 15.625e-3),
              250.0: (3, 7.8125e-3)}

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
    ParamSpec('gyro_noise_density', 0.025, 'Gyro noise density (covariance)',
              'deg/s/sqrt(Hz)', 0.0, 10.0),
    ParamSpec('accel_noise_density', 126e-6, 'Accelerometer noise density (covariance)',
              'g/sqrt(Hz)', 0.0, 0.1),
    ParamSpec('mag_noise', 1e-6, 'Magnetometer noise, RMS per sample (covariance)', 'T', 0.0,
              1e-4),
]


@dataclass(frozen=True)
class Fxos8700Settings:
    """Settings of ``Fxos8700ImuNode``."""

    bus: str
    rate: float                 # poll (chain) rate [Hz]
    i2c_timeout: float          # [s]
    data_timeout: float         # [s]
    address: int
    gyro_address: int
    odr: float                  # [Hz]
    accel_range: float          # [g]
    gyro_odr: float             # [Hz]
    gyro_range: float           # [dps]
    gyro_noise_density: float   # [dps/sqrt(Hz)]
    accel_noise_density: float  # [g/sqrt(Hz)]
    mag_noise: float            # [T]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Fxos8700Settings:
        """Build from the parameters; ``ValueError`` names the parameter and the allowed set."""
        parse_bus(v['bus'])
        odr = choice('odr', v['odr'], list(ACCEL_ODR))
        gyro_odr = choice('gyro_odr', v['gyro_odr'], list(GYRO_ODR))
        if v['rate'] > min(odr, gyro_odr):
            raise ValueError(f'rate: {v["rate"]:g} Hz polls faster than the chips make samples '
                             f'(odr {odr:g} Hz, gyro_odr {gyro_odr:g} Hz)')
        return cls(bus=v['bus'], rate=v['rate'], i2c_timeout=v['i2c_timeout'],
                   data_timeout=v['data_timeout'],
                   address=check_address('address', v['address']),
                   gyro_address=check_address('gyro_address', v['gyro_address']), odr=odr,
                   accel_range=choice('accel_range', v['accel_range'], list(ACCEL_RANGE)),
                   gyro_odr=gyro_odr,
                   gyro_range=choice('gyro_range', v['gyro_range'], list(GYRO_RANGE)),
                   gyro_noise_density=v['gyro_noise_density'],
                   accel_noise_density=v['accel_noise_density'], mag_noise=v['mag_noise'])


def default_settings(**changes: Any) -> Fxos8700Settings:
    """Return the settings of the parameter defaults (check-device, tests)."""
    values = {s.name: s.default for s in SPECS}
    values.update(bus='1', rate=200.0, i2c_timeout=0.05, data_timeout=0.5)
    values.update(changes)
    return Fxos8700Settings.from_params(values)


class Fxos8700Chips(ImuChips):
    """The FXOS8700CQ and FXAS21002C of one board: configuration and reads."""

    def __init__(self, bus: Bus, s: Fxos8700Settings) -> None:
        self.am = bus.device(s.address)
        self.g = bus.device(s.gyro_address)
        self.s = s
        self._fs, accel_lsb = ACCEL_RANGE[s.accel_range]
        self._gfs, gyro_lsb = GYRO_RANGE[s.gyro_range]
        self._accel_scale = accel_lsb * G
        self._gyro_scale = gyro_lsb * DEG
        self._gyro: np.ndarray | None = None
        self.status = 0
        self.corrupt = False

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

    def open(self) -> list[str]:
        """Check both WHO_AM_Is, write the configuration and read it back."""
        check_identity(self.am, FXOS_WHO_AM_I, FXOS_WHO_AM_I_VALUE, 'FXOS8700CQ')
        check_identity(self.g, FXAS_WHO_AM_I, FXAS_WHO_AM_I_VALUE, 'FXAS21002C')
        writes = self.config()
        for dev, register, value in writes:
            dev.write_u8(register, value)
        final = {(dev.address, register): (dev, value) for dev, register, value in writes}
        for (_, register), (dev, value) in final.items():
            read = dev.read_u8(register)
            if read != value:
                raise DeviceError(f'{dev.name}: register 0x{register:02x} reads 0x{read:02x} '
                                  f'after writing 0x{value:02x}')
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
        s = self.s
        return Noise(gyro=s.gyro_noise_density * DEG * math.sqrt(s.gyro_odr / 2.0),
                     accel=s.accel_noise_density * G * math.sqrt(s.odr / 2.0),
                     mag=s.mag_noise)


class Fxos8700ImuNode(I2cImuNode):
    """FXOS8700CQ + FXAS21002C driver: the chain's source (see ``common.I2cImuNode``)."""

    def __init__(self, node_name: str = 'imu', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Fxos8700Settings.from_params, **kwargs)

    def addresses_text(self) -> str:
        """Return the two addresses ('0x1f+0x21')."""
        return f'0x{self.settings.address:02x}+0x{self.settings.gyro_address:02x}'

    def make_chips(self, bus: Bus) -> Fxos8700Chips:
        """Return the chips on ``bus``."""
        return Fxos8700Chips(bus, self.settings)


def check_device(target: CheckTarget) -> list[str]:
    """``enbarr check-device fxos8700``: identities, configuration and one SI sample."""
    from enbarr_plugins.imu.fxos8700_emulator import attach_fxos8700
    return check_imu(target, default_settings, Fxos8700Chips,
                     lambda fake, s: attach_fxos8700(fake, s.address, s.gyro_address))
