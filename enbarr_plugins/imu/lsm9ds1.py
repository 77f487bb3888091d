"""ST LSM9DS1 9-DOF IMU over I2C: ``imu/data_raw`` + ``imu/mag`` (the ROV's IMU).

Two I2C devices in one package: accelerometer + gyroscope at 0x6B (0x6A with SDO_AG low),
WHO_AM_I (0x0F) = 0x68; magnetometer at 0x1E (0x1C with SDO_M low), WHO_AM_I_M (0x0F) = 0x3D.

Registers used (ST DocID025715 "LSM9DS1 iNEMO inertial module" Rev 3, section 7 register
description; the same values in Linux drivers/iio/imu/st_lsm6dsx/st_lsm6dsx_core.c, the
ST_LSM9DS1_ID entry, and drivers/iio/magnetometer/st_magn_core.c, the LIS3MDL/LSM9DS1 entry):

accel/gyro
  CTRL_REG1_G 0x10   ODR_G [7:5] 14.9/59.5/119/238/476/952 Hz = 1..6, FS_G [4:3]
                     245/500/2000 dps = 0/1/3 (8.75/17.50/70 mdps/LSB)
  STATUS_REG  0x17   XLDA bit 0, GDA bit 1 (mirrored at 0x27)
  OUT_X_L_G   0x18   gyro X/Y/Z, 16-bit little-endian (L then H)
  CTRL_REG4   0x1E   Zen_G/Yen_G/Xen_G bits 5:3 (0x38: all on)
  CTRL_REG5_XL 0x1F  Zen_XL/Yen_XL/Xen_XL bits 5:3
  CTRL_REG6_XL 0x20  ODR_XL [7:5] (same codes; with the gyro on, the accelerometer runs at the
                     gyro's ODR), FS_XL [4:3] 2/16/4/8 g = 0/1/2/3 (0.061/0.732/0.122/0.244
                     mg/LSB)
  CTRL_REG8   0x22   BDU bit 6 (no torn samples), IF_ADD_INC bit 2 (auto-increment, default 1)
  OUT_X_L_XL  0x28   accel X/Y/Z, 16-bit little-endian
  One 23-byte burst from 0x17 reads status, gyro, (control registers), status, accel.
magnetometer
  CTRL_REG1_M 0x20   OM [6:5] (3: ultra-high performance X/Y), DO [4:2] 0.625 ... 80 Hz = 0..7
  CTRL_REG2_M 0x21   FS [6:5] 4/8/12/16 gauss = 0..3 (0.146/0.292/0.438/0.584 mgauss/LSB,
                     st_magn_core.c gains; the datasheet rounds to 0.14/0.29/0.43/0.58)
  CTRL_REG3_M 0x22   MD [1:0] 0 = continuous conversion (power-on default 3: power-down)
  CTRL_REG4_M 0x23   OMZ [3:2] (3: ultra-high performance Z)
  CTRL_REG5_M 0x24   BDU bit 6
  STATUS_REG_M 0x27  ZYXDA bit 3
  OUT_X_L_M   0x28   16-bit little-endian. The magnetometer auto-increments only when the MSB
                     of the sub-address is set (datasheet 6.1.1; st_magn ``multi_read_bit``):
                     the burst is read from 0x27 | 0x80.

Axes (imu_link = FLU). The driver's imu_link is the accel/gyro frame printed on the chip
(datasheet figure 2, "pin 1 indicator"): mount the board with the chip's X forward and Z up,
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
import math
from typing import Any

import numpy as np

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu.common import (
    Bus, check_address, check_identity, check_imu, choice, DEG, G, I2cImuNode, ImuChips,
    ImuSample, Noise, parse_bus)

# accelerometer + gyroscope
WHO_AM_I = 0x0F
WHO_AM_I_AG_VALUE = 0x68
CTRL_REG1_G = 0x10
STATUS_REG_G = 0x17
OUT_X_L_G = 0x18
CTRL_REG4 = 0x1E
CTRL_REG5_XL = 0x1F
CTRL_REG6_XL = 0x20
CTRL_REG8 = 0x22
STATUS_REG = 0x27
OUT_X_L_XL = 0x28
XLDA, GDA = 0x01, 0x02
BDU, IF_ADD_INC = 0x40, 0x04
# magnetometer
WHO_AM_I_M_VALUE = 0x3D
CTRL_REG1_M = 0x20
CTRL_REG2_M = 0x21
CTRL_REG3_M = 0x22
CTRL_REG4_M = 0x23
CTRL_REG5_M = 0x24
STATUS_REG_M = 0x27
OUT_X_L_M = 0x28
ZYXDA = 0x08
AUTO_INCREMENT_M = 0x80  # MSB of the sub-address: multi-byte read (magnetometer only)

ADDRESS_AG = 0x6B
ADDRESS_M = 0x1E

#: ODR [Hz] -> ODR_G code (the accelerometer takes the same code).
GYRO_ODR = {14.9: 1, 59.5: 2, 119.0: 3, 238.0: 4, 476.0: 5, 952.0: 6}
#: Accelerometer ODR [Hz] of each code (standalone; with the gyro on it follows the gyro).
ACCEL_ODR_OF_CODE = {1: 10.0, 2: 50.0, 3: 119.0, 4: 238.0, 5: 476.0, 6: 952.0}
#: Gyro full scale [dps] -> (FS_G code, sensitivity [dps/LSB]).
GYRO_RANGE = {245.0: (0, 8.75e-3), 500.0: (1, 17.5e-3), 2000.0: (3, 70e-3)}
#: Accelerometer full scale [g] -> (FS_XL code, sensitivity [g/LSB]).
ACCEL_RANGE = {2.0: (0, 0.061e-3), 4.0: (2, 0.122e-3), 8.0: (3, 0.244e-3),
               16.0: (1, 0.732e-3)}
#: Magnetometer ODR [Hz] -> DO code.
MAG_ODR = {0.625: 0, 1.25: 1, 2.5: 2, 5.0: 3, 10.0: 4, 20.0: 5, 40.0: 6, 80.0: 7}
#: Magnetometer full scale [gauss] -> (FS code, sensitivity [gauss/LSB]).
MAG_RANGE = {4.0: (0, 0.146e-3), 8.0: (1, 0.292e-3), 12.0: (2, 0.438e-3),
             16.0: (3, 0.584e-3)}
GAUSS = 1e-4  # [T]
#: Chip magnetometer axes -> FLU (see the module docstring).
MAG_AXES = np.array([-1.0, 1.0, 1.0])

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
    ParamSpec('gyro_noise_density', 0.015, 'Gyro white noise density (covariance)',
              'deg/s/sqrt(Hz)', 0.0, 10.0),
    ParamSpec('accel_noise_density', 200e-6, 'Accelerometer noise density (covariance)',
              'g/sqrt(Hz)', 0.0, 0.1),
    ParamSpec('mag_noise', 4e-7, 'Magnetometer noise, RMS per sample (covariance)', 'T', 0.0,
              1e-4),
]


@dataclass(frozen=True)
class Lsm9ds1Settings:
    """Settings of ``Lsm9ds1ImuNode`` (``BUS_SPECS`` of common + ``SPECS``)."""

    bus: str
    rate: float                 # poll (chain) rate [Hz]
    i2c_timeout: float          # [s]
    data_timeout: float         # [s]
    address: int
    mag_address: int
    odr: float                  # [Hz]
    gyro_range: float           # [dps]
    accel_range: float          # [g]
    mag_odr: float              # [Hz]
    mag_range: float            # [gauss]
    gyro_noise_density: float   # [dps/sqrt(Hz)]
    accel_noise_density: float  # [g/sqrt(Hz)]
    mag_noise: float            # [T]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Lsm9ds1Settings:
        """Build from the parameters; ``ValueError`` names the parameter and the allowed set."""
        parse_bus(v['bus'])
        odr = choice('odr', v['odr'], list(GYRO_ODR))
        if v['rate'] > odr:
            raise ValueError(f'rate: {v["rate"]:g} Hz polls faster than the chip makes samples '
                             f'(odr {odr:g} Hz); choose rate <= odr')
        return cls(bus=v['bus'], rate=v['rate'], i2c_timeout=v['i2c_timeout'],
                   data_timeout=v['data_timeout'],
                   address=check_address('address', v['address']),
                   mag_address=check_address('mag_address', v['mag_address']),
                   odr=odr, gyro_range=choice('gyro_range', v['gyro_range'], list(GYRO_RANGE)),
                   accel_range=choice('accel_range', v['accel_range'], list(ACCEL_RANGE)),
                   mag_odr=choice('mag_odr', v['mag_odr'], list(MAG_ODR)),
                   mag_range=choice('mag_range', v['mag_range'], list(MAG_RANGE)),
                   gyro_noise_density=v['gyro_noise_density'],
                   accel_noise_density=v['accel_noise_density'], mag_noise=v['mag_noise'])


def default_settings(**changes: Any) -> Lsm9ds1Settings:
    """Return the settings of the parameter defaults (check-device, tests)."""
    values = {s.name: s.default for s in SPECS}
    values.update(bus='1', rate=200.0, i2c_timeout=0.05, data_timeout=0.5)
    values.update(changes)
    return Lsm9ds1Settings.from_params(values)


class Lsm9ds1Chips(ImuChips):
    """The two I2C devices of an LSM9DS1 and how they are configured and read."""

    def __init__(self, bus: Bus, s: Lsm9ds1Settings) -> None:
        self.ag = bus.device(s.address)
        self.m = bus.device(s.mag_address)
        self.s = s
        self._odr_code = GYRO_ODR[s.odr]
        self._fs_g, gyro_lsb = GYRO_RANGE[s.gyro_range]
        self._fs_xl, accel_lsb = ACCEL_RANGE[s.accel_range]
        self._do, self._fs_m = MAG_ODR[s.mag_odr], MAG_RANGE[s.mag_range][0]
        self._gyro_scale = gyro_lsb * DEG                            # rad/s per LSB
        self._accel_scale = accel_lsb * G                            # m/s^2 per LSB
        self._mag_scale = MAG_RANGE[s.mag_range][1] * GAUSS * MAG_AXES  # T per LSB, FLU
        self.status = 0
        self.corrupt = False

    def config(self) -> list[tuple[Any, int, int]]:
        """Return the (device, register, value) writes of the configuration, in order."""
        ag, m = self.ag, self.m
        return [
            (ag, CTRL_REG8, BDU | IF_ADD_INC),
            (ag, CTRL_REG4, 0x38),
            (ag, CTRL_REG5_XL, 0x38),
            (ag, CTRL_REG1_G, self._odr_code << 5 | self._fs_g << 3),
            (ag, CTRL_REG6_XL, self._odr_code << 5 | self._fs_xl << 3),
            (m, CTRL_REG1_M, 0x3 << 5 | self._do << 2),
            (m, CTRL_REG2_M, self._fs_m << 5),
            (m, CTRL_REG4_M, 0x3 << 2),
            (m, CTRL_REG5_M, BDU),
            (m, CTRL_REG3_M, 0x00),
        ]

    def open(self) -> list[str]:
        """Check both WHO_AM_Is, write and verify the configuration."""
        check_identity(self.ag, WHO_AM_I, WHO_AM_I_AG_VALUE, 'LSM9DS1 accelerometer/gyroscope')
        check_identity(self.m, WHO_AM_I, WHO_AM_I_M_VALUE, 'LSM9DS1 magnetometer')
        for dev, register, value in self.config():
            dev.write_u8(register, value)
        for dev, register, value in self.config():
            read = dev.read_u8(register)
            if read != value:
                raise DeviceError(f'{dev.name}: register 0x{register:02x} reads 0x{read:02x} '
                                  f'after writing 0x{value:02x}')
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
        """Return the noise per sample of the configuration (density * sqrt(ODR / 2))."""
        s = self.s
        bw = math.sqrt(s.odr / 2.0)
        return Noise(gyro=s.gyro_noise_density * DEG * bw,
                     accel=s.accel_noise_density * G * bw, mag=s.mag_noise)


class Lsm9ds1ImuNode(I2cImuNode):
    """LSM9DS1 driver: the chain's source (see ``common.I2cImuNode``)."""

    def __init__(self, node_name: str = 'imu', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Lsm9ds1Settings.from_params, **kwargs)

    def addresses_text(self) -> str:
        """Return the two addresses ('0x6b+0x1e')."""
        return f'0x{self.settings.address:02x}+0x{self.settings.mag_address:02x}'

    def make_chips(self, bus: Bus) -> Lsm9ds1Chips:
        """Return the chips on ``bus``."""
        return Lsm9ds1Chips(bus, self.settings)


def check_device(target: CheckTarget) -> list[str]:
    """``enbarr check-device lsm9ds1``: identities, configuration and one sample in SI units."""
    from enbarr_plugins.imu.lsm9ds1_emulator import attach_lsm9ds1
    return check_imu(target, default_settings, Lsm9ds1Chips,
                     lambda fake, s: attach_lsm9ds1(fake, s.address, s.mag_address))
