"""``enbarr check-device ms5837``: the depth sensor alone, without a vessel.

Resets the chip with the driver's own code, reads and checks its PROM, converts D2 and D1 at
OSR 4096 and prints the calibration, the pressure and the temperature. ``--bus emulated``
puts the emulator on a private fake bus for the check. Lives apart from the driver: it is the
one place that needs both the driver and the emulator.
"""

from __future__ import annotations


from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu.common import Bus
from enbarr_plugins.pressure.ms5837 import Ms5837Device
from enbarr_plugins.pressure.ms5837_emulator import attach_ms5837
from enbarr_plugins.pressure.ms5837_protocol import ADDRESS, compensate


def check_ms5837(target: CheckTarget) -> list[str]:
    """Return the PROM's calibration and one compensated sample (see the module doc)."""
    value = target.bus or '1'
    address = ADDRESS if target.address is None else target.address
    with emulation.checked_i2c_bus(value, lambda fake: attach_ms5837(fake, address)) as value:
        try:
            bus = Bus(value, min(target.timeout, 1.0))
        except ValueError as err:
            raise DeviceError(str(err)) from err
        try:
            chip = Ms5837Device(bus.device(address), 4096)
            cal = chip.open()
            d2 = chip.convert(d1=False)
            d1 = chip.convert(d1=True)
        finally:
            bus.close()
    if d1 == 0 or d2 == 0:
        raise DeviceError(f'{bus.name} 0x{address:02x}: ADC read 0 (D1 {d1}, D2 {d2}): '
                          'conversion lost')
    r = compensate(cal, d1, d2)
    return [f'MS5837-30BA at {bus.name} 0x{address:02x}, PROM CRC ok, C1..C6 '
            f'{", ".join(map(str, cal.coefficients))}',
            f'pressure {r.pressure_pa:.0f} Pa ({r.p / 10:.1f} mbar), temperature '
            f'{r.temperature_c:.2f} degC (D1 {d1}, D2 {d2}, osr 4096)']
