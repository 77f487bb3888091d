"""TE MS5837-30BA (Blue Robotics Bar30) depth sensor over I2C: pressure, temperature, depth.

The chip at 0x76 (fixed) is driven by one-byte commands (``ms5837_protocol.py``, from the
data sheet REV C2): ``start()`` resets it, reads the seven PROM words and refuses a PROM whose
CRC-4 does not check or that is not a 30BA's (a clear error naming bus, address and the words
read). Every sample then converts D2 (temperature) and D1 (pressure) at the ``osr``
parameter, each time waiting the data sheet's longest conversion time on a monotonic clock
before the ADC read (an early read returns 0 and spoils the conversion), and applies the
first- and second-order compensation of the 30BA.

Published: ``pressure`` (``sensor_msgs/FluidPressure``, Pa), ``pressure/temperature``
(``sensor_msgs/Temperature``, degC) and ``depth``. The depth is a
``geometry_msgs/PoseWithCovarianceStamped`` with position.z = -depth in odom (ENU, z up) and
its variance in covariance[14], the other axes unobserved: a stamp and a variance, which a
``std_msgs/Float64`` has neither of, and the message a pose-fusing filter (robot_localization's
``pose0``) takes a depth sensor in. depth = (p - surface_pressure) / (fluid_density * g).

Re-zeroing: ``surface_pressure`` [Pa] is a live parameter; setting it to 0 takes the next
pressure read as the surface (the operator holds the ROV at the surface and sets 0). The
surface pressure in use is on ``/diagnostics``.

Faults: a failed transfer at run time (NACK, stall) is a ``DeviceError`` naming bus and
address: counted, ERROR on ``/diagnostics``, the device reopened (reset + PROM) with backoff,
never a traceback. An ADC read of 0 (a conversion lost: reset by a brown-out) drops the sample
and counts it; ``MAX_ZERO_READS`` in a row are a fault.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import time
from typing import Any

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.imu.common import Bus, check_address, parse_bus
from enbarr_plugins.pressure.common import DEPTH_SPECS, DepthTopics
from enbarr_plugins.pressure.ms5837_protocol import (
    ADC_READ, ADDRESS, Calibration, compensate, convert_command, OSR, parse_prom, PROM_READ,
    PROM_WORDS, PromError, Reading, RESET, RESET_TIME)
from enbarr_plugins.transport.i2c import I2cDevice

#: Consecutive ADC reads of 0 that make a device fault.
MAX_ZERO_READS = 5

SPECS = [
    ParamSpec('bus', '1', "I2C bus: a number ('1'), a device ('/dev/i2c-1') or "
              "'emulated[:NAME]' (this package's emulator in the same process)",
              read_only=True),
    ParamSpec('address', ADDRESS, 'I2C address (the MS5837 has only 0x76)', '', 3, 0x77,
              read_only=True),
    ParamSpec('osr', 4096, 'Oversampling: 256, 512, 1024, 2048 or 4096 (longer conversion, '
              'less noise)', '', 256, 4096, read_only=True),
    ParamSpec('rate', 10.0, 'Samples per second (each one converts D2 and D1)', 'Hz', 0.1,
              400.0, read_only=True),
    ParamSpec('i2c_timeout', 0.05, 'I2C adapter timeout: longest one transfer may block',
              's', 0.01, 1.0, read_only=True),
    *DEPTH_SPECS,
]


@dataclass(frozen=True)
class Ms5837Settings:
    """Settings of ``Ms5837Node`` (``SPECS``)."""

    bus: str
    address: int
    osr: int
    rate: float             # [Hz]
    i2c_timeout: float      # [s]
    fluid_density: float    # [kg/m^3]
    surface_pressure: float  # [Pa], 0: re-zero on the next reading
    depth_noise: float      # [m]

    @property
    def conversion_time(self) -> float:
        """Longest conversion time at ``osr`` [s]."""
        return OSR[self.osr][1]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Ms5837Settings:
        """Build from the parameters; ``ValueError`` names the parameter."""
        parse_bus(v['bus'])
        osr = int(v['osr'])
        if osr not in OSR:
            raise ValueError(f"osr: {osr} is not one of the chip's "
                             f'({", ".join(map(str, OSR))})')
        fastest = 1.0 / (2.0 * OSR[osr][1])
        if v['rate'] > fastest:
            raise ValueError(f'rate: {v["rate"]:g} Hz is faster than two conversions at osr '
                             f'{osr} allow; choose rate <= {fastest:.0f} Hz or a lower osr')
        return cls(bus=v['bus'], address=check_address('address', v['address']), osr=osr,
                   rate=float(v['rate']), i2c_timeout=float(v['i2c_timeout']),
                   fluid_density=float(v['fluid_density']),
                   surface_pressure=float(v['surface_pressure']),
                   depth_noise=float(v['depth_noise']))


def wait_until(deadline_ns: int) -> None:
    """Sleep until the monotonic clock reaches ``deadline_ns`` (sleep may wake early)."""
    while (left := deadline_ns - time.monotonic_ns()) > 0:
        time.sleep(left * 1e-9)


class Ms5837Device:
    """The chip behind the driver: open (reset + PROM) and one sample (D2, D1)."""

    def __init__(self, dev: I2cDevice, osr: int) -> None:
        self.dev = dev
        self.osr = osr
        self._conversion_ns = int(OSR[osr][1] * 1e9)
        self.calibration: Calibration | None = None

    def open(self) -> Calibration:
        """Reset, wait for the PROM reload, read and check the PROM."""
        self.dev.command(RESET)
        wait_until(time.monotonic_ns() + int(RESET_TIME * 1e9))
        words = [int.from_bytes(self.dev.read_block(PROM_READ + 2 * i, 2), 'big')
                 for i in range(PROM_WORDS)]
        try:
            self.calibration = parse_prom(words, self.dev.name)
        except PromError as err:
            raise DeviceError(str(err)) from err
        return self.calibration

    def convert(self, d1: bool) -> int:
        """Start a conversion, wait its conversion time, return the 24-bit ADC result."""
        self.dev.command(convert_command(d1, self.osr))
        wait_until(time.monotonic_ns() + self._conversion_ns)
        return int.from_bytes(self.dev.read_block(ADC_READ, 3), 'big')


class Ms5837Node(SensorDriver):
    """MS5837-30BA driver; see the module docstring."""

    def __init__(self, node_name: str = 'depth_sensor', **kwargs: Any) -> None:
        super().__init__(node_name, device='i2c', **kwargs)
        self.settings: Ms5837Settings
        self._topics = DepthTopics(self)
        self.bind_settings(SPECS, Ms5837Settings.from_params, self._apply)
        s = self.settings
        self.device = f'{s.bus} 0x{s.address:02x}'
        self._i2c_bus: Bus | None = None
        self._chip: Ms5837Device | None = None
        self.zero_reads = 0
        self._zero_run = 0
        self.identity = ''
        self._loop = self.create_rate_loop(s.rate, self._tick)
        self.open_on(self._loop)

    def _apply(self, settings: Ms5837Settings) -> None:
        self.settings = settings
        self._topics.set_surface(settings.surface_pressure)

    # -- device lifecycle ---------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the bus, reset the chip and check its PROM."""
        s = self.settings
        bus = Bus(s.bus, s.i2c_timeout)
        chip = Ms5837Device(bus.device(s.address), s.osr)
        try:
            cal = chip.open()
        except DeviceError as err:
            bus.close()
            if isinstance(err.__cause__, PromError):
                raise  # it names the device and the words read
            text = str(err).removeprefix(f'{self.device}: ')  # transport errors name it
            raise DeviceError(f'{self.device}: no MS5837-30BA answers: {text}') from err
        self._i2c_bus, self._chip = bus, chip
        self._zero_run = 0
        self.identity = f'MS5837-30BA, C1..C6 {", ".join(map(str, cal.coefficients))}'
        self.get_logger().info(f'{self.device}: {self.identity}, osr {s.osr}')

    def close_device(self) -> None:
        """Drop the chip and close the bus (when this driver opened it)."""
        self._chip = None
        bus, self._i2c_bus = self._i2c_bus, None
        if bus is not None:
            bus.close()

    # -- the loop -----------------------------------------------------------------------------
    def _tick(self) -> None:
        chip = self._chip
        if not self.connected or chip is None or chip.calibration is None:
            self.open_if_requested()
            return
        try:
            d2 = chip.convert(d1=False)
            d1 = chip.convert(d1=True)
        except DeviceError as err:
            self.device_fault(err)
            return
        if d1 == 0 or d2 == 0:
            self.zero_reads += 1
            self._zero_run += 1
            if self._zero_run >= MAX_ZERO_READS:
                self.device_fault(DeviceError(
                    f'{self.device}: {self._zero_run} ADC reads of 0 in a row (conversions '
                    'lost: chip reset?)'))
            return
        self._zero_run = 0
        self._publish(compensate(chip.calibration, d1, d2))

    def _publish(self, reading: Reading) -> None:
        s = self.settings
        self._topics.publish(self.get_clock().now().to_msg(), reading.pressure_pa,
                             reading.temperature_c, s.fluid_density, s.depth_noise)
        self.sample_received()

    def status_values(self) -> dict[str, Any]:
        """Return the sample and zero-read counters, the identity and the surface pressure."""
        values = super().status_values()
        values.update({'identity': self.identity, 'zero_reads': self.zero_reads,
                       'surface_pressure': self._topics.surface,
                       'loop_overruns': self._loop.overruns})
        return values

    def destroy_node(self) -> None:
        """Stop the loop, close the device, destroy the node."""
        self.stop()
        self.close_device()
        super().destroy_node()
