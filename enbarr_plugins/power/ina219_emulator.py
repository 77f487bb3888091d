"""An emulated TI INA219 on the emulated I2C bus, byte by byte.

Written from the INA219 data sheet (SBOS448) with its own register numbers and scaling: it
imports neither the driver nor its protocol module, so a wrong number on one side shows as a
failed test. What it does as the chip does: 16-bit registers read MSB first; a write of
0x8000 to the configuration resets every register (calibration back to 0); the shunt voltage
register holds the true current times the shunt resistance in 10 uV steps, the bus voltage
register the true voltage in 4 mV steps in bits 15..3 with CNVR (bit 1) set; the current
register is trunc(shunt_register * calibration / 4096) and the power register
trunc(current_register * bus_register / 5000) (the data sheet's equations 4 and 5), both 0
while the calibration is 0.
"""

from __future__ import annotations

import math

ADDRESS = 0x40
REG_CONFIG, REG_SHUNT, REG_BUS, REG_POWER, REG_CURRENT, REG_CAL = 0, 1, 2, 3, 4, 5
CONFIG_AT_RESET = 0x399F


class Ina219Chip:
    """The chip's registers, measuring ``volts`` [V] and ``amps`` [A] across ``shunt`` [ohm]."""

    def __init__(self, shunt: float = 0.1, volts: float = 12.0, amps: float = 0.0) -> None:
        self.shunt = shunt
        self.volts = volts
        self.amps = amps
        self.config = CONFIG_AT_RESET
        self.calibration = 0
        self.resets = 0

    def brown_out(self) -> None:
        """Lose the registers, as a supply dip does."""
        self.config, self.calibration = CONFIG_AT_RESET, 0
        self.resets += 1

    def _registers(self) -> dict[int, int]:
        shunt = max(-32000, min(32000, round(self.amps * self.shunt / 10e-6)))
        bus_steps = max(0, min(8000, round(self.volts / 4e-3)))
        bus = (bus_steps << 3) | 0x2
        current = math.trunc(shunt * self.calibration / 4096)
        power = math.trunc(abs(current) * bus_steps / 5000)
        return {REG_CONFIG: self.config, REG_SHUNT: shunt & 0xFFFF, REG_BUS: bus,
                REG_POWER: power & 0xFFFF, REG_CURRENT: current & 0xFFFF,
                REG_CAL: self.calibration}

    def read(self, register: int, length: int) -> bytes:
        """Return the register at the pointer, MSB first (the pointer does not advance)."""
        value = self._registers().get(register, 0)
        data = value.to_bytes(2, 'big')
        return (data * ((length + 1) // 2))[:length]

    def write(self, register: int, data: bytes) -> None:
        """Set the pointer; with two bytes, write the register (MSB first)."""
        if len(data) != 2:
            return
        value = int.from_bytes(data, 'big')
        if register == REG_CONFIG:
            if value & 0x8000:
                self.brown_out()
                self.resets -= 1
            else:
                self.config = value
        elif register == REG_CAL:
            self.calibration = value & 0xFFFE
