"""An emulated Bosch BMP280 on the emulated I2C bus, byte by byte.

Written from the BMP280 data sheet (BST-BMP280-DS001) with its own register numbers and
formulas: it imports neither the driver nor its protocol module, so a wrong number on one
side shows as a failed test. What it does as the chip does: chip id 0xD0 reads 0x58; 0xB6
written to 0xE0 resets ctrl_meas and config to 0 (sleep) and the data registers to 0x80000;
the trimming parameters sit at 0x88..0x9F, little-endian, the data sheet's worked example's
by default (section 3.12); a burst read auto-increments the register address. In normal or
forced mode the data registers hold the raw values of the true pressure and temperature
(``pressure`` [Pa], ``temperature`` [degC]), found by inverting the compensation (both are
monotonic in their raw value), with the resolution of the oversampling (16 bits at x1 up to
20 bits at x16, section 3.3) and 0x80000 for a skipped measurement; forced mode returns to
sleep after one measurement. The chip has no timing of its own here: a measurement is
complete when read.

``Bmp280EmulatorNode`` puts the chip on the shared emulated bus
(``emulation.plug_i2c``) when started; its live parameters are what the chip measures.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus

ID_REGISTER, ID_BMP280, RESET_REGISTER, RESET_VALUE = 0xD0, 0x58, 0xE0, 0xB6
STATUS_REGISTER, CTRL_REGISTER, CONFIG_REGISTER, DATA_FIRST = 0xF3, 0xF4, 0xF5, 0xF7
TRIM_FIRST = 0x88
NOT_MEASURED = 0x80000
#: The data sheet's example trimming (section 3.12): dig_T1..T3, dig_P1..P9.
EXAMPLE_T = (27504, 26435, -1000)
EXAMPLE_P = (36477, -10685, 3024, 2855, 140, -7, 15500, -14600, 6000)
#: osrs code (ctrl_meas bits) -> bits of resolution; 0: skipped.
RESOLUTION_BITS = {0: 0, 1: 16, 2: 17, 3: 18, 4: 19, 5: 20, 6: 20, 7: 20}


def _fine(raw_t: int, t: tuple[int, int, int]) -> int:
    a = (((raw_t >> 3) - (t[0] << 1)) * t[1]) >> 11
    b = (((((raw_t >> 4) - t[0]) * ((raw_t >> 4) - t[0])) >> 12) * t[2]) >> 14
    return a + b


def _pascal_q8(raw_p: int, fine: int, p: tuple[int, ...]) -> int:
    v1 = fine - 128000
    v2 = v1 * v1 * p[5] + ((v1 * p[4]) << 17) + (p[3] << 35)
    v1 = ((v1 * v1 * p[2]) >> 8) + ((v1 * p[1]) << 12)
    v1 = (((1 << 47) + v1) * p[0]) >> 33
    if v1 == 0:
        return 0
    n = (((1048576 - raw_p) << 31) - v2) * 3125
    q = abs(n) // abs(v1)
    q = q if (n < 0) == (v1 < 0) else -q
    return ((q + ((p[8] * (q >> 13) * (q >> 13)) >> 25) + ((p[7] * q) >> 19)) >> 8) + (p[6] << 4)


def _invert(value: float, forward: Any, increasing: bool) -> int:
    """Return the 20-bit raw value whose compensation is nearest ``value`` (bisection)."""
    lo, hi = 0, (1 << 20) - 1
    while lo < hi:
        mid = (lo + hi) // 2
        below = forward(mid) < value
        if below == increasing:
            lo = mid + 1
        else:
            hi = mid
    return lo


class Bmp280Chip:
    """The chip's registers, measuring ``pressure`` [Pa] and ``temperature`` [degC]."""

    def __init__(self, pressure: float = 101325.0, temperature: float = 25.0,
                 trim_t: tuple[int, int, int] = EXAMPLE_T,
                 trim_p: tuple[int, ...] = EXAMPLE_P) -> None:
        self.pressure = pressure
        self.temperature = temperature
        self.trim_t, self.trim_p = trim_t, trim_p
        self.chip_id = ID_BMP280
        self.resets = 0
        self.measurements = 0
        self._reset_registers()

    def _reset_registers(self) -> None:
        self.ctrl_meas = 0
        self.config = 0
        self._raw = (NOT_MEASURED, NOT_MEASURED)

    def _trim_bytes(self) -> bytes:
        words = [(self.trim_t[0], False), (self.trim_t[1], True), (self.trim_t[2], True),
                 (self.trim_p[0], False), *((w, True) for w in self.trim_p[1:])]
        return b''.join(w.to_bytes(2, 'little', signed=s) for w, s in words)

    def _measure(self) -> None:
        """Raw values of the true pressure and temperature at the set oversampling."""
        bits_t = RESOLUTION_BITS[self.ctrl_meas >> 5]
        bits_p = RESOLUTION_BITS[(self.ctrl_meas >> 2) & 0x7]
        if not bits_t:   # no temperature: no t_fine, the pressure is not computed either
            self._raw = (NOT_MEASURED, NOT_MEASURED)
            return
        raw_t = _invert(self.temperature * 100.0,
                        lambda r: (_fine(r, self.trim_t) * 5 + 128) >> 8, True)
        raw_t &= ~((1 << (20 - bits_t)) - 1)
        fine = _fine(raw_t, self.trim_t)
        raw_p = NOT_MEASURED
        if bits_p:
            # pressure falls as the raw value rises (p = 1048576 - adc_P in the formula)
            raw_p = _invert(self.pressure * 256.0,
                            lambda r: _pascal_q8(r, fine, self.trim_p), False)
            raw_p &= ~((1 << (20 - bits_p)) - 1)
        self._raw = (raw_p, raw_t)
        self.measurements += 1

    def _registers(self) -> dict[int, int]:
        regs = {TRIM_FIRST + i: b for i, b in enumerate(self._trim_bytes())}
        raw_p, raw_t = self._raw
        regs.update({ID_REGISTER: self.chip_id, RESET_REGISTER: 0x00, STATUS_REGISTER: 0x00,
                     CTRL_REGISTER: self.ctrl_meas, CONFIG_REGISTER: self.config,
                     DATA_FIRST: raw_p >> 12, DATA_FIRST + 1: (raw_p >> 4) & 0xFF,
                     DATA_FIRST + 2: (raw_p & 0xF) << 4, DATA_FIRST + 3: raw_t >> 12,
                     DATA_FIRST + 4: (raw_t >> 4) & 0xFF, DATA_FIRST + 5: (raw_t & 0xF) << 4})
        return regs

    def read(self, register: int, length: int) -> bytes:
        """Answer a burst read from ``register``, the address auto-incremented."""
        if register == DATA_FIRST and self.ctrl_meas & 0x3 != 0:
            self._measure()
            if self.ctrl_meas & 0x3 in (0b01, 0b10):      # forced: one measurement, sleep
                self.ctrl_meas &= ~0x3
        regs = self._registers()
        return bytes(regs.get(register + i, 0x00) for i in range(length))

    def write(self, register: int, data: bytes) -> None:
        """Take a write of one byte to ``register``.

        Register-data pairs on the real bus; the data sheet's auto-increment is for reads
        only, so one byte here.
        """
        if not data:
            return
        value = data[0]
        if register == RESET_REGISTER and value == RESET_VALUE:
            self._reset_registers()
            self.resets += 1
        elif register == CTRL_REGISTER:
            self.ctrl_meas = value
        elif register == CONFIG_REGISTER:
            self.config = value & 0xFD     # bit 1 is reserved


SPECS = [
    ParamSpec('name', 'default', "Name of the emulated bus (the driver's bus: 'emulated' for "
              "'default', else 'emulated:NAME')", read_only=True),
    ParamSpec('address', 0x77, 'I2C address of the emulated chip', '', 3, 0x77,
              read_only=True),
    ParamSpec('pressure', 101325.0, 'Air pressure the chip measures', 'Pa', 30000.0,
              110000.0),
    ParamSpec('temperature', 25.0, 'Air temperature the chip measures', 'degC', -40.0, 85.0),
]


@dataclass(frozen=True)
class EmulatorSettings:
    """Settings of ``Bmp280EmulatorNode`` (``SPECS``)."""

    name: str
    address: int
    pressure: float      # [Pa]
    temperature: float   # [degC]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> EmulatorSettings:
        """Build from the parameters."""
        return cls(name=v['name'], address=v['address'], pressure=float(v['pressure']),
                   temperature=float(v['temperature']))


class Bmp280EmulatorNode(EnbarrNode):
    """An emulated BMP280 for profiles without hardware; see the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'bmp280_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: EmulatorSettings
        self.chip = Bmp280Chip()
        self.bind_settings(SPECS, EmulatorSettings.from_params, self._apply)
        self.bus: FakeI2cBus | None = None

    def _apply(self, settings: EmulatorSettings) -> None:
        self.settings = settings
        self.chip.pressure, self.chip.temperature = settings.pressure, settings.temperature

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
