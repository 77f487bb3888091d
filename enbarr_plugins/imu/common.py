"""What the I2C IMU drivers (LSM9DS1, FXOS8700 + FXAS21002C) and their emulators share.

Driver side (``I2cImuNode``): the ``bus`` parameter (``'1'``, ``'/dev/i2c-1'``,
``'emulated[:NAME]'``), the chain's source thread, publishing ``imu/mag`` then
``imu/data_raw`` (the contract of ``enbarr_plugins.imu.sim``), and the faults:

- nothing is opened before ``start()``. There the first attempt runs in place, before the
  loop starts, so an absent device is reported at once; every later attempt (a reconnect)
  runs on the node's own loop thread, never on the executor: a stalled bus costs the adapter
  timeout (``i2c_timeout``) on that thread only;
- a failed transfer (NACK, stall = ``ETIMEDOUT``, short read) is a ``DeviceError`` naming bus,
  address and register: ``device_fault`` -> ``/diagnostics`` ERROR, log, retry with backoff;
- no new sample (data-ready bits clear) for ``data_timeout``: a fault naming the status
  byte read (a chip that lost its configuration in a brown-out reads as powered down), so the
  reconnect writes the configuration again;
- a status byte of 0xff (SDA held high: a bus that reads all ones) is a corrupted read: the
  sample is dropped and counted, and ``MAX_CORRUPT`` in a row are a fault. I2C register reads
  carry no sequence numbers, so out-of-order frames do not exist on this transport.

Samples are stamped on the node clock right after the read (``docs/architecture.md``, Time).
Covariances: white noise density x sqrt(bandwidth), the bandwidth taken as ODR/2.

Emulator side (``ChipEmulator``): a register file behind ``FakeI2cBus`` that makes a new
sample every 1/ODR seconds (monotonic clock) of the configured output data rate from the
latest truth (``sim/imu``: orientation, angular velocity, specific force in ``imu_link``)
with seeded white noise and a constant bias, so data-ready bits behave like the chip's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math
import struct
import threading
import time
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu, MagneticField

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.kinematics import quat_to_rotmat
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus, I2cDevice, open_i2c

#: Standard gravity [m/s^2] (the chips' "g").
G = 9.80665
#: Degrees to radians.
DEG = math.pi / 180.0
#: Consecutive corrupted reads that make a device fault.
MAX_CORRUPT = 5


def choice(name: str, value: float, allowed: Sequence[float]) -> float:
    """Return ``value`` when it is one of ``allowed`` (within 1e-6), else ``ValueError``."""
    for a in allowed:
        if abs(float(value) - a) < 1e-6:
            return a
    raise ValueError(f'{name}: {value:g} is not one of the values of the chip '
                     f'({", ".join(f"{a:g}" for a in allowed)})')


def parse_bus(value: str) -> int | None:
    """Return the bus number of ``'1'`` or ``'/dev/i2c-1'``; None for ``emulated[:NAME]``.

    ``ValueError`` naming ``bus`` for anything else.
    """
    if emulation.is_emulated(value):
        return None
    text = value.strip()
    if text.startswith('/dev/i2c-'):
        text = text[len('/dev/i2c-'):]
    if text.isdigit():
        return int(text)
    raise ValueError(f"bus: expected a bus number ('1'), a device ('/dev/i2c-1') or "
                     f"'emulated[:NAME]', got {value!r}")


def check_address(name: str, address: int) -> int:
    """Return a 7-bit I2C address or raise ``ValueError`` naming the parameter."""
    if not 0x03 <= address <= 0x77:
        raise ValueError(f'{name}: 0x{address:x} is not a 7-bit I2C address (0x03..0x77)')
    return address


class Bus:
    """An open bus: the smbus2 object (or the emulator's), its name, whether we close it."""

    def __init__(self, value: str, timeout: float) -> None:
        number = parse_bus(value)
        if number is None:
            self.smbus = emulation.lookup('i2c', value)
            self.name = value
            self.owned = False  # an emulated bus is shared with the other chips on it
        else:
            self.smbus = open_i2c(number, timeout=timeout)
            self.name = f'i2c-{number}'
            self.owned = True

    def device(self, address: int) -> I2cDevice:
        """Return the registers of the chip at ``address`` (one retry per transfer)."""
        return I2cDevice(self.smbus, address, bus_name=self.name, retries=1, retry_delay=0.0)

    def close(self) -> None:
        """Close the bus if this driver opened it; never raises."""
        if self.owned:
            try:
                self.smbus.close()
            except OSError:
                pass


def check_identity(dev: I2cDevice, register: int, expected: int, chip: str) -> int:
    """Read WHO_AM_I; ``DeviceError`` naming bus, address and the value read when wrong."""
    value = dev.read_u8(register)
    if value != expected:
        raise DeviceError(f'{dev.name}: WHO_AM_I (0x{register:02x}) reads 0x{value:02x}, '
                          f'expected 0x{expected:02x} ({chip}); another chip at this address?')
    return value


@dataclass(frozen=True)
class ImuSample:
    """One sample in ``imu_link`` (FLU), SI units; ``mag`` None when the magnetometer had none."""

    gyro: np.ndarray        # [rad/s]
    accel: np.ndarray       # specific force [m/s^2]
    mag: np.ndarray | None  # [T]


@dataclass(frozen=True)
class Noise:
    """Standard deviations per sample of the published covariances."""

    gyro: float   # [rad/s]
    accel: float  # [m/s^2]
    mag: float    # [T]


class ImuChips:
    """The chips of one IMU board behind a driver: what ``I2cImuNode`` calls.

    ``open`` checks identities and writes the configuration; ``read`` returns the new sample,
    None when the data-ready bits say there is none (``status`` keeps the byte read), and
    raises ``DeviceError`` on a failed transfer; ``corrupt`` is set when the read was
    implausible (status 0xff).
    """

    status = 0
    corrupt = False

    def open(self) -> list[str]:
        """Check identities, configure; return what was found (for logs and check-device)."""
        raise NotImplementedError

    def read(self) -> ImuSample | None:
        """Return the new sample, or None (see the class doc)."""
        raise NotImplementedError

    def noise(self) -> Noise:
        """Return the noise of the configured ranges and rates."""
        raise NotImplementedError


BUS_SPECS = [
    ParamSpec('bus', '1', "I2C bus: a number ('1'), a device ('/dev/i2c-1') or "
              "'emulated[:NAME]' (this package's emulator in the same process)",
              read_only=True),
    ParamSpec('rate', 200.0, 'Rate at which the chips are polled; the chain runs at this rate '
              '(at most the chip output data rate)', 'Hz', 1.0, 1000.0, read_only=True),
    ParamSpec('i2c_timeout', 0.05, 'I2C adapter timeout: longest one transfer may block',
              's', 0.01, 1.0, read_only=True),
    ParamSpec('data_timeout', 0.5, 'No new sample (data-ready clear) for this long is a '
              'device fault (reconfigure)', 's', 0.01, 60.0),
]


class I2cImuNode(SensorDriver):
    """The driver node of an I2C IMU board: the chain's source; see the module docstring.

    Subclasses give their parameter specs and settings builder and ``make_chips(bus)``.
    """

    def __init__(self, node_name: str, specs: Sequence[ParamSpec],
                 build: Callable[[dict[str, Any]], Any], **kwargs: Any) -> None:
        super().__init__(node_name, device='i2c', **kwargs)
        self.settings: Any
        self.bind_settings(list(BUS_SPECS) + list(specs), build, self._apply)
        s = self.settings
        self.device = f'{s.bus} {self.addresses_text()}'
        self._raw_pub = self.create_topic_publisher(topics.IMU_RAW)
        self._mag_pub = self.create_topic_publisher(topics.IMU_MAG)
        self._bus: Bus | None = None
        self._chips: ImuChips | None = None
        self._open_requested = False
        self._last_new_ns = 0
        self._corrupt_run = 0
        self.no_data = 0     # polls with no new sample
        self.corrupted = 0   # reads dropped as corrupted
        self.identity = ''
        self._loop = self.create_rate_loop(s.rate, self._tick)

    def _apply(self, settings: Any) -> None:
        self.settings = settings
        self._data_timeout_ns = int(settings.data_timeout * 1e9)

    # -- what a board implements --------------------------------------------------------------
    def addresses_text(self) -> str:
        """Return the chip addresses, for messages ('0x6b+0x1e')."""
        raise NotImplementedError

    def make_chips(self, bus: Bus) -> ImuChips:
        """Return the board's chips on ``bus`` (not yet opened)."""
        raise NotImplementedError

    # -- device lifecycle ---------------------------------------------------------------------
    def connect(self) -> bool:
        """Open the device on the loop thread once it runs (see the module docstring)."""
        if self._loop.running and threading.current_thread().name != self._loop.name:
            self._open_requested = True
            return False
        return super().connect()

    def open_device(self) -> None:
        """Open the bus, check the identities and configure the chips."""
        s = self.settings
        bus = Bus(s.bus, s.i2c_timeout)
        chips = self.make_chips(bus)
        try:
            found = chips.open()
        except DeviceError:
            bus.close()
            raise
        self._bus, self._chips = bus, chips
        self.identity = '; '.join(found)
        self._noise = chips.noise()
        self._last_new_ns = time.monotonic_ns()
        self._corrupt_run = 0
        self.get_logger().info(f'{self.device}: {self.identity}')

    def close_device(self) -> None:
        """Drop the chips and close the bus (when this driver opened it)."""
        self._chips = None
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()

    # -- the loop -----------------------------------------------------------------------------
    def _tick(self) -> None:
        chips = self._chips
        if not self.connected or chips is None:
            if self._open_requested:
                self._open_requested = False
                super().connect()
            return
        try:
            sample = chips.read()
        except DeviceError as err:
            self.device_fault(err)
            return
        now = time.monotonic_ns()
        if chips.corrupt:
            self.corrupted += 1
            self._corrupt_run += 1
            if self._corrupt_run >= MAX_CORRUPT:
                self.device_fault(DeviceError(
                    f'{self.device}: {self._corrupt_run} corrupted reads in a row (status '
                    f'0x{chips.status:02x}: SDA stuck high?)'))
            return
        self._corrupt_run = 0
        if sample is None:
            self.no_data += 1
            if now - self._last_new_ns > self._data_timeout_ns:
                self.device_fault(DeviceError(
                    f'{self.device}: no new sample for {(now - self._last_new_ns) * 1e-9:.2f} s '
                    f'(status 0x{chips.status:02x}: data-ready clear; chip reset or stuck?)'))
            return
        self._last_new_ns = now
        self._publish(sample)

    def _publish(self, sample: ImuSample) -> None:
        stamp = self.get_clock().now().to_msg()
        n = self._noise
        if sample.mag is not None:
            mag = new(MagneticField)
            mag.header.stamp = stamp
            mag.header.frame_id = topics.IMU_FRAME
            convert.set_vector3(mag.magnetic_field, sample.mag)
            c = mag.magnetic_field_covariance
            c[0] = c[4] = c[8] = n.mag ** 2
            self._mag_pub.publish(mag)
        raw = new(Imu)
        raw.header.stamp = stamp
        raw.header.frame_id = topics.IMU_FRAME
        raw.orientation_covariance[0] = -1.0  # no orientation estimate (REP-145)
        convert.set_vector3(raw.angular_velocity, sample.gyro)
        convert.set_vector3(raw.linear_acceleration, sample.accel)
        c = raw.angular_velocity_covariance
        c[0] = c[4] = c[8] = n.gyro ** 2
        c = raw.linear_acceleration_covariance
        c[0] = c[4] = c[8] = n.accel ** 2
        self._raw_pub.publish(raw)
        self.sample_received()

    def status_values(self) -> dict[str, Any]:
        """Return the sample, no-data and corrupted-read counters and the identity."""
        values = super().status_values()
        values.update({'identity': self.identity, 'no_new_data': self.no_data,
                       'corrupted': self.corrupted, 'loop_overruns': self._loop.overruns})
        return values

    def destroy_node(self) -> None:
        """Stop the loop, close the device, destroy the node."""
        self.stop()
        self.close_device()
        super().destroy_node()


# -- emulator side ---------------------------------------------------------------------------

def encode(values: Sequence[float], lsb: float, *, big_endian: bool, bits: int = 16) -> bytes:
    """Return ``values / lsb`` as saturated two's-complement words (left-justified if < 16).

    Plain ``struct`` on three numbers: a third of the cost of numpy at this size.
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

    A subclass sets ``registers`` defaults, implements ``odr()`` (0: powered down) and
    ``sample(truth, rng)`` (write the output registers, set the data-ready bits), and the
    chip's ``read``/``write`` rules. ``lock`` guards the registers (the bridge writes the truth
    from the executor thread while the driver reads on its loop thread).

    Faults: ``set_identity`` (the WHO_AM_I value it answers), ``data_ready_stuck`` (no new
    sample ever: the driver sees stale data), ``corrupt`` (reads return 0xff: SDA stuck high),
    ``truncate`` (a burst comes one byte short).
    NACKs, stalls and unplugging are faults of the bus (``FakeI2cBus.nack/stall/detach``).
    """

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


class EmulatorNode(EnbarrNode):
    """Base of the IMU emulator nodes: chips on the shared emulated bus, ``sim/imu`` bridge.

    The chips are plugged into the bus when the node starts, and unplugged when it is
    destroyed.

    Parameters ``name`` (the bus: ``emulated:NAME`` in the driver), ``magnetic_field`` (Earth
    field in odom, ENU, like ``sim_imu``) and ``seed``. ``/diagnostics`` reports what the chips
    received (register reads and writes, samples made).
    """

    device_emulator = True  # bringup builds it before the drivers (orchestrator.build_nodes)

    def __init__(self, node_name: str, specs: Sequence[ParamSpec],
                 build: Callable[[dict[str, Any]], Any], **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: Any
        common = [
            ParamSpec('name', 'default', "Name of the emulated bus (the driver's bus: "
                      "'emulated' for 'default', else 'emulated:NAME')", read_only=True),
            ParamSpec('magnetic_field', [0.0, 1.8e-5, -4.8e-5], 'Earth field in odom (ENU)',
                      'T', -1e-3, 1e-3),
            ParamSpec('seed', 1, 'Seed of the noise generator', '', 0, 2**31 - 1,
                      read_only=True),
        ]
        self.bind_settings(common + list(specs), build, self._apply)
        self.bus: FakeI2cBus | None = None   # the shared emulated bus, once started
        self.chips: dict[int, ChipEmulator] = self.make_chips()
        for chip in self.chips.values():
            chip.set_truth(level_truth(self.settings.magnetic_field))
        self.create_topic_subscription(topics.SIM_IMU, self._on_truth)
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Put the chips on the shared emulated bus (a profile check builds, never starts)."""
        if self.bus is None:
            self.bus = emulation.get_or_create('i2c', self.settings.name, FakeI2cBus)
            for address, chip in self.chips.items():
                self.bus.attach(address, chip)
        super().start()

    def _apply(self, settings: Any) -> None:
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
            for address, chip in self.chips.items():
                if bus.devices.get(address) is chip:
                    bus.detach(address)
            if not bus.devices:
                emulation.unregister('i2c', self.settings.name, bus)
        super().destroy_node()


def wait_sample(chips: ImuChips, timeout: float) -> ImuSample:
    """Poll ``chips`` until a sample with a magnetometer reading comes (check-device)."""
    deadline = time.monotonic() + timeout
    gyro_accel = None
    while time.monotonic() < deadline:
        sample = chips.read()
        if sample is not None:
            if sample.mag is not None:
                return sample
            gyro_accel = sample
        time.sleep(0.005)
    if gyro_accel is not None:
        raise DeviceError(f'no magnetometer sample within {timeout:g} s (accel/gyro work)')
    raise DeviceError(f'no new sample within {timeout:g} s (status 0x{chips.status:02x}: '
                      'data-ready never set)')


def sample_lines(sample: ImuSample) -> list[str]:
    """Return one sample in SI units, for check-device."""
    def fmt(v: np.ndarray, scale: float = 1.0) -> str:
        return ' '.join(f'{x * scale:+.3f}' for x in v)
    lines = [f'gyro [rad/s] (FLU): {fmt(sample.gyro)}',
             f'accel [m/s^2] (FLU): {fmt(sample.accel)}']
    if sample.mag is not None:
        lines.append(f'mag [uT] (FLU): {fmt(sample.mag, 1e6)}')
    return lines


def check_imu(target: Any, default_settings: Callable[..., Any],
              make_chips: Callable[[Bus, Any], ImuChips],
              attach: Callable[[FakeI2cBus, Any], None]) -> list[str]:
    """``enbarr check-device`` of an I2C IMU: identities, configuration, one sample in SI.

    ``default_settings(**changes)`` builds the driver's settings, ``make_chips(bus, s)`` its
    chips, ``attach(fake_bus, s)`` puts the emulated chips on a fake bus (``--bus emulated``:
    a private emulated bus for the check, withdrawn afterwards).
    """
    value = target.bus or '1'
    changes: dict[str, Any] = {'bus': value}
    if target.address is not None:
        changes['address'] = target.address
    try:
        s = default_settings(**changes)
    except ValueError as err:
        raise DeviceError(str(err)) from err
    name = None
    if emulation.is_emulated(value):
        name = f'check-device-{time.monotonic_ns()}'
        fake = FakeI2cBus()
        attach(fake, s)
        emulation.register('i2c', name, fake)
        s = default_settings(**{**changes, 'bus': f'emulated:{name}'})
    try:
        bus = Bus(s.bus, min(target.timeout, 1.0))
        try:
            chips = make_chips(bus, s)
            lines = chips.open()
            sample = wait_sample(chips, target.timeout)
        finally:
            bus.close()
    finally:
        if name is not None:
            emulation.unregister('i2c', name)
    return lines + sample_lines(sample)
