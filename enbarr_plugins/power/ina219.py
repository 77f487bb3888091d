"""Battery monitor: TI INA219 over I2C, published as ``sensor_msgs/BatteryState``.

Why the INA219 (``ina219_protocol.py``): voltage and current on one chip, as on the hobby ROV
power modules; the ADS1115 would need an external current sense.

``start()`` writes the configuration (32 V range, 320 mV shunt range, 12-bit, continuous)
and the calibration computed from ``shunt`` [ohm] and ``current_lsb`` [A], then reads the
calibration back: the INA219 has no identity register, and a chip that returns what was
written is the chip expected. Every sample reads the calibration, the bus voltage and the
current; a calibration that reads 0 (the chip reset by a supply dip, when its current reads 0
too) is written again, the sample dropped and counted in ``recalibrations``; ``MAX_RECALIBRATIONS``
in a row are a fault.

Published on ``battery``: voltage [V], current [A] (negative while discharging, as
BatteryState defines it: the INA219's positive current is the load's draw) and percentage
(0..1) from ``cells`` and a straight line per cell from ``cell_empty`` to ``cell_full`` volts
(a rough curve: it reads the voltage under load); NaN when ``cells`` is 0 (unknown), as the
message allows. Unmeasured fields are NaN. A bus voltage with OVF set (current or power out
of range) is counted in ``overflows``.

Faults: a failed transfer is a ``DeviceError`` naming bus and address: counted, ERROR on
``/diagnostics``, the chip set up again with backoff, never a traceback.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensor_msgs.msg import BatteryState

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.imu.common import Bus, check_address, parse_bus
from enbarr_plugins.power.ina219_protocol import (
    ADDRESS, BUS_VOLTAGE, bus_voltage, CALIBRATION, calibration, CONFIG,
    CONFIG_32V_320MV_12BIT, current, CURRENT)
from enbarr_plugins.transport.i2c import I2cDevice

NAN = float('nan')
#: Recalibrations in a row (the calibration never holds) that make a device fault.
MAX_RECALIBRATIONS = 5

SPECS = [
    ParamSpec('bus', '1', "I2C bus: a number ('1'), a device ('/dev/i2c-1') or "
              "'emulated[:NAME]'", read_only=True),
    ParamSpec('address', ADDRESS, 'I2C address (0x40..0x4f by the A0/A1 pins)', '', 3, 0x77,
              read_only=True),
    ParamSpec('shunt', 0.1, 'Shunt resistance', 'ohm', 0.0001, 10.0, read_only=True),
    ParamSpec('current_lsb', 0.0001, 'Current register step (sets the calibration)', 'A',
              1e-6, 0.1, read_only=True),
    ParamSpec('rate', 5.0, 'Samples per second', 'Hz', 0.1, 100.0, read_only=True),
    ParamSpec('cells', 0, 'Battery cells in series (0: unknown, percentage NaN)', '', 0, 14),
    ParamSpec('cell_empty', 3.3, 'Cell voltage reported as 0 %', 'V', 2.5, 4.5),
    ParamSpec('cell_full', 4.2, 'Cell voltage reported as 100 %', 'V', 2.5, 4.5),
    ParamSpec('i2c_timeout', 0.05, 'I2C adapter timeout', 's', 0.01, 1.0, read_only=True),
]


@dataclass(frozen=True)
class Ina219Settings:
    """Settings of ``Ina219Node`` (``SPECS``)."""

    bus: str
    address: int
    shunt: float        # [ohm]
    current_lsb: float  # [A]
    calibration: int    # the register's value
    rate: float         # [Hz]
    cells: int
    cell_empty: float   # [V]
    cell_full: float    # [V]
    i2c_timeout: float  # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Ina219Settings:
        """Build from the parameters; ``ValueError`` names the parameter."""
        parse_bus(v['bus'])
        if v['cell_full'] <= v['cell_empty']:
            raise ValueError('cell_full must be above cell_empty')
        return cls(bus=v['bus'], address=check_address('address', v['address']),
                   shunt=float(v['shunt']), current_lsb=float(v['current_lsb']),
                   calibration=calibration(float(v['current_lsb']), float(v['shunt'])),
                   rate=float(v['rate']), cells=int(v['cells']),
                   cell_empty=float(v['cell_empty']), cell_full=float(v['cell_full']),
                   i2c_timeout=float(v['i2c_timeout']))


def percentage(volts: float, cells: int, empty: float, full: float) -> float:
    """Return the state of charge 0..1 from the pack voltage, straight per cell; NaN: 0 cells."""
    if cells <= 0:
        return NAN
    return min(1.0, max(0.0, (volts / cells - empty) / (full - empty)))


def read16(dev: I2cDevice, register: int) -> int:
    """Read one 16-bit register, MSB first."""
    return int.from_bytes(dev.read_block(register, 2), 'big')


def write16(dev: I2cDevice, register: int, value: int) -> None:
    """Write one 16-bit register, MSB first."""
    dev.write_block(register, value.to_bytes(2, 'big'))


class Ina219Node(SensorDriver):
    """INA219 battery monitor; see the module docstring."""

    def __init__(self, node_name: str = 'battery_monitor', **kwargs: Any) -> None:
        super().__init__(node_name, device='i2c', **kwargs)
        self.settings: Ina219Settings
        self.bind_settings(SPECS, Ina219Settings.from_params, self._apply)
        s = self.settings
        self.device = f'{s.bus} 0x{s.address:02x}'
        self._pub = self.create_topic_publisher(topics.BATTERY)
        self._i2c_bus: Bus | None = None
        self._dev: I2cDevice | None = None
        self.recalibrations = 0
        self._recalibration_run = 0
        self.overflows = 0
        self._loop = self.create_rate_loop(s.rate, self._tick)
        self.open_on(self._loop)

    def _apply(self, settings: Ina219Settings) -> None:
        self.settings = settings

    def open_device(self) -> None:
        """Open the bus, write configuration and calibration, read the calibration back."""
        s = self.settings
        bus = Bus(s.bus, s.i2c_timeout)
        dev = bus.device(s.address)
        try:
            write16(dev, CONFIG, CONFIG_32V_320MV_12BIT)
            write16(dev, CALIBRATION, s.calibration)
            back = read16(dev, CALIBRATION)
        except DeviceError as err:
            bus.close()
            text = str(err).removeprefix(f'{self.device}: ')
            raise DeviceError(f'{self.device}: no INA219 answers: {text}') from err
        if back != s.calibration:
            bus.close()
            raise DeviceError(f'{self.device}: not an INA219: the calibration register reads '
                              f'0x{back:04x} after 0x{s.calibration:04x} was written')
        self._i2c_bus, self._dev = bus, dev
        self._recalibration_run = 0
        self.get_logger().info(f'{self.device}: INA219, calibration {s.calibration}')

    def close_device(self) -> None:
        """Drop the chip and close the bus (when this driver opened it)."""
        self._dev = None
        bus, self._i2c_bus = self._i2c_bus, None
        if bus is not None:
            bus.close()

    def _tick(self) -> None:
        dev = self._dev
        if not self.connected or dev is None:
            self.open_if_requested()
            return
        s = self.settings
        try:
            if read16(dev, CALIBRATION) != s.calibration:
                self.recalibrations += 1   # reset by a supply dip: current reads 0 until set
                self._recalibration_run += 1
                if self._recalibration_run >= MAX_RECALIBRATIONS:
                    raise DeviceError(f'{self.device}: the calibration does not hold '
                                      f'({self._recalibration_run} writes in a row)')
                write16(dev, CONFIG, CONFIG_32V_320MV_12BIT)
                write16(dev, CALIBRATION, s.calibration)
                return
            self._recalibration_run = 0
            bus = bus_voltage(read16(dev, BUS_VOLTAGE))
            amps = current(read16(dev, CURRENT), s.current_lsb)
        except DeviceError as err:
            self.device_fault(err)
            return
        if bus.overflow:
            self.overflows += 1
        msg = BatteryState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.voltage = bus.volts
        msg.current = -amps
        msg.temperature = msg.charge = msg.capacity = msg.design_capacity = NAN
        msg.percentage = percentage(bus.volts, s.cells, s.cell_empty, s.cell_full)
        msg.power_supply_status = (BatteryState.POWER_SUPPLY_STATUS_DISCHARGING if amps > 0
                                   else BatteryState.POWER_SUPPLY_STATUS_UNKNOWN)
        msg.present = True
        self._pub.publish(msg)
        self.sample_received()

    def status_values(self) -> dict[str, Any]:
        """Return the sample, recalibration and overflow counters."""
        values = super().status_values()
        values.update({'recalibrations': self.recalibrations, 'overflows': self.overflows,
                       'calibration': self.settings.calibration})
        return values

    def destroy_node(self) -> None:
        """Stop the loop, close the device, destroy the node."""
        self.stop()
        self.close_device()
        super().destroy_node()
