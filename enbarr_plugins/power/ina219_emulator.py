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

``Ina219EmulatorNode`` puts the chip on the shared emulated bus
(``emulation.get_or_create('i2c', name, FakeI2cBus)``) when started; the battery it measures is
its live parameters ``volts`` and ``amps``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus

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


SPECS = [
    ParamSpec('name', 'default', "Name of the emulated bus (the driver's bus: 'emulated' for "
              "'default', else 'emulated:NAME')", read_only=True),
    ParamSpec('address', ADDRESS, 'I2C address of the emulated chip', '', 3, 0x77,
              read_only=True),
    ParamSpec('shunt', 0.1, 'Shunt resistance of the emulated board', 'ohm', 0.0001, 10.0,
              read_only=True),
    ParamSpec('volts', 14.8, 'Battery voltage the chip measures', 'V', 0.0, 32.0),
    ParamSpec('amps', 1.0, 'Load current the chip measures (positive: drawn)', 'A', -30.0,
              30.0),
]


@dataclass(frozen=True)
class EmulatorSettings:
    """Settings of ``Ina219EmulatorNode`` (``SPECS``)."""

    name: str
    address: int
    shunt: float   # [ohm]
    volts: float   # [V]
    amps: float    # [A]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> EmulatorSettings:
        """Build from the parameters."""
        return cls(name=v['name'], address=v['address'], shunt=float(v['shunt']),
                   volts=float(v['volts']), amps=float(v['amps']))


class Ina219EmulatorNode(EnbarrNode):
    """An emulated INA219 for profiles without hardware; see the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'ina219_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: EmulatorSettings
        self.chip = Ina219Chip()
        self.bind_settings(SPECS, EmulatorSettings.from_params, self._apply)
        self.bus: FakeI2cBus | None = None

    def _apply(self, settings: EmulatorSettings) -> None:
        self.settings = settings
        self.chip.shunt, self.chip.volts, self.chip.amps = (
            settings.shunt, settings.volts, settings.amps)

    def start(self) -> None:
        """Put the chip on the shared emulated bus (a profile check builds, never starts)."""
        if self.bus is None:
            self.bus = emulation.plug_i2c(self.settings.name, {self.settings.address: self.chip})
        super().start()

    def destroy_node(self) -> None:
        """Unplug the chip; withdraw the bus when nothing else sits on it."""
        bus, self.bus = self.bus, None
        if bus is not None:
            emulation.unplug_i2c(self.settings.name, bus, {self.settings.address: self.chip})
        super().destroy_node()
