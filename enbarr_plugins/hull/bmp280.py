"""Inside the hull: a Bosch BMP280 (or BME280) over I2C, for the failsafes.

The enclosure's air pressure and temperature, published on ``hull/pressure`` and
``hull/temperature``.

A sealed enclosure's air pressure rises when water comes in (or the seal is squeezed at depth)
and its temperature when the electronics overheat: ArduSub's FS_PRESS_ENABLE and
FS_TEMP_ENABLE read a chip like this one on the Navigator and Pixhawk boards.

``start()`` reads the chip id (0x58 BMP280, 0x60 BME280), the trimming parameters, then
writes config (standby, IIR filter) and ctrl_meas (oversampling, normal mode) and reads
ctrl_meas back. Normal mode: the chip measures on its own every measurement plus standby
time; every sample reads ctrl_meas and the six data bytes in one burst. A ctrl_meas that
reads sleep (the chip reset by a supply dip or a soft reset) is written again, the sample
dropped and counted in ``reconfigurations``; ``MAX_RECONFIGURATIONS`` in a row are a fault.
A temperature that still reads 0x80000 (no measurement yet) is not published.

Faults: a failed transfer is a ``DeviceError`` naming bus and address: counted, ERROR on
``/diagnostics``, the chip set up again with backoff, never a traceback.

Which address: 0x76 with SDO to GND, 0x77 with SDO high. The ROV's Bar30 depth sensor
(MS5837) sits at 0x76 and cannot move, so a BMP280 on the same bus must be at 0x77 (the
default here; most breakouts pull SDO high).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensor_msgs.msg import FluidPressure, Temperature

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.hull.bmp280_protocol import (
    CALIBRATION, Calibration, CALIBRATION_LENGTH, CalibrationError, CHIP_ID, CHIP_IDS,
    compensate, config, CONFIG, CTRL_MEAS, ctrl_meas, DATA, DATA_LENGTH, FILTER, MODE_NORMAL,
    OVERSAMPLING, raw_values, SKIPPED, STANDBY_MS)
from enbarr_plugins.imu.common import Bus, check_address, parse_bus
from enbarr_plugins.transport.i2c import I2cDevice

#: Reconfigurations in a row (the chip never stays in normal mode) that make a device fault.
MAX_RECONFIGURATIONS = 5

SPECS = [
    ParamSpec('bus', '1', "I2C bus: a number ('1'), a device ('/dev/i2c-1') or "
              "'emulated[:NAME]'", read_only=True),
    ParamSpec('address', 0x77, 'I2C address: 0x77 (SDO high), 0x76 (SDO low; taken by a '
              'Bar30 on the same bus)', '', 3, 0x77, read_only=True),
    ParamSpec('rate', 2.0, 'Samples read per second', 'Hz', 0.1, 50.0, read_only=True),
    ParamSpec('pressure_oversampling', 16, 'Pressure oversampling (1, 2, 4, 8, 16)', '', 1,
              16, read_only=True),
    ParamSpec('temperature_oversampling', 2, 'Temperature oversampling (1, 2, 4, 8, 16)', '',
              1, 16, read_only=True),
    ParamSpec('filter', 4, 'IIR filter coefficient (0 off, 2, 4, 8, 16)', '', 0, 16,
              read_only=True),
    ParamSpec('standby', 250.0, 'Standby between measurements in normal mode (0.5, 62.5, 125, '
              '250, 500, 1000, 2000, 4000)', 'ms', 0.5, 4000.0, read_only=True),
    ParamSpec('pressure_noise', 1.3, 'Pressure standard deviation published as the variance '
              "(the data sheet's RMS noise at x16 with filter 4 is about 1.3 Pa)", 'Pa', 0.0,
              1000.0),
    ParamSpec('i2c_timeout', 0.05, 'I2C adapter timeout', 's', 0.01, 1.0, read_only=True),
]


@dataclass(frozen=True)
class Bmp280Settings:
    """Settings of ``Bmp280Node`` (``SPECS``)."""

    bus: str
    address: int
    rate: float            # [Hz]
    ctrl_meas: int         # the register's value (normal mode)
    config: int            # the register's value
    pressure_noise: float  # [Pa]
    i2c_timeout: float     # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Bmp280Settings:
        """Build from the parameters; ``ValueError`` names the parameter."""
        parse_bus(v['bus'])
        for name, table in (('pressure_oversampling', OVERSAMPLING),
                            ('temperature_oversampling', OVERSAMPLING), ('filter', FILTER),
                            ('standby', STANDBY_MS)):
            if v[name] not in table or (table is OVERSAMPLING and v[name] == 0):
                allowed = ', '.join(f'{k:g}' for k in table if k or table is not OVERSAMPLING)
                raise ValueError(f"{name}: {v[name]:g} is not one of the chip's ({allowed})")
        return cls(bus=v['bus'], address=check_address('address', v['address']),
                   rate=float(v['rate']),
                   ctrl_meas=ctrl_meas(int(v['temperature_oversampling']),
                                       int(v['pressure_oversampling']), MODE_NORMAL),
                   config=config(float(v['standby']), int(v['filter'])),
                   pressure_noise=float(v['pressure_noise']),
                   i2c_timeout=float(v['i2c_timeout']))


class Bmp280Node(SensorDriver):
    """BMP280 inside the hull; see the module docstring."""

    def __init__(self, node_name: str = 'hull_sensor', **kwargs: Any) -> None:
        super().__init__(node_name, device='i2c', **kwargs)
        self.settings: Bmp280Settings
        self.bind_settings(SPECS, Bmp280Settings.from_params, self._apply)
        s = self.settings
        self.device = f'{s.bus} 0x{s.address:02x}'
        self._pressure = self.create_topic_publisher(topics.HULL_PRESSURE)
        self._temperature = self.create_topic_publisher(topics.HULL_TEMPERATURE)
        self._i2c_bus: Bus | None = None
        self._dev: I2cDevice | None = None
        self._calibration: Calibration | None = None
        self.chip = ''
        self.reconfigurations = 0
        self._reconfiguration_run = 0
        self.not_ready = 0
        self._loop = self.create_rate_loop(s.rate, self._tick)
        self.open_on(self._loop)

    def _apply(self, settings: Bmp280Settings) -> None:
        self.settings = settings

    def _configure(self, dev: I2cDevice) -> None:
        s = self.settings
        dev.write_u8(CONFIG, s.config)      # config first: written in sleep it always holds
        dev.write_u8(CTRL_MEAS, s.ctrl_meas)

    def open_device(self) -> None:
        """Open the bus, check the chip id, read the trimming, start normal mode."""
        s = self.settings
        bus = Bus(s.bus, s.i2c_timeout)
        dev = bus.device(s.address)
        try:
            chip_id = dev.read_u8(CHIP_ID)
            if chip_id not in CHIP_IDS:
                raise DeviceError(f'{self.device}: not a BMP280: chip id 0x{chip_id:02x} '
                                  f'(a BMP280 reads 0x58, a BME280 0x60)')
            try:
                cal = Calibration.from_bytes(dev.read_block(CALIBRATION, CALIBRATION_LENGTH))
            except CalibrationError as err:
                raise DeviceError(f'{self.device}: {err}') from err
            self._configure(dev)
            back = dev.read_u8(CTRL_MEAS)
        except DeviceError as err:
            bus.close()
            text = str(err).removeprefix(f'{self.device}: ')
            raise DeviceError(f'{self.device}: {text}') from err
        if back != s.ctrl_meas:
            bus.close()
            raise DeviceError(f'{self.device}: ctrl_meas reads 0x{back:02x} after '
                              f'0x{s.ctrl_meas:02x} was written')
        self._i2c_bus, self._dev, self._calibration = bus, dev, cal
        self.chip = CHIP_IDS[chip_id]
        self._reconfiguration_run = 0
        self.get_logger().info(f'{self.device}: {self.chip}, ctrl_meas 0x{s.ctrl_meas:02x}, '
                               f'config 0x{s.config:02x}')

    def close_device(self) -> None:
        """Drop the chip and close the bus (when this driver opened it)."""
        self._dev = None
        bus, self._i2c_bus = self._i2c_bus, None
        if bus is not None:
            bus.close()

    def _tick(self) -> None:
        dev, cal = self._dev, self._calibration
        if not self.connected or dev is None or cal is None:
            self.open_if_requested()
            return
        s = self.settings
        try:
            if dev.read_u8(CTRL_MEAS) != s.ctrl_meas:
                self.reconfigurations += 1   # reset by a supply dip: asleep, data 0x80000
                self._reconfiguration_run += 1
                if self._reconfiguration_run >= MAX_RECONFIGURATIONS:
                    raise DeviceError(f'{self.device}: the chip does not stay in normal mode '
                                      f'({self._reconfiguration_run} writes in a row)')
                self._configure(dev)
                return
            self._reconfiguration_run = 0
            adc_p, adc_t = raw_values(dev.read_block(DATA, DATA_LENGTH))
        except DeviceError as err:
            self.device_fault(err)
            return
        if adc_t == SKIPPED or adc_p == SKIPPED:
            self.not_ready += 1             # no measurement since the chip woke
            return
        reading = compensate(adc_p, adc_t, cal)
        stamp = self.get_clock().now().to_msg()
        p = FluidPressure()
        p.header.stamp = stamp
        p.fluid_pressure = float(reading.pressure or 0.0)
        p.variance = s.pressure_noise ** 2
        t = Temperature()
        t.header.stamp = stamp
        t.temperature = reading.temperature
        self._pressure.publish(p)
        self._temperature.publish(t)
        self.sample_received()

    def status_values(self) -> dict[str, Any]:
        """Return the chip and the sample, reconfiguration and not-ready counters."""
        values = super().status_values()
        values.update({'chip': self.chip, 'reconfigurations': self.reconfigurations,
                       'not_ready': self.not_ready})
        return values

    def destroy_node(self) -> None:
        """Stop the loop, close the device, destroy the node."""
        self.stop()
        self.close_device()
        super().destroy_node()
