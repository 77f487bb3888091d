"""``enbarr check-device ina219``: the battery monitor alone, without a vessel.

Only reads (the configuration, the calibration, the bus and the shunt voltage): a check must
not change a chip a running driver set up. The current needs the shunt's resistance, so the
shunt voltage is printed instead. ``--bus emulated`` puts the emulator on a private fake bus.
Lives apart from the driver: it is the one place that needs both the driver and the emulator.
"""

from __future__ import annotations


from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu.common import Bus
from enbarr_plugins.power.ina219 import read16
from enbarr_plugins.power.ina219_emulator import Ina219Chip
from enbarr_plugins.power.ina219_protocol import (
    ADDRESS, BUS_VOLTAGE, bus_voltage, CALIBRATION, CONFIG, SHUNT_VOLTAGE, shunt_voltage)


def check_ina219(target: CheckTarget) -> list[str]:
    """Return the configuration, the calibration, the bus and shunt voltage (module doc)."""
    value = target.bus or '1'
    address = ADDRESS if target.address is None else target.address
    with emulation.checked_i2c_bus(
            value, lambda fake: fake.attach(address, Ina219Chip(volts=14.8, amps=1.0))) as value:
        try:
            bus = Bus(value, min(target.timeout, 1.0))
        except ValueError as err:
            raise DeviceError(str(err)) from err
        try:
            dev = bus.device(address)
            config, cal = read16(dev, CONFIG), read16(dev, CALIBRATION)
            volts = bus_voltage(read16(dev, BUS_VOLTAGE))
            shunt = shunt_voltage(read16(dev, SHUNT_VOLTAGE))
        finally:
            bus.close()
    return [f'INA219 at {bus.name} 0x{address:02x}: configuration 0x{config:04x}, '
            f'calibration {cal}' + (' (not set: current and power read 0)' if not cal else ''),
            f'bus {volts.volts:.3f} V{" (overflow)" if volts.overflow else ""}, shunt '
            f'{shunt * 1e3:.2f} mV']
