"""What the emulated I2C IMU chips share: a register file that samples the simulator's truth.

``ChipEmulator``: a register file behind ``FakeI2cBus`` that makes a new sample every 1/ODR
seconds (monotonic clock) of the configured output data rate from the latest truth
(``sim/imu``: orientation, angular velocity, specific force in ``imu_link``) with seeded white
noise and a constant bias, so data-ready bits behave like the chip's. ``EmulatorNode``: the
chips of one board on the shared emulated bus, fed by ``sim/imu``.

An emulator is written from the chip's data sheet, not from its driver: it imports neither
the driver nor the driver's protocol module, and keeps its own register table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import struct
import threading
import time
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu

from enbarr_core.framework.checks import floats
from enbarr_core.framework.kinematics import quat_to_rotmat
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.imu.common import check_address, G
from enbarr_plugins.transport.i2c import FakeI2cBus


def encode(values: Sequence[float], lsb: float, *, big_endian: bool, bits: int = 16) -> bytes:
    """Return ``values / lsb`` as saturated two's-complement words (left-justified if < 16).

    Plain ``struct`` on three numbers: cheaper than numpy at this size.
    """
    top = 1 << (bits - 1)
    shift = 16 - bits
    words = [max(-top, min(top - 1, round(float(v) / lsb))) << shift for v in values]
    return struct.pack('>3h' if big_endian else '<3h', *words)


@dataclass
class Truth:
    """What the emulated chips measure, in ``imu_link`` (FLU)."""

    gyro: np.ndarray   # [rad/s]
    accel: np.ndarray  # specific force [m/s^2]
    mag: np.ndarray    # [T]


def level_truth(magnetic_field: Sequence[float]) -> Truth:
    """At rest and level, heading east (identity orientation in ENU)."""
    return Truth(np.zeros(3), np.array([0.0, 0.0, G]), np.asarray(magnetic_field, float))


class ChipEmulator:
    """Base of one emulated chip: registers, faults, samples at the configured ODR.

    A subclass sets ``WHO_AM_I_REGISTER`` and ``POWER_ON`` (register -> value after power-on;
    every other register reads 0), implements ``odr()`` (0: powered down) and ``sample()``
    (write the output registers, set the data-ready bits), and the chip's ``read``/``write``
    rules. ``lock`` guards the registers (the bridge writes the truth from the executor thread
    while the driver reads on its loop thread).

    Faults: ``set_identity`` (the WHO_AM_I value it answers), ``data_ready_stuck`` (no new
    sample ever: the driver sees stale data), ``corrupt`` (reads return 0xff: SDA stuck high),
    ``truncate`` (a burst comes one byte short).
    NACKs, stalls and unplugging are faults of the bus (``FakeI2cBus.nack/stall/detach``).
    """

    WHO_AM_I_REGISTER: int
    POWER_ON: Mapping[int, int] = {}

    def __init__(self, seed: int) -> None:
        self.lock = threading.Lock()
        self.registers = bytearray(256)
        self.rng = np.random.default_rng(seed)
        self.truth = level_truth([0.0, 1.8e-5, -4.8e-5])
        self.data_ready_stuck = False
        self.corrupt = False
        self.truncate = False
        self.reads = 0
        self.errors = 0  # faulty replies given (corrupt, truncated)
        self.writes = 0
        self.samples = 0
        self._next_ns = 0
        self.power_on()

    def power_on(self) -> None:
        """Reset the registers to their power-on values (a brown-out, a replug, a reset)."""
        self.registers[:] = bytes(256)
        for register, value in self.POWER_ON.items():
            self.registers[register] = value

    def set_identity(self, value: int) -> None:
        """Answer ``value`` to WHO_AM_I (another chip at this address)."""
        self.registers[self.WHO_AM_I_REGISTER] = value

    def odr(self) -> float:
        """Return the configured output data rate [Hz] (0: powered down)."""
        raise NotImplementedError

    def read_registers(self, register: int, length: int) -> bytes:
        """Return ``length`` bytes from ``register`` by the chip's rules (lock held)."""
        raise NotImplementedError

    def write_registers(self, register: int, data: bytes) -> None:
        """Take a write by the chip's rules (lock held)."""
        raise NotImplementedError

    def read(self, register: int, length: int) -> bytes:
        """Answer a read (``RegisterEmulator``): faults first, then due samples, then data."""
        with self.lock:
            self.reads += 1
            if self.corrupt:
                self.errors += 1
                return b'\xff' * length
            self.update()
            data = self.read_registers(register, length)
            if self.truncate and length > 1:
                self.errors += 1
                return data[:-1]
            return data

    def write(self, register: int, data: bytes) -> None:
        """Take a write (``RegisterEmulator``)."""
        with self.lock:
            self.writes += 1
            self.write_registers(register, data)

    def sample(self) -> None:
        """Write one new sample of ``self.truth`` into the output registers (lock held)."""
        raise NotImplementedError

    def set_truth(self, truth: Truth) -> None:
        """Take the latest truth (the next samples measure it)."""
        self.truth = truth

    def update(self) -> None:
        """Make the samples due since the last call (lock held)."""
        rate = self.odr()
        if rate <= 0.0 or self.data_ready_stuck:
            return
        now = time.monotonic_ns()
        if now >= self._next_ns:
            period = int(1e9 / rate)
            self._next_ns += period
            if self._next_ns <= now:  # first sample, or late: no burst of old samples
                self._next_ns = now + period
            self.sample()
            self.samples += 1


SPECS = [
    ParamSpec('name', 'default', "Name of the emulated bus (the driver's bus: "
              "'emulated' for 'default', else 'emulated:NAME')", read_only=True),
    ParamSpec('magnetic_field', [0.0, 1.8e-5, -4.8e-5], 'Earth field in odom (ENU)', 'T',
              -1e-3, 1e-3),
    ParamSpec('seed', 1, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
    ParamSpec('gyro_bias', [0.004, -0.003, 0.002], 'Constant gyro bias (chip axes)', 'rad/s',
              -0.5, 0.5, read_only=True),
    ParamSpec('accel_bias', [0.0, 0.0, 0.0], 'Constant accelerometer bias (chip axes)',
              'm/s^2', -5.0, 5.0, read_only=True),
]


@dataclass(frozen=True)
class EmulatorSettings:
    """Settings of an IMU emulator node (``SPECS`` and its chips' addresses)."""

    name: str
    magnetic_field: tuple[float, ...]  # [T], odom ENU
    seed: int
    gyro_bias: tuple[float, ...]       # [rad/s]
    accel_bias: tuple[float, ...]      # [m/s^2]
    addresses: tuple[int, ...]         # of the board's chips

    @classmethod
    def from_params(cls, v: Mapping[str, Any],
                    address_names: Sequence[str]) -> EmulatorSettings:
        """Build from the parameters; ``ValueError`` names the field."""
        return cls(name=v['name'], magnetic_field=floats('magnetic_field',
                                                         v['magnetic_field'], 3),
                   seed=v['seed'], gyro_bias=floats('gyro_bias', v['gyro_bias'], 3),
                   accel_bias=floats('accel_bias', v['accel_bias'], 3),
                   addresses=tuple(check_address(n, v[n]) for n in address_names))


class EmulatorNode(EnbarrNode):
    """Base of the IMU emulator nodes: chips on the shared emulated bus, ``sim/imu`` bridge.

    The chips are plugged into the bus when the node starts, and unplugged when it is
    destroyed.

    Parameters ``name`` (the bus: ``emulated:NAME`` in the driver), ``magnetic_field`` (Earth
    field in odom, ENU, like ``sim_imu``), ``seed``, the constant biases, and the addresses
    of the board's chips (``address_specs``, in the order of ``EmulatorSettings.addresses``).
    ``/diagnostics`` reports what the chips received (register reads and writes, samples).
    """

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str, address_specs: Sequence[ParamSpec],
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: EmulatorSettings
        names = [spec.name for spec in address_specs]
        self.bind_settings(SPECS + list(address_specs),
                           lambda v: EmulatorSettings.from_params(v, names), self._apply)
        self.bus: FakeI2cBus | None = None   # the shared emulated bus, once started
        self.chips: dict[int, ChipEmulator] = self.make_chips()
        for chip in self.chips.values():
            chip.set_truth(level_truth(self.settings.magnetic_field))
        self.create_topic_subscription(topics.SIM_IMU, self._on_truth)
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Put the chips on the shared emulated bus (a profile check builds, never starts)."""
        if self.bus is None:
            self.bus = emulation.plug_i2c(self.settings.name, self.chips)
        super().start()

    def _apply(self, settings: EmulatorSettings) -> None:
        self.settings = settings
        self._field = np.asarray(settings.magnetic_field, dtype=float)

    def make_chips(self) -> dict[int, ChipEmulator]:
        """Return the chips of the board by address."""
        raise NotImplementedError

    def _on_truth(self, msg: Imu) -> None:
        q = convert.quaternion_to_array(msg.orientation)
        truth = Truth(convert.vector3_to_array(msg.angular_velocity),
                      convert.vector3_to_array(msg.linear_acceleration),
                      quat_to_rotmat(q).T @ self._field)
        for chip in self.chips.values():
            chip.set_truth(truth)

    def _report(self) -> None:
        bus = self.bus
        if bus is None or not self.started:
            return
        values: dict[str, Any] = {'bus': f'emulated:{self.settings.name}'}
        for address, chip in self.chips.items():
            attached = bus.devices.get(address) is chip
            values[f'0x{address:02x}'] = (
                f'{"attached" if attached else "unplugged"}, reads {chip.reads}, writes '
                f'{chip.writes}, samples {chip.samples}, faulty replies {chip.errors}')
        self.publish_diagnostics(0, 'emulating', values)

    def destroy_node(self) -> None:
        """Unplug the chips; withdraw the bus when nothing else sits on it."""
        bus, self.bus = self.bus, None
        if bus is not None:
            emulation.unplug_i2c(self.settings.name, bus, self.chips)
        super().destroy_node()
