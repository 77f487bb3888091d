"""An emulated LSM9DS1 on the emulated I2C bus, measuring the simulator's truth.

Written from ST DocID025715 Rev 3 (register map, section 6; register descriptions, sections 7
and 8; Table 3 sensitivities), with its own register table below: it imports neither the
driver nor its protocol module, so a wrong number on one side shows as a failed test instead
of agreeing with itself. The two register files: WHO_AM_I, the control registers with their
range and rate meaning, STATUS data-ready bits set by each new sample and cleared when the
outputs are read, 16-bit little-endian outputs in the chip's axes (the magnetometer's X
opposite the accelerometer's). Auto-increment as the chip does it: the accel/gyro device
advances when CTRL_REG8.IF_ADD_INC is set (power-on default), the magnetometer only when the
sub-address MSB is set (Linux st_magn ``multi_read_bit``), otherwise a burst reads one
register again (the strict reading: hobby code that reads without the MSB suggests some parts
are more lenient; the driver sets it either way).
Power-on defaults: accel/gyro and magnetometer powered down (CTRL_REG1_G = 0,
CTRL_REG3_M = 0x03), so a chip that lost its configuration produces no data.

``Lsm9ds1EmulatorNode`` puts the two devices on the shared emulated bus
(``emulation.get_or_create('i2c', name, FakeI2cBus)``, where the PCA9685 emulator also sits)
when started and feeds them ``sim/imu``; see ``chip_emulator.EmulatorNode``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu.chip_emulator import ChipEmulator, EmulatorNode, encode
from enbarr_plugins.imu.common import DEG, G
from enbarr_plugins.transport.i2c import FakeI2cBus

# The data sheet's register map and fields, typed again for the emulator.
ADDRESS_AG, ADDRESS_M = 0x6B, 0x1E
WHO_AM_I = 0x0F
CTRL_REG1_G, STATUS_REG_G, OUT_X_L_G = 0x10, 0x17, 0x18
CTRL_REG4, CTRL_REG5_XL, CTRL_REG6_XL, CTRL_REG8 = 0x1E, 0x1F, 0x20, 0x22
STATUS_REG, OUT_X_L_XL = 0x27, 0x28
XLDA, GDA, IF_ADD_INC, SW_RESET = 0x01, 0x02, 0x04, 0x01
CTRL_REG1_M, CTRL_REG2_M, CTRL_REG3_M, STATUS_REG_M, OUT_X_L_M = 0x20, 0x21, 0x22, 0x27, 0x28
ZYXDA, SUB_ADDRESS_MSB = 0x08, 0x80
#: ODR_G code -> gyro (and accelerometer) rate [Hz]; ODR_XL code -> accelerometer-only rate.
GYRO_RATE = {1: 14.9, 2: 59.5, 3: 119.0, 4: 238.0, 5: 476.0, 6: 952.0}
ACCEL_ONLY_RATE = {1: 10.0, 2: 50.0, 3: 119.0, 4: 238.0, 5: 476.0, 6: 952.0}
#: FS_G code -> [dps/LSB]; FS_XL code -> [g/LSB]; FS (magnetometer) code -> [gauss/LSB].
GYRO_LSB = {0: 8.75e-3, 1: 17.50e-3, 3: 70e-3}
ACCEL_LSB = {0: 0.061e-3, 2: 0.122e-3, 3: 0.244e-3, 1: 0.732e-3}
MAG_LSB = {0: 0.14e-3, 1: 0.29e-3, 2: 0.43e-3, 3: 0.58e-3}
#: DO code -> magnetometer rate [Hz].
MAG_RATE = {0: 0.625, 1: 1.25, 2: 2.5, 3: 5.0, 4: 10.0, 5: 20.0, 6: 40.0, 7: 80.0}
#: FLU -> the magnetometer's own axes (X opposite the accelerometer's).
MAG_AXES = np.array([-1.0, 1.0, 1.0])
GAUSS = 1e-4  # [T]

#: Noise the emulator adds per sample: std [rad/s], [m/s^2] at 238 Hz, [T] (see lsm9ds1.py).
GYRO_SIGMA = 0.015 * DEG * np.sqrt(119.0)
ACCEL_SIGMA = 200e-6 * G * np.sqrt(119.0)
MAG_SIGMA = 4e-7


class Lsm9ds1AccelGyro(ChipEmulator):
    """The accelerometer/gyroscope device (0x6b) of an LSM9DS1."""

    WHO_AM_I_REGISTER = WHO_AM_I
    POWER_ON = {WHO_AM_I: 0x68, CTRL_REG4: 0x38, CTRL_REG5_XL: 0x38, CTRL_REG8: IF_ADD_INC}
    READ_ONLY = frozenset([WHO_AM_I, STATUS_REG_G, STATUS_REG,
                           *range(OUT_X_L_G, OUT_X_L_G + 6), *range(OUT_X_L_XL, OUT_X_L_XL + 6)])

    def __init__(self, seed: int = 1, gyro_bias: Any = (0.0, 0.0, 0.0),
                 accel_bias: Any = (0.0, 0.0, 0.0)) -> None:
        super().__init__(seed)
        self.gyro_bias = np.asarray(gyro_bias, dtype=float)
        self.accel_bias = np.asarray(accel_bias, dtype=float)

    def _gyro_code(self) -> int:
        return self.registers[CTRL_REG1_G] >> 5

    def odr(self) -> float:
        """Return the gyro ODR when it runs, else the accelerometer's standalone ODR."""
        gyro = GYRO_RATE.get(self._gyro_code())
        if gyro is not None:
            return gyro
        return ACCEL_ONLY_RATE.get(self.registers[CTRL_REG6_XL] >> 5, 0.0)

    def sample(self) -> None:
        """Write one sample of the truth (chip axes = FLU) and set the data-ready bits."""
        regs, rng, t = self.registers, self.rng, self.truth
        accel_lsb = ACCEL_LSB[(regs[CTRL_REG6_XL] >> 3) & 0x3] * G
        accel = t.accel + self.accel_bias + rng.normal(0.0, ACCEL_SIGMA, 3)
        regs[OUT_X_L_XL:OUT_X_L_XL + 6] = encode(accel, accel_lsb, big_endian=False)
        ready = XLDA
        if self._gyro_code() in GYRO_RATE:
            # FS_G code 2 is not available (data sheet); the chip's behaviour there is unknown.
            lsb = GYRO_LSB.get((regs[CTRL_REG1_G] >> 3) & 0x3, GYRO_LSB[3]) * DEG
            gyro = t.gyro + self.gyro_bias + rng.normal(0.0, GYRO_SIGMA, 3)
            regs[OUT_X_L_G:OUT_X_L_G + 6] = encode(gyro, lsb, big_endian=False)
            ready |= GDA
        for status in (STATUS_REG_G, STATUS_REG):
            regs[status] |= ready

    def read_registers(self, register: int, length: int) -> bytes:
        """Read with IF_ADD_INC auto-increment; reading an output clears its data-ready bit."""
        regs = self.registers
        step = 1 if regs[CTRL_REG8] & IF_ADD_INC else 0
        addresses = [(register + i * step) & 0xFF for i in range(length)]
        data = bytes(regs[a] for a in addresses)
        if any(OUT_X_L_G <= a < OUT_X_L_G + 6 for a in addresses):
            regs[STATUS_REG_G] &= ~GDA & 0xFF
            regs[STATUS_REG] &= ~GDA & 0xFF
        if any(OUT_X_L_XL <= a < OUT_X_L_XL + 6 for a in addresses):
            regs[STATUS_REG_G] &= ~XLDA & 0xFF
            regs[STATUS_REG] &= ~XLDA & 0xFF
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write control registers (read-only ones ignore writes); SW_RESET resets."""
        step = 1 if self.registers[CTRL_REG8] & IF_ADD_INC else 0
        for i, value in enumerate(data):
            a = (register + i * step) & 0xFF
            if a in self.READ_ONLY:
                continue
            if a == CTRL_REG8 and value & SW_RESET:
                self.power_on()
                continue
            self.registers[a] = value


class Lsm9ds1Magnetometer(ChipEmulator):
    """The magnetometer device (0x1e) of an LSM9DS1."""

    WHO_AM_I_REGISTER = WHO_AM_I
    POWER_ON = {WHO_AM_I: 0x3D, CTRL_REG1_M: 0x10, CTRL_REG3_M: 0x03}  # 10 Hz, power-down
    READ_ONLY = frozenset([WHO_AM_I, STATUS_REG_M, *range(OUT_X_L_M, OUT_X_L_M + 6)])

    def __init__(self, seed: int = 2) -> None:
        super().__init__(seed)

    def odr(self) -> float:
        """Return the ODR in continuous mode, else 0."""
        if self.registers[CTRL_REG3_M] & 0x3:
            return 0.0
        return MAG_RATE[(self.registers[CTRL_REG1_M] >> 2) & 0x7]

    def sample(self) -> None:
        """Write the field in the magnetometer's own axes and set ZYXDA."""
        regs = self.registers
        lsb = MAG_LSB[(regs[CTRL_REG2_M] >> 5) & 0x3] * GAUSS
        m_chip = MAG_AXES * self.truth.mag + self.rng.normal(0.0, MAG_SIGMA, 3)
        regs[OUT_X_L_M:OUT_X_L_M + 6] = encode(m_chip, lsb, big_endian=False)
        regs[STATUS_REG_M] |= ZYXDA | 0x07

    def read_registers(self, register: int, length: int) -> bytes:
        """Read; the sub-address MSB selects auto-increment; outputs read clear ZYXDA."""
        step = 1 if register & SUB_ADDRESS_MSB else 0
        base = register & 0x7F
        addresses = [(base + i * step) & 0x7F for i in range(length)]
        data = bytes(self.registers[a] for a in addresses)
        if any(OUT_X_L_M <= a < OUT_X_L_M + 6 for a in addresses):
            self.registers[STATUS_REG_M] = 0
        return data

    def write_registers(self, register: int, data: bytes) -> None:
        """Write control registers."""
        step = 1 if register & SUB_ADDRESS_MSB else 0
        for i, value in enumerate(data):
            a = ((register & 0x7F) + i * step) & 0x7F
            if a not in self.READ_ONLY:
                self.registers[a] = value


def attach_lsm9ds1(bus: FakeI2cBus, address: int = ADDRESS_AG, mag_address: int = ADDRESS_M,
                   seed: int = 1,
                   **biases: Any) -> tuple[Lsm9ds1AccelGyro, Lsm9ds1Magnetometer]:
    """Put an emulated LSM9DS1 on ``bus``; return its two devices."""
    ag = Lsm9ds1AccelGyro(seed, **biases)
    m = Lsm9ds1Magnetometer(seed + 1)
    bus.attach(address, ag)
    bus.attach(mag_address, m)
    return ag, m


ADDRESS_SPECS = [
    ParamSpec('address', ADDRESS_AG, 'I2C address of the accelerometer/gyroscope', '', 3, 0x77,
              read_only=True),
    ParamSpec('mag_address', ADDRESS_M, 'I2C address of the magnetometer', '', 3, 0x77,
              read_only=True),
]


class Lsm9ds1EmulatorNode(EmulatorNode):
    """An emulated LSM9DS1 for profiles without hardware; see the module docstring."""

    def __init__(self, node_name: str = 'lsm9ds1_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, ADDRESS_SPECS, **kwargs)

    def make_chips(self) -> dict[int, ChipEmulator]:
        """Return the two devices by address."""
        s = self.settings
        address, mag_address = s.addresses
        self.accel_gyro = Lsm9ds1AccelGyro(s.seed, s.gyro_bias, s.accel_bias)
        self.magnetometer = Lsm9ds1Magnetometer(s.seed + 1)
        return {address: self.accel_gyro, mag_address: self.magnetometer}
