"""An emulated LSM9DS1 on the emulated I2C bus, measuring the simulator's truth.

The register files of the two devices (ST DocID025715 Rev 3, section 7; register names and
bits as in ``enbarr_plugins.imu.lsm9ds1``): WHO_AM_I, the control registers with their
range and rate meaning, STATUS data-ready bits set by each new sample and cleared when the
outputs are read, 16-bit little-endian outputs in the chip's axes (the magnetometer's X
opposite the accelerometer's). Auto-increment as the chip does it: the accel/gyro device
advances when CTRL_REG8.IF_ADD_INC is set (power-on default), the magnetometer only when
the sub-address MSB is set (datasheet 6.1.1, Linux st_magn ``multi_read_bit``), otherwise a
burst reads one register again (the strict reading: hobby code that reads without the MSB
suggests some parts are more lenient; the driver sets it either way).
Power-on defaults: accel/gyro and magnetometer powered down (CTRL_REG1_G = 0,
CTRL_REG3_M = 0x03), so a chip that lost its configuration produces no data.

``Lsm9ds1EmulatorNode`` puts the two devices on the shared emulated bus
(``emulation.get_or_create('i2c', name, FakeI2cBus)``, where the PCA9685 emulator also sits)
and feeds them ``sim/imu``; see ``common.EmulatorNode``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from enbarr_core.framework.checks import floats
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu import lsm9ds1 as chip
from enbarr_plugins.imu.common import (
    check_address, ChipEmulator, DEG, EmulatorNode, encode, G)
from enbarr_plugins.transport.i2c import FakeI2cBus

#: Noise the emulator adds per sample: std [rad/s], [m/s^2] at 238 Hz, [T] (see lsm9ds1.py).
GYRO_SIGMA = 0.015 * DEG * np.sqrt(119.0)
ACCEL_SIGMA = 200e-6 * G * np.sqrt(119.0)
MAG_SIGMA = 4e-7


class Lsm9ds1AccelGyro(ChipEmulator):
    """The accelerometer/gyroscope device (0x6b) of an LSM9DS1."""

    READ_ONLY = frozenset([chip.WHO_AM_I, chip.STATUS_REG_G, chip.STATUS_REG,
                           *range(chip.OUT_X_L_G, chip.OUT_X_L_G + 6),
                           *range(chip.OUT_X_L_XL, chip.OUT_X_L_XL + 6)])

    def __init__(self, seed: int = 1, gyro_bias: Any = (0.0, 0.0, 0.0),
                 accel_bias: Any = (0.0, 0.0, 0.0)) -> None:
        super().__init__(seed)
        self.gyro_bias = np.asarray(gyro_bias, dtype=float)
        self.accel_bias = np.asarray(accel_bias, dtype=float)
        self.power_on()

    def power_on(self) -> None:
        """Reset the registers to their power-on values (a brown-out, a replug)."""
        self.registers[:] = bytes(256)
        self.registers[chip.WHO_AM_I] = chip.WHO_AM_I_AG_VALUE
        self.registers[chip.CTRL_REG4] = 0x38
        self.registers[chip.CTRL_REG5_XL] = 0x38
        self.registers[chip.CTRL_REG8] = chip.IF_ADD_INC

    def set_identity(self, value: int) -> None:
        """Answer ``value`` to WHO_AM_I (a wrong chip at this address)."""
        self.registers[chip.WHO_AM_I] = value

    def _gyro_code(self) -> int:
        return self.registers[chip.CTRL_REG1_G] >> 5

    def odr(self) -> float:
        """Return the gyro ODR when it runs, else the accelerometer's standalone ODR."""
        g = self._gyro_code()
        if 1 <= g <= 6:
            return {v: k for k, v in chip.GYRO_ODR.items()}[g]
        a = self.registers[chip.CTRL_REG6_XL] >> 5
        return chip.ACCEL_ODR_OF_CODE.get(a, 0.0)

    def sample(self) -> None:
        """Write one sample of the truth (chip axes = FLU) and set the data-ready bits."""
        regs, rng, t = self.registers, self.rng, self.truth
        fs_xl = (regs[chip.CTRL_REG6_XL] >> 3) & 0x3
        accel_lsb = {code: lsb for code, lsb in chip.ACCEL_RANGE.values()}[fs_xl] * G
        accel = t.accel + self.accel_bias + rng.normal(0.0, ACCEL_SIGMA, 3)
        regs[chip.OUT_X_L_XL:chip.OUT_X_L_XL + 6] = encode(accel, accel_lsb, big_endian=False)
        ready = chip.XLDA
        if 1 <= self._gyro_code() <= 6:
            fs_g = (regs[chip.CTRL_REG1_G] >> 3) & 0x3
            lsb = {code: lsb for code, lsb in chip.GYRO_RANGE.values()}.get(fs_g, 70e-3) * DEG
            gyro = t.gyro + self.gyro_bias + rng.normal(0.0, GYRO_SIGMA, 3)
            regs[chip.OUT_X_L_G:chip.OUT_X_L_G + 6] = encode(gyro, lsb, big_endian=False)
            ready |= chip.GDA
        for status in (chip.STATUS_REG_G, chip.STATUS_REG):
            regs[status] |= ready

    def read_registers(self, register: int, length: int) -> bytes:
        """Read with IF_ADD_INC auto-increment; reading an output clears its data-ready bit."""
        regs = self.registers
        step = 1 if regs[chip.CTRL_REG8] & chip.IF_ADD_INC else 0
        addresses = [(register + i * step) & 0xFF for i in range(length)]
        data = bytes(regs[a] for a in addresses)
        if any(chip.OUT_X_L_G <= a < chip.OUT_X_L_G + 6 for a in addresses):
            regs[chip.STATUS_REG_G] &= ~chip.GDA & 0xFF
            regs[chip.STATUS_REG] &= ~chip.GDA & 0xFF
        if any(chip.OUT_X_L_XL <= a < chip.OUT_X_L_XL + 6 for a in addresses):
            regs[chip.STATUS_REG_G] &= ~chip.XLDA & 0xFF
            regs[chip.STATUS_REG] &= ~chip.XLDA & 0xFF
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write control registers (read-only ones ignore writes); SW_RESET resets."""
        step = 1 if self.registers[chip.CTRL_REG8] & chip.IF_ADD_INC else 0
        for i, value in enumerate(data):
            a = (register + i * step) & 0xFF
            if a in self.READ_ONLY:
                continue
            if a == chip.CTRL_REG8 and value & 0x01:  # SW_RESET
                self.power_on()
                continue
            self.registers[a] = value


class Lsm9ds1Magnetometer(ChipEmulator):
    """The magnetometer device (0x1e) of an LSM9DS1."""

    READ_ONLY = frozenset([chip.WHO_AM_I, chip.STATUS_REG_M,
                           *range(chip.OUT_X_L_M, chip.OUT_X_L_M + 6)])

    def __init__(self, seed: int = 2) -> None:
        super().__init__(seed)
        self.power_on()

    def power_on(self) -> None:
        """Reset the registers to their power-on values."""
        self.registers[:] = bytes(256)
        self.registers[chip.WHO_AM_I] = chip.WHO_AM_I_M_VALUE
        self.registers[chip.CTRL_REG1_M] = 0x10   # 10 Hz
        self.registers[chip.CTRL_REG3_M] = 0x03   # power-down

    def set_identity(self, value: int) -> None:
        """Answer ``value`` to WHO_AM_I."""
        self.registers[chip.WHO_AM_I] = value

    def odr(self) -> float:
        """Return the ODR in continuous mode, else 0."""
        if self.registers[chip.CTRL_REG3_M] & 0x3:
            return 0.0
        code = (self.registers[chip.CTRL_REG1_M] >> 2) & 0x7
        return {v: k for k, v in chip.MAG_ODR.items()}[code]

    def sample(self) -> None:
        """Write the field in the magnetometer's own axes and set ZYXDA."""
        regs = self.registers
        fs = (regs[chip.CTRL_REG2_M] >> 5) & 0x3
        lsb = {code: lsb for code, lsb in chip.MAG_RANGE.values()}[fs] * chip.GAUSS
        m_chip = chip.MAG_AXES * self.truth.mag + self.rng.normal(0.0, MAG_SIGMA, 3)
        regs[chip.OUT_X_L_M:chip.OUT_X_L_M + 6] = encode(m_chip, lsb, big_endian=False)
        regs[chip.STATUS_REG_M] |= chip.ZYXDA | 0x07

    def read_registers(self, register: int, length: int) -> bytes:
        """Read; the sub-address MSB selects auto-increment; outputs read clear ZYXDA."""
        step = 1 if register & chip.AUTO_INCREMENT_M else 0
        base = register & 0x7F
        addresses = [(base + i * step) & 0x7F for i in range(length)]
        data = bytes(self.registers[a] for a in addresses)
        if any(chip.OUT_X_L_M <= a < chip.OUT_X_L_M + 6 for a in addresses):
            self.registers[chip.STATUS_REG_M] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write control registers."""
        step = 1 if register & chip.AUTO_INCREMENT_M else 0
        for i, value in enumerate(data):
            a = ((register & 0x7F) + i * step) & 0x7F
            if a not in self.READ_ONLY:
                self.registers[a] = value


def attach_lsm9ds1(bus: FakeI2cBus, address: int = chip.ADDRESS_AG,
                   mag_address: int = chip.ADDRESS_M, seed: int = 1,
                   **biases: Any) -> tuple[Lsm9ds1AccelGyro, Lsm9ds1Magnetometer]:
    """Put an emulated LSM9DS1 on ``bus``; return its two devices."""
    ag = Lsm9ds1AccelGyro(seed, **biases)
    m = Lsm9ds1Magnetometer(seed + 1)
    bus.attach(address, ag)
    bus.attach(mag_address, m)
    return ag, m


SPECS = [
    ParamSpec('address', chip.ADDRESS_AG, 'I2C address of the accelerometer/gyroscope', '',
              3, 0x77, read_only=True),
    ParamSpec('mag_address', chip.ADDRESS_M, 'I2C address of the magnetometer', '', 3, 0x77,
              read_only=True),
    ParamSpec('gyro_bias', [0.004, -0.003, 0.002], 'Constant gyro bias (chip axes)', 'rad/s',
              -0.5, 0.5, read_only=True),
    ParamSpec('accel_bias', [0.0, 0.0, 0.0], 'Constant accelerometer bias (chip axes)',
              'm/s^2', -5.0, 5.0, read_only=True),
]


@dataclass(frozen=True)
class Lsm9ds1EmulatorSettings:
    """Settings of ``Lsm9ds1EmulatorNode``."""

    name: str
    magnetic_field: tuple[float, ...]  # [T], odom ENU
    seed: int
    address: int
    mag_address: int
    gyro_bias: tuple[float, ...]       # [rad/s]
    accel_bias: tuple[float, ...]      # [m/s^2]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Lsm9ds1EmulatorSettings:
        """Build from the parameters; ``ValueError`` names the field."""
        return cls(name=v['name'], magnetic_field=floats('magnetic_field', v['magnetic_field'],
                                                         3),
                   seed=v['seed'], address=check_address('address', v['address']),
                   mag_address=check_address('mag_address', v['mag_address']),
                   gyro_bias=floats('gyro_bias', v['gyro_bias'], 3),
                   accel_bias=floats('accel_bias', v['accel_bias'], 3))


class Lsm9ds1EmulatorNode(EmulatorNode):
    """An emulated LSM9DS1 for profiles without hardware; see the module docstring."""

    def __init__(self, node_name: str = 'lsm9ds1_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Lsm9ds1EmulatorSettings.from_params, **kwargs)

    def make_chips(self) -> dict[int, Any]:
        """Return the two devices by address."""
        s = self.settings
        self.accel_gyro = Lsm9ds1AccelGyro(s.seed, s.gyro_bias, s.accel_bias)
        self.magnetometer = Lsm9ds1Magnetometer(s.seed + 1)
        return {s.address: self.accel_gyro, s.mag_address: self.magnetometer}
