"""An emulated MS5837-30BA on the emulated I2C bus, byte by byte.

Written from the MS5837-30BA data sheet (REV C2 12/2019) with its own command table and its
own copy of the compensation: it imports neither the driver nor its protocol module, so a
wrong number on one side shows as a failed test instead of agreeing with itself.

What it does as the chip does: reset (0x1E) reloads the PROM and drops a pending
conversion; PROM read 0xA0 + 2 * i answers word i MSB first, word 0 carrying the CRC-4
computed from C1..C6 (the data sheet's algorithm) and the 30BA's product type; convert D1
(0x40 + offset) / D2 (0x50 + offset) starts a conversion that lasts the OSR's conversion
time; ADC read (0x00) answers the 24-bit result MSB first once, 0 when read again or before
the conversion finished, and an early read spoils that conversion (the data sheet: "the
conversion will not stop and the final result will be wrong"; here it reads 0). A conversion
command during a conversion is counted as a protocol error.

The raw values measure ``pressure`` [Pa] and ``temperature`` [degC]: D2 and D1 are found by
bisection on the compensation (both are monotonic in their raw value), so the driver's
result equals the truth within the chip's 0.1 mbar / 0.01 degC steps. ``noise`` [Pa] adds
seeded white noise to the pressure measured.

``Ms5837EmulatorNode`` puts the chip on the shared emulated bus
(``emulation.get_or_create('i2c', name, FakeI2cBus)``, where the PCA9685 and IMU emulators
also sit) when started and feeds it the simulator's depth (``sim/odometry``: depth = -z of
base_link in odom ENU) as the pressure of its simulated water.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import threading
import time
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus

# The data sheet's commands and numbers, typed again for the emulator.
ADDRESS = 0x76
RESET, ADC_READ, PROM_READ = 0x1E, 0x00, 0xA0
D1_BASE, D2_BASE = 0x40, 0x50
#: Command offset -> when the emulated chip's conversion is done [ns] (OSR 256 .. 4096); a read
#: before then returns 0. The chip is taken to need all the time its manufacturer's driver gives
#: it (TE Connectivity, MS5837_Arduino_Library, ms5837.h: 1, 2, 3, 5, 9 ms), the longest it can
#: take by that source, so that a driver waiting any less is caught.
CONVERSION_NS = {0x0: 1_000_000, 0x2: 2_000_000, 0x4: 3_000_000, 0x6: 5_000_000,
                 0x8: 9_000_000}
PRODUCT_30BA = 0x1A
#: The data sheet's example calibration (C1..C6).
EXAMPLE_C = (34982, 36352, 20328, 22354, 26646, 26146)
FULL_SCALE = (1 << 24) - 1
G = 9.80665  # [m/s^2]


def prom_crc4(words: Sequence[int]) -> int:
    """Return the data sheet's CRC-4 of the 7 PROM words (CRC nibble of word 0 taken as 0)."""
    n = [words[0] & 0x0FFF, *words[1:7], 0]
    rem = 0
    for cnt in range(16):
        rem ^= (n[cnt >> 1] & 0xFF) if cnt & 1 else (n[cnt >> 1] >> 8)
        for _ in range(8):
            rem = (((rem << 1) ^ 0x3000) if rem & 0x8000 else rem << 1) & 0xFFFF
    return (rem >> 12) & 0xF


def temp_and_p(c: Sequence[int], d1: int, d2: int) -> tuple[int, int]:
    """TEMP [0.01 degC] and P [0.1 mbar] of the 30BA, second order included."""
    c1, c2, c3, c4, c5, c6 = c
    dt = d2 - c5 * 256
    temp = 2000 + (dt * c6) // 2**23
    off = c2 * 2**16 + (c4 * dt) // 2**7
    sens = c1 * 2**15 + (c3 * dt) // 2**8
    if temp < 2000:
        ti, offi, sensi = (3 * dt * dt) // 2**33, (3 * (temp - 2000) ** 2) // 2, \
            (5 * (temp - 2000) ** 2) // 8
        if temp < -1500:
            offi += 7 * (temp + 1500) ** 2
            sensi += 4 * (temp + 1500) ** 2
    else:
        ti, offi, sensi = (2 * dt * dt) // 2**37, ((temp - 2000) ** 2) // 16, 0
    p = ((d1 * (sens - sensi)) // 2**21 - (off - offi)) // 2**13
    return temp - ti, p


def _smallest(at_least: Callable[[int], bool]) -> int:
    """Return the smallest 24-bit value where ``at_least`` (monotonic) holds, else full scale."""
    lo, hi = 0, FULL_SCALE
    while lo < hi:
        mid = (lo + hi) // 2
        if at_least(mid):
            hi = mid
        else:
            lo = mid + 1
    return lo


class Ms5837Chip:
    """One emulated MS5837-30BA: a ``RegisterEmulator`` for ``FakeI2cBus``.

    ``clock`` returns monotonic nanoseconds (tests may pass their own). Fault:
    ``lose_conversions`` (every conversion is lost, as after a brown-out reset: ADC reads 0).
    Counters:
    ``early_reads`` (ADC reads before the conversion finished), ``protocol_errors``
    (unknown commands, a conversion started during another), ``conversions``.
    """

    def __init__(self, coefficients: Sequence[int] = EXAMPLE_C, *, pressure: float = 101325.0,
                 temperature: float = 20.0, noise: float = 0.0, seed: int = 1,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.c = tuple(int(x) for x in coefficients)
        word0 = PRODUCT_30BA << 5
        words = [word0, *self.c]
        self.prom = [word0 | prom_crc4(words) << 12, *self.c]
        self.pressure = pressure          # [Pa]
        self.temperature = temperature    # [degC]
        self.noise = noise                # [Pa] RMS
        self.rng = np.random.default_rng(seed)
        self.clock = clock
        self.lock = threading.Lock()
        self.early_reads = 0
        self.protocol_errors = 0
        self.conversions = 0
        self.resets = 0
        self.lose_conversions = False
        self._result: int | None = None   # the finished (or running) conversion's value
        self._done_ns = 0

    def raw(self, pressure: float, temperature: float) -> tuple[int, int]:
        """Return (D1, D2) whose compensation gives ``pressure`` [Pa], ``temperature`` [degC]."""
        temp_target = round(temperature * 100.0)
        d2 = _smallest(lambda d: temp_and_p(self.c, 0, d)[0] >= temp_target)
        p_target = round(pressure / 10.0)
        d1 = _smallest(lambda d: temp_and_p(self.c, d, d2)[1] >= p_target)
        return d1, d2

    def _start(self, command: int) -> None:
        base, offset = command & 0xF0, command & 0x0F
        now = self.clock()
        if self._result is not None and now < self._done_ns:
            self.protocol_errors += 1  # the data sheet: the result will be wrong
        pressure = self.pressure + (self.rng.normal(0.0, self.noise) if self.noise else 0.0)
        d1, d2 = self.raw(pressure, self.temperature)
        self._result = None if self.lose_conversions else (d1 if base == D1_BASE else d2)
        self._done_ns = now + CONVERSION_NS[offset]
        self.conversions += 1

    def write(self, register: int, data: bytes) -> None:
        """Take a command (a send byte arrives as ``register`` with no data)."""
        with self.lock:
            if register == RESET:
                self.resets += 1
                self._result = None
            elif register & 0xF0 in (D1_BASE, D2_BASE) and register & 0x0F in CONVERSION_NS:
                self._start(register)
            else:
                self.protocol_errors += 1

    def read(self, register: int, length: int) -> bytes:
        """Answer ADC read (24 bits, once) and PROM reads (16 bits); else 0s."""
        with self.lock:
            if register == ADC_READ:
                value = 0
                if self._result is not None:
                    if self.clock() < self._done_ns:
                        self.early_reads += 1
                    else:
                        value = self._result
                    self._result = None  # read once; an early read spoils the conversion
                return value.to_bytes(3, 'big')[:length].ljust(length, b'\0')
            if PROM_READ <= register <= PROM_READ + 12 and register % 2 == 0:
                word = self.prom[(register - PROM_READ) // 2]
                return word.to_bytes(2, 'big')[:length].ljust(length, b'\0')
            self.protocol_errors += 1
            return bytes(length)


def attach_ms5837(bus: FakeI2cBus, address: int = ADDRESS, **kwargs: object) -> Ms5837Chip:
    """Put an emulated MS5837-30BA on ``bus``; return it (kwargs: ``Ms5837Chip``'s)."""
    chip = Ms5837Chip(**kwargs)  # type: ignore[arg-type]
    bus.attach(address, chip)
    return chip


SPECS = [
    ParamSpec('name', 'default', "Name of the emulated bus (the driver's bus: 'emulated' for "
              "'default', else 'emulated:NAME')", read_only=True),
    ParamSpec('address', ADDRESS, 'I2C address of the emulated chip', '', 3, 0x77,
              read_only=True),
    ParamSpec('water_density', 997.0, 'Density of the simulated water', 'kg/m^3', 900.0,
              1100.0),
    ParamSpec('water_surface_pressure', 101325.0, 'Air pressure on the simulated water', 'Pa',
              50000.0, 150000.0),
    ParamSpec('water_temperature', 15.0, 'Temperature of the simulated water', 'degC', -5.0,
              40.0),
    ParamSpec('pressure_noise', 20.0, 'White noise on the measured pressure, std', 'Pa', 0.0,
              10000.0),
    ParamSpec('seed', 4, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
]


@dataclass(frozen=True)
class EmulatorSettings:
    """Settings of ``Ms5837EmulatorNode`` (``SPECS``)."""

    name: str
    address: int
    water_density: float           # [kg/m^3]
    water_surface_pressure: float  # [Pa]
    water_temperature: float       # [degC]
    pressure_noise: float          # [Pa]
    seed: int

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> EmulatorSettings:
        """Build from the declared parameters' values."""
        return cls(**{name: v[name] for name in cls.__dataclass_fields__})


class Ms5837EmulatorNode(EnbarrNode):
    """An emulated MS5837-30BA for profiles without hardware; see the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'ms5837_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: EmulatorSettings
        self.bind_settings(SPECS, EmulatorSettings.from_params, self._apply)
        s = self.settings
        self.chip = Ms5837Chip(pressure=s.water_surface_pressure,
                               temperature=s.water_temperature, noise=s.pressure_noise,
                               seed=s.seed)
        self.bus: FakeI2cBus | None = None
        self._depth = 0.0
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def _apply(self, settings: EmulatorSettings) -> None:
        self.settings = settings
        chip = getattr(self, 'chip', None)
        if chip is not None:
            with chip.lock:
                chip.noise = settings.pressure_noise
                chip.temperature = settings.water_temperature
            self._set_depth(self._depth)

    def start(self) -> None:
        """Put the chip on the shared emulated bus (a profile check builds, never starts)."""
        if self.bus is None:
            self.bus = emulation.plug_i2c(self.settings.name, {self.settings.address: self.chip})
        super().start()

    def _set_depth(self, depth: float) -> None:
        s = self.settings
        self._depth = depth
        with self.chip.lock:
            self.chip.pressure = s.water_surface_pressure + s.water_density * G * max(depth, 0.0)

    def _on_truth(self, msg: Odometry) -> None:
        self._set_depth(-msg.pose.pose.position.z)

    def destroy_node(self) -> None:
        """Unplug the chip; withdraw the bus when nothing else sits on it."""
        bus, self.bus = self.bus, None
        if bus is not None:
            emulation.unplug_i2c(self.settings.name, bus, {self.settings.address: self.chip})
        super().destroy_node()
