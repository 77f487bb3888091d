"""What the I2C IMU drivers (LSM9DS1, FXOS8700 + FXAS21002C) share.

``I2cImuNode``: the ``bus`` parameter (``'1'``, ``'/dev/i2c-1'``, ``'emulated[:NAME]'``), the
chain's source thread, publishing ``imu/mag`` then ``imu/data_raw`` (the contract of
``enbarr_plugins.imu.sim``), and the faults:

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

``ImuChips``: the chips of one board. Opening checks each chip's WHO_AM_I, writes the
configuration and reads it back (a chip that does not hold what was written is refused).

Samples are stamped on the node clock right after the read (``docs/architecture.md``, Time).
Covariances: white noise density x sqrt(bandwidth), the bandwidth taken as ODR/2.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
import time
from typing import Any, TypeVar

import numpy as np
from sensor_msgs.msg import Imu, MagneticField

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import I2cDevice, open_i2c

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


def noise_specs(gyro: float, accel: float, mag: float) -> list[ParamSpec]:
    """Return the noise parameters of the published covariances, with a board's defaults.

    ``gyro`` [dps/sqrt(Hz)] and ``accel`` [g/sqrt(Hz)] are white noise densities, ``mag``
    [T] an RMS per sample.
    """
    return [
        ParamSpec('gyro_noise_density', gyro, 'Gyro white noise density (covariance)',
                  'deg/s/sqrt(Hz)', 0.0, 10.0),
        ParamSpec('accel_noise_density', accel, 'Accelerometer white noise density '
                  '(covariance)', 'g/sqrt(Hz)', 0.0, 0.1),
        ParamSpec('mag_noise', mag, 'Magnetometer noise, RMS per sample (covariance)', 'T',
                  0.0, 1e-4),
    ]


@dataclass(frozen=True)
class I2cImuSettings:
    """The settings every I2C IMU driver has (``BUS_SPECS``, ``noise_specs``).

    A board's settings add theirs.
    """

    bus: str
    rate: float                 # poll (chain) rate [Hz]
    i2c_timeout: float          # [s]
    data_timeout: float         # [s]
    gyro_noise_density: float   # [dps/sqrt(Hz)]
    accel_noise_density: float  # [g/sqrt(Hz)]
    mag_noise: float            # [T]

    def noise(self, gyro_odr: float, accel_odr: float) -> Noise:
        """Return the noise per sample at these output data rates [Hz].

        sigma = density * sqrt(bandwidth), the bandwidth taken as ODR / 2.
        """
        return Noise(gyro=self.gyro_noise_density * DEG * math.sqrt(gyro_odr / 2.0),
                     accel=self.accel_noise_density * G * math.sqrt(accel_odr / 2.0),
                     mag=self.mag_noise)


def common_settings(v: Mapping[str, Any], fastest: float, rates: str) -> dict[str, Any]:
    """Return the ``I2cImuSettings`` fields of ``v``; ``ValueError`` naming the parameter.

    ``fastest`` [Hz] is the chips' sample rate that the poll ``rate`` may not exceed;
    ``rates`` says which parameters set it, for the message.
    """
    parse_bus(v['bus'])
    if v['rate'] > fastest:
        raise ValueError(f'rate: {v["rate"]:g} Hz polls faster than the chips make samples '
                         f'({rates}); choose rate <= {fastest:g} Hz')
    return {name: v[name] for name in ('bus', 'rate', 'i2c_timeout', 'data_timeout',
                                       'gyro_noise_density', 'accel_noise_density',
                                       'mag_noise')}


S = TypeVar('S', bound=I2cImuSettings)


def parameter_defaults(specs: Sequence[ParamSpec], build: Callable[[dict[str, Any]], S],
                       **changes: Any) -> S:
    """Build a board's settings from the parameter defaults and ``changes`` (check-device)."""
    values = {spec.name: spec.default for spec in [*BUS_SPECS, *specs]}
    values.update(changes)
    return build(values)


class ImuChips:
    """The chips of one IMU board behind a driver: what ``I2cImuNode`` calls.

    A board names its chips' identities (``identities``), its configuration (``config``: the
    register writes in order) and what it found (``describe``); ``open`` checks, writes and
    reads back. ``read`` returns the new sample, None when the data-ready bits say there is
    none (``status`` keeps the byte read), and raises ``DeviceError`` on a failed transfer;
    ``corrupt`` is set when the read was implausible (status 0xff).
    """

    def __init__(self, bus: Bus, settings: Any) -> None:
        self.s = settings
        self.status = 0
        self.corrupt = False

    @staticmethod
    def addresses(settings: Any) -> tuple[int, ...]:
        """Return the addresses of the board's chips in ``settings`` (for messages)."""
        raise NotImplementedError

    def identities(self) -> list[tuple[I2cDevice, int, int, str]]:
        """Return (device, WHO_AM_I register, expected value, chip name) of every chip."""
        raise NotImplementedError

    def config(self) -> list[tuple[I2cDevice, int, int]]:
        """Return the (device, register, value) writes of the configuration, in order."""
        raise NotImplementedError

    def describe(self) -> list[str]:
        """Return what was found and configured (for logs and check-device)."""
        raise NotImplementedError

    def open(self) -> list[str]:
        """Check identities, configure and read the configuration back; ``describe()``.

        A register written twice (a standby write before an active one) is checked for the
        last value written.
        """
        for dev, register, expected, chip in self.identities():
            check_identity(dev, register, expected, chip)
        writes = self.config()
        for dev, register, value in writes:
            dev.write_u8(register, value)
        final = {(dev.address, register): (dev, value) for dev, register, value in writes}
        for (_, register), (dev, value) in final.items():
            read = dev.read_u8(register)
            if read != value:
                raise DeviceError(f'{dev.name}: register 0x{register:02x} reads 0x{read:02x} '
                                  f'after writing 0x{value:02x}')
        return self.describe()

    def read(self) -> ImuSample | None:
        """Return the new sample, or None (see the class doc)."""
        raise NotImplementedError

    def noise(self) -> Noise:
        """Return the noise of the configured ranges and rates."""
        raise NotImplementedError


class I2cImuNode(SensorDriver):
    """The driver node of an I2C IMU board: the chain's source; see the module docstring.

    A board's node gives its parameter specs (beyond ``BUS_SPECS``), its settings builder
    and its ``ImuChips`` class (built as ``chips(bus, settings)``).
    """

    def __init__(self, node_name: str, specs: Sequence[ParamSpec],
                 build: Callable[[dict[str, Any]], I2cImuSettings], chips: type[ImuChips],
                 **kwargs: Any) -> None:
        super().__init__(node_name, device='i2c', **kwargs)
        self.settings: Any
        self._chips_class = chips
        self.bind_settings(list(BUS_SPECS) + list(specs), build, self._apply)
        s = self.settings
        self.device = f'{s.bus} ' + '+'.join(f'0x{a:02x}' for a in chips.addresses(s))
        self._raw_pub = self.create_topic_publisher(topics.IMU_RAW)
        self._mag_pub = self.create_topic_publisher(topics.IMU_MAG)
        self._bus: Bus | None = None
        self._chips: ImuChips | None = None
        self._last_new_ns = 0
        self._corrupt_run = 0
        self.no_data = 0     # polls with no new sample
        self.corrupted = 0   # reads dropped as corrupted
        self.identity = ''
        self._loop = self.create_rate_loop(s.rate, self._tick)
        self.open_on(self._loop)  # see the module docstring

    def _apply(self, settings: Any) -> None:
        self.settings = settings
        self._data_timeout_ns = int(settings.data_timeout * 1e9)

    # -- device lifecycle ---------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the bus, check the identities and configure the chips."""
        s = self.settings
        bus = Bus(s.bus, s.i2c_timeout)
        chips = self._chips_class(bus, s)
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
            self.open_if_requested()
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
