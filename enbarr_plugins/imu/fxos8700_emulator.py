"""An emulated FXOS8700CQ + FXAS21002C pair on the emulated I2C bus, measuring the truth.

Register files as in ``enbarr_plugins.imu.fxos8700`` (NXP data sheets): WHO_AM_I, the
control registers with their range and rate meaning (FXOS8700CQ: fields of CTRL_REG1 other
than ACTIVE, XYZ_DATA_CFG and M_CTRL_REG1/2 change only in standby; writes while active are
ignored, as on the chip), STATUS data-ready set by each new sample and cleared when the
outputs are read, big-endian outputs (accelerometer 14-bit left-justified). Auto-increment:
FXOS8700CQ linear, except that with M_CTRL_REG2.HYB_AUTOINC_MODE a burst goes on from 0x06 to
0x33 (hybrid read); FXAS21002C wraps from 0x06 to 0x00 (0x01 with CTRL_REG3.WRAPTOONE). The
FXAS21002C makes no data for 1/ODR + 60 ms after it turns active. Power-on: both in standby.

``Fxos8700EmulatorNode`` puts both on the shared emulated bus and feeds them ``sim/imu``;
see ``common.EmulatorNode``. Chip axes = imu_link (FLU).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import time
from typing import Any

import numpy as np

from enbarr_core.framework.checks import floats
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu import fxos8700 as chip
from enbarr_plugins.imu.common import (
    check_address, ChipEmulator, DEG, EmulatorNode, encode, G)
from enbarr_plugins.transport.i2c import FakeI2cBus

#: Emulated noise per sample (data sheet densities at the default 200 Hz; see fxos8700.py).
GYRO_SIGMA = 0.025 * DEG * np.sqrt(100.0)
ACCEL_SIGMA = 126e-6 * G * np.sqrt(100.0)
MAG_SIGMA = 1e-6
#: FXAS21002C standby -> active transition beyond one sample period [s].
GYRO_TURN_ON = 0.060


class Fxos8700Emulator(ChipEmulator):
    """The FXOS8700CQ accelerometer + magnetometer."""

    READ_ONLY = frozenset([chip.STATUS, chip.FXOS_WHO_AM_I, chip.M_DR_STATUS,
                           *range(chip.OUT_X_MSB, chip.OUT_X_MSB + 6),
                           *range(chip.M_OUT_X_MSB, chip.M_OUT_X_MSB + 6)])
    STANDBY_ONLY = frozenset([chip.XYZ_DATA_CFG, chip.M_CTRL_REG1, chip.M_CTRL_REG2])

    def __init__(self, seed: int = 1, accel_bias: Any = (0.0, 0.0, 0.0)) -> None:
        super().__init__(seed)
        self.accel_bias = np.asarray(accel_bias, dtype=float)
        self.power_on()

    def power_on(self) -> None:
        """Power-on register values: standby."""
        self.registers[:] = bytes(256)
        self.registers[chip.FXOS_WHO_AM_I] = chip.FXOS_WHO_AM_I_VALUE

    def set_identity(self, value: int) -> None:
        """Answer ``value`` to WHO_AM_I."""
        self.registers[chip.FXOS_WHO_AM_I] = value

    def odr(self) -> float:
        """Return the hybrid-mode ODR while active, else 0."""
        ctrl = self.registers[chip.CTRL_REG1]
        if not ctrl & chip.ACTIVE:
            return 0.0
        code = (ctrl >> 3) & 0x7
        rate = {v: k for k, v in chip.ACCEL_ODR.items()}[code]
        hybrid = self.registers[chip.M_CTRL_REG1] & 0x3 == 0x3
        return rate if hybrid else 2.0 * rate

    def sample(self) -> None:
        """Write accelerometer and magnetometer samples; set ZYXDR in both status registers."""
        regs = self.registers
        fs = regs[chip.XYZ_DATA_CFG] & 0x3
        lsb = {code: lsb for code, lsb in chip.ACCEL_RANGE.values()}.get(fs, 0.976e-3) * G
        accel = self.truth.accel + self.accel_bias + self.rng.normal(0.0, ACCEL_SIGMA, 3)
        regs[chip.OUT_X_MSB:chip.OUT_X_MSB + 6] = encode(accel, lsb, big_endian=True, bits=14)
        mag = self.truth.mag + self.rng.normal(0.0, MAG_SIGMA, 3)
        regs[chip.M_OUT_X_MSB:chip.M_OUT_X_MSB + 6] = encode(mag, chip.MAG_LSB, big_endian=True)
        regs[chip.STATUS] |= chip.ZYXDR | 0x07
        regs[chip.M_DR_STATUS] |= chip.ZYXDR | 0x07

    def _next(self, address: int) -> int:
        if address == 0x06 and self.registers[chip.M_CTRL_REG2] & chip.HYB_AUTOINC_MODE:
            return chip.M_OUT_X_MSB
        return (address + 1) & 0xFF

    def read_registers(self, register: int, length: int) -> bytes:
        """Burst read (hybrid auto-increment); reading the outputs clears the status."""
        addresses = [register]
        while len(addresses) < length:
            addresses.append(self._next(addresses[-1]))
        data = bytes(self.registers[a] for a in addresses)
        if any(chip.OUT_X_MSB <= a < chip.OUT_X_MSB + 6 for a in addresses):
            self.registers[chip.STATUS] = 0
        if any(chip.M_OUT_X_MSB <= a < chip.M_OUT_X_MSB + 6 for a in addresses):
            self.registers[chip.M_DR_STATUS] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write; in active mode only CTRL_REG1.ACTIVE and the free registers change."""
        a = register
        for value in data:
            active = self.registers[chip.CTRL_REG1] & chip.ACTIVE
            if a == chip.CTRL_REG1 and active:
                value = (self.registers[a] & ~chip.ACTIVE & 0xFF) | (value & chip.ACTIVE)
                self.registers[a] = value
            elif a == chip.CTRL_REG2 and value & 0x40:  # RST
                self.power_on()
            elif a not in self.READ_ONLY and not (active and a in self.STANDBY_ONLY):
                self.registers[a] = value
            a = self._next(a)


class Fxas21002cEmulator(ChipEmulator):
    """The FXAS21002C gyroscope."""

    READ_ONLY = frozenset([chip.STATUS, chip.FXAS_WHO_AM_I, 0x07,
                           *range(chip.OUT_X_MSB, chip.OUT_X_MSB + 6)])

    def __init__(self, seed: int = 2, gyro_bias: Any = (0.0, 0.0, 0.0)) -> None:
        super().__init__(seed)
        self.gyro_bias = np.asarray(gyro_bias, dtype=float)
        self._active_ns = 0
        self.power_on()

    def power_on(self) -> None:
        """Power-on register values: standby."""
        self.registers[:] = bytes(256)
        self.registers[chip.FXAS_WHO_AM_I] = chip.FXAS_WHO_AM_I_VALUE

    def set_identity(self, value: int) -> None:
        """Answer ``value`` to WHO_AM_I."""
        self.registers[chip.FXAS_WHO_AM_I] = value

    def odr(self) -> float:
        """Return the ODR once active and settled, else 0."""
        ctrl = self.registers[chip.G_CTRL_REG1]
        if not ctrl & chip.G_ACTIVE:
            return 0.0
        rate = 800.0 / (1 << min((ctrl >> 2) & 0x7, 6))
        if time.monotonic_ns() - self._active_ns < (GYRO_TURN_ON + 1.0 / rate) * 1e9:
            return 0.0
        return rate

    def sample(self) -> None:
        """Write one gyro sample; set ZYXDR in STATUS and DR_STATUS."""
        regs = self.registers
        lsb = 62.5e-3 / (1 << (regs[chip.CTRL_REG0] & 0x3)) * DEG
        gyro = self.truth.gyro + self.gyro_bias + self.rng.normal(0.0, GYRO_SIGMA, 3)
        regs[chip.OUT_X_MSB:chip.OUT_X_MSB + 6] = encode(gyro, lsb, big_endian=True)
        regs[chip.STATUS] |= chip.ZYXDR | 0x07
        regs[0x07] |= chip.ZYXDR | 0x07

    def read_registers(self, register: int, length: int) -> bytes:
        """Burst read, wrapping from 0x06 to 0x00 (or 0x01: WRAPTOONE)."""
        wrap = 0x01 if self.registers[chip.G_CTRL_REG3] & chip.WRAPTOONE else 0x00
        addresses = [register]
        while len(addresses) < length:
            last = addresses[-1]
            addresses.append(wrap if last == 0x06 else (last + 1) & 0xFF)
        data = bytes(self.registers[a] for a in addresses)
        if any(chip.OUT_X_MSB <= a < chip.OUT_X_MSB + 6 for a in addresses):
            self.registers[chip.STATUS] = self.registers[0x07] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write; turning ACTIVE on starts the turn-on delay; RST resets."""
        for i, value in enumerate(data):
            a = (register + i) & 0xFF
            if a in self.READ_ONLY:
                continue
            if a == chip.G_CTRL_REG1:
                if value & 0x40:  # RST
                    self.power_on()
                    continue
                if value & chip.G_ACTIVE and not self.registers[a] & chip.G_ACTIVE:
                    self._active_ns = time.monotonic_ns()
            self.registers[a] = value


def attach_fxos8700(bus: FakeI2cBus, address: int = chip.ADDRESS,
                    gyro_address: int = chip.GYRO_ADDRESS, seed: int = 1,
                    gyro_bias: Any = (0.0, 0.0, 0.0), accel_bias: Any = (0.0, 0.0, 0.0)
                    ) -> tuple[Fxos8700Emulator, Fxas21002cEmulator]:
    """Put an emulated FXOS8700CQ + FXAS21002C on ``bus``; return both."""
    am = Fxos8700Emulator(seed, accel_bias)
    g = Fxas21002cEmulator(seed + 1, gyro_bias)
    bus.attach(address, am)
    bus.attach(gyro_address, g)
    return am, g


SPECS = [
    ParamSpec('address', chip.ADDRESS, 'I2C address of the FXOS8700CQ', '', 3, 0x77,
              read_only=True),
    ParamSpec('gyro_address', chip.GYRO_ADDRESS, 'I2C address of the FXAS21002C', '', 3, 0x77,
              read_only=True),
    ParamSpec('gyro_bias', [0.004, -0.003, 0.002], 'Constant gyro bias', 'rad/s', -0.5, 0.5,
              read_only=True),
    ParamSpec('accel_bias', [0.0, 0.0, 0.0], 'Constant accelerometer bias', 'm/s^2', -5.0,
              5.0, read_only=True),
]


@dataclass(frozen=True)
class Fxos8700EmulatorSettings:
    """Settings of ``Fxos8700EmulatorNode``."""

    name: str
    magnetic_field: tuple[float, ...]  # [T], odom ENU
    seed: int
    address: int
    gyro_address: int
    gyro_bias: tuple[float, ...]       # [rad/s]
    accel_bias: tuple[float, ...]      # [m/s^2]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Fxos8700EmulatorSettings:
        """Build from the parameters; ``ValueError`` names the field."""
        return cls(name=v['name'],
                   magnetic_field=floats('magnetic_field', v['magnetic_field'], 3),
                   seed=v['seed'], address=check_address('address', v['address']),
                   gyro_address=check_address('gyro_address', v['gyro_address']),
                   gyro_bias=floats('gyro_bias', v['gyro_bias'], 3),
                   accel_bias=floats('accel_bias', v['accel_bias'], 3))


class Fxos8700EmulatorNode(EmulatorNode):
    """An emulated FXOS8700CQ + FXAS21002C for profiles without hardware."""

    def __init__(self, node_name: str = 'fxos8700_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, Fxos8700EmulatorSettings.from_params, **kwargs)

    def make_chips(self) -> dict[int, Any]:
        """Return both chips by address."""
        s = self.settings
        self.accel_mag = Fxos8700Emulator(s.seed, s.accel_bias)
        self.gyro = Fxas21002cEmulator(s.seed + 1, s.gyro_bias)
        return {s.address: self.accel_mag, s.gyro_address: self.gyro}
