"""An emulated FXOS8700CQ + FXAS21002C pair on the emulated I2C bus, measuring the truth.

Written from the NXP data sheets (FXOS8700CQ Rev 8, FXAS21002C Rev 2.1), with its own register
table below: it imports neither the driver nor its protocol module. Register files: WHO_AM_I,
the control registers with their range and rate meaning (FXOS8700CQ: fields of CTRL_REG1
other than ACTIVE, XYZ_DATA_CFG and M_CTRL_REG1/2 change only in standby; writes while active
are ignored, as on the chip), STATUS data-ready set by each new sample and cleared when the
outputs are read, big-endian outputs (accelerometer 14-bit left-justified). Auto-increment:
FXOS8700CQ linear, except that with M_CTRL_REG2.HYB_AUTOINC_MODE a burst goes on from 0x06 to
0x33 (hybrid read); FXAS21002C wraps from 0x06 to 0x00 (0x01 with CTRL_REG3.WRAPTOONE). The
FXAS21002C makes no data for 1/ODR + 60 ms after it turns active. Power-on: both in standby.

``Fxos8700EmulatorNode`` puts both on the shared emulated bus when started and feeds them
``sim/imu``; see ``chip_emulator.EmulatorNode``. Chip axes = imu_link (FLU).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu.chip_emulator import ChipEmulator, EmulatorNode, encode
from enbarr_plugins.imu.common import DEG, G
from enbarr_plugins.transport.i2c import FakeI2cBus

# The data sheets' register maps and fields, typed again for the emulator.
ADDRESS, GYRO_ADDRESS = 0x1F, 0x21
STATUS, OUT_X_MSB = 0x00, 0x01                       # both chips
FXOS_WHO_AM_I, XYZ_DATA_CFG, CTRL_REG1, CTRL_REG2 = 0x0D, 0x0E, 0x2A, 0x2B
M_DR_STATUS, M_OUT_X_MSB, M_CTRL_REG1, M_CTRL_REG2 = 0x32, 0x33, 0x5B, 0x5C
ACTIVE, RST, HYB_AUTOINC_MODE, M_HMS_HYBRID, ZYXDR = 0x01, 0x40, 0x20, 0x03, 0x08
DR_STATUS, FXAS_WHO_AM_I, CTRL_REG0, G_CTRL_REG1, G_CTRL_REG3 = 0x07, 0x0C, 0x0D, 0x13, 0x15
G_ACTIVE, G_RST, WRAPTOONE = 0x02, 0x40, 0x08
#: CTRL_REG1 DR code -> accelerometer/magnetometer rate of one sensor alone [Hz] (hybrid
#: mode halves it).
SINGLE_RATE = {0: 800.0, 1: 400.0, 2: 200.0, 3: 100.0, 4: 50.0, 5: 12.5, 6: 6.25, 7: 1.5625}
#: XYZ_DATA_CFG FS code -> [g/LSB] of the 14-bit value (code 3 is reserved).
ACCEL_LSB = {0: 0.244e-3, 1: 0.488e-3, 2: 0.976e-3}
MAG_LSB = 0.1e-6  # [T]
#: CTRL_REG0 FS code -> [dps/LSB].
GYRO_LSB = {0: 62.5e-3, 1: 31.25e-3, 2: 15.625e-3, 3: 7.8125e-3}
#: G_CTRL_REG1 DR code -> gyro rate [Hz] (codes 6 and 7 both 12.5 Hz).
GYRO_RATE = {0: 800.0, 1: 400.0, 2: 200.0, 3: 100.0, 4: 50.0, 5: 25.0, 6: 12.5, 7: 12.5}

#: Emulated noise per sample (data sheet densities at the default 200 Hz; see fxos8700.py).
GYRO_SIGMA = 0.025 * DEG * np.sqrt(100.0)
ACCEL_SIGMA = 126e-6 * G * np.sqrt(100.0)
MAG_SIGMA = 1e-6
#: FXAS21002C standby -> active transition beyond one sample period [s].
GYRO_TURN_ON = 0.060


class Fxos8700Emulator(ChipEmulator):
    """The FXOS8700CQ accelerometer + magnetometer."""

    WHO_AM_I_REGISTER = FXOS_WHO_AM_I
    POWER_ON = {FXOS_WHO_AM_I: 0xC7}
    READ_ONLY = frozenset([STATUS, FXOS_WHO_AM_I, M_DR_STATUS,
                           *range(OUT_X_MSB, OUT_X_MSB + 6),
                           *range(M_OUT_X_MSB, M_OUT_X_MSB + 6)])
    STANDBY_ONLY = frozenset([XYZ_DATA_CFG, M_CTRL_REG1, M_CTRL_REG2])

    def __init__(self, seed: int = 1, accel_bias: Any = (0.0, 0.0, 0.0)) -> None:
        super().__init__(seed)
        self.accel_bias = np.asarray(accel_bias, dtype=float)

    def odr(self) -> float:
        """Return the hybrid-mode ODR while active, else 0."""
        ctrl = self.registers[CTRL_REG1]
        if not ctrl & ACTIVE:
            return 0.0
        rate = SINGLE_RATE[(ctrl >> 3) & 0x7]
        hybrid = self.registers[M_CTRL_REG1] & 0x3 == M_HMS_HYBRID
        return rate / 2.0 if hybrid else rate

    def sample(self) -> None:
        """Write accelerometer and magnetometer samples; set ZYXDR in both status registers."""
        regs = self.registers
        lsb = ACCEL_LSB.get(regs[XYZ_DATA_CFG] & 0x3, ACCEL_LSB[2]) * G
        accel = self.truth.accel + self.accel_bias + self.rng.normal(0.0, ACCEL_SIGMA, 3)
        regs[OUT_X_MSB:OUT_X_MSB + 6] = encode(accel, lsb, big_endian=True, bits=14)
        mag = self.truth.mag + self.rng.normal(0.0, MAG_SIGMA, 3)
        regs[M_OUT_X_MSB:M_OUT_X_MSB + 6] = encode(mag, MAG_LSB, big_endian=True)
        regs[STATUS] |= ZYXDR | 0x07
        regs[M_DR_STATUS] |= ZYXDR | 0x07

    def _next(self, address: int) -> int:
        if address == 0x06 and self.registers[M_CTRL_REG2] & HYB_AUTOINC_MODE:
            return M_OUT_X_MSB
        return (address + 1) & 0xFF

    def read_registers(self, register: int, length: int) -> bytes:
        """Burst read (hybrid auto-increment); reading the outputs clears the status."""
        addresses = [register]
        while len(addresses) < length:
            addresses.append(self._next(addresses[-1]))
        data = bytes(self.registers[a] for a in addresses)
        if any(OUT_X_MSB <= a < OUT_X_MSB + 6 for a in addresses):
            self.registers[STATUS] = 0
        if any(M_OUT_X_MSB <= a < M_OUT_X_MSB + 6 for a in addresses):
            self.registers[M_DR_STATUS] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write; in active mode only CTRL_REG1.ACTIVE and the free registers change."""
        a = register
        for value in data:
            active = self.registers[CTRL_REG1] & ACTIVE
            if a == CTRL_REG1 and active:
                value = (self.registers[a] & ~ACTIVE & 0xFF) | (value & ACTIVE)
                self.registers[a] = value
            elif a == CTRL_REG2 and value & RST:
                self.power_on()
            elif a not in self.READ_ONLY and not (active and a in self.STANDBY_ONLY):
                self.registers[a] = value
            a = self._next(a)


class Fxas21002cEmulator(ChipEmulator):
    """The FXAS21002C gyroscope."""

    WHO_AM_I_REGISTER = FXAS_WHO_AM_I
    POWER_ON = {FXAS_WHO_AM_I: 0xD7}
    READ_ONLY = frozenset([STATUS, FXAS_WHO_AM_I, DR_STATUS, *range(OUT_X_MSB, OUT_X_MSB + 6)])

    def __init__(self, seed: int = 2, gyro_bias: Any = (0.0, 0.0, 0.0)) -> None:
        self._active_ns = 0
        super().__init__(seed)
        self.gyro_bias = np.asarray(gyro_bias, dtype=float)

    def odr(self) -> float:
        """Return the ODR once active and settled, else 0."""
        ctrl = self.registers[G_CTRL_REG1]
        if not ctrl & G_ACTIVE:
            return 0.0
        rate = GYRO_RATE[(ctrl >> 2) & 0x7]
        if time.monotonic_ns() - self._active_ns < (GYRO_TURN_ON + 1.0 / rate) * 1e9:
            return 0.0
        return rate

    def sample(self) -> None:
        """Write one gyro sample; set ZYXDR in STATUS and DR_STATUS."""
        regs = self.registers
        lsb = GYRO_LSB[regs[CTRL_REG0] & 0x3] * DEG
        gyro = self.truth.gyro + self.gyro_bias + self.rng.normal(0.0, GYRO_SIGMA, 3)
        regs[OUT_X_MSB:OUT_X_MSB + 6] = encode(gyro, lsb, big_endian=True)
        regs[STATUS] |= ZYXDR | 0x07
        regs[DR_STATUS] |= ZYXDR | 0x07

    def read_registers(self, register: int, length: int) -> bytes:
        """Burst read, wrapping from 0x06 to 0x00 (or 0x01: WRAPTOONE)."""
        wrap = 0x01 if self.registers[G_CTRL_REG3] & WRAPTOONE else 0x00
        addresses = [register]
        while len(addresses) < length:
            last = addresses[-1]
            addresses.append(wrap if last == 0x06 else (last + 1) & 0xFF)
        data = bytes(self.registers[a] for a in addresses)
        if any(OUT_X_MSB <= a < OUT_X_MSB + 6 for a in addresses):
            self.registers[STATUS] = self.registers[DR_STATUS] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write; turning ACTIVE on starts the turn-on delay; RST resets."""
        for i, value in enumerate(data):
            a = (register + i) & 0xFF
            if a in self.READ_ONLY:
                continue
            if a == G_CTRL_REG1:
                if value & G_RST:
                    self.power_on()
                    continue
                if value & G_ACTIVE and not self.registers[a] & G_ACTIVE:
                    self._active_ns = time.monotonic_ns()
            self.registers[a] = value


def attach_fxos8700(bus: FakeI2cBus, address: int = ADDRESS, gyro_address: int = GYRO_ADDRESS,
                    seed: int = 1, gyro_bias: Any = (0.0, 0.0, 0.0),
                    accel_bias: Any = (0.0, 0.0, 0.0)
                    ) -> tuple[Fxos8700Emulator, Fxas21002cEmulator]:
    """Put an emulated FXOS8700CQ + FXAS21002C on ``bus``; return both."""
    am = Fxos8700Emulator(seed, accel_bias)
    g = Fxas21002cEmulator(seed + 1, gyro_bias)
    bus.attach(address, am)
    bus.attach(gyro_address, g)
    return am, g


ADDRESS_SPECS = [
    ParamSpec('address', ADDRESS, 'I2C address of the FXOS8700CQ', '', 3, 0x77,
              read_only=True),
    ParamSpec('gyro_address', GYRO_ADDRESS, 'I2C address of the FXAS21002C', '', 3, 0x77,
              read_only=True),
]


class Fxos8700EmulatorNode(EmulatorNode):
    """An emulated FXOS8700CQ + FXAS21002C for profiles without hardware."""

    def __init__(self, node_name: str = 'fxos8700_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, ADDRESS_SPECS, **kwargs)

    def make_chips(self) -> dict[int, ChipEmulator]:
        """Return both chips by address."""
        s = self.settings
        address, gyro_address = s.addresses
        self.accel_mag = Fxos8700Emulator(s.seed, s.accel_bias)
        self.gyro = Fxas21002cEmulator(s.seed + 1, s.gyro_bias)
        return {address: self.accel_mag, gyro_address: self.gyro}
