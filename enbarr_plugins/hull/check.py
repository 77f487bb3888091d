"""``enbarr check-device bmp280``: the hull's pressure and temperature sensor alone.

Only reads (chip id, trimming, ctrl_meas, config, the data registers): a check must not
change a chip a running driver set up. A chip asleep (ctrl_meas mode 0, as after power-on)
has measured nothing and says so. ``--bus emulated`` puts the emulator, measuring, on a
private fake bus. Lives apart from the driver: it is the one place that needs both the
driver's protocol and the emulator.
"""

from __future__ import annotations

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.hull.bmp280_emulator import Bmp280Chip
from enbarr_plugins.hull.bmp280_protocol import (
    CALIBRATION, Calibration, CALIBRATION_LENGTH, CalibrationError, CHIP_ID, CHIP_IDS,
    compensate, CONFIG, CTRL_MEAS, ctrl_meas, DATA, DATA_LENGTH, MODE_NORMAL, raw_values,
    SKIPPED)
from enbarr_plugins.imu.common import Bus

ADDRESS = 0x77


def _measuring_chip() -> Bmp280Chip:
    chip = Bmp280Chip(pressure=101325.0, temperature=21.5)
    chip.write(CTRL_MEAS, bytes([ctrl_meas(2, 16, MODE_NORMAL)]))
    return chip


def check_bmp280(target: CheckTarget) -> list[str]:
    """Return the chip, its registers and one compensated sample (see the module doc)."""
    value = target.bus or '1'
    address = ADDRESS if target.address is None else target.address
    with emulation.checked_i2c_bus(
            value, lambda fake: fake.attach(address, _measuring_chip())) as value:
        try:
            bus = Bus(value, min(target.timeout, 1.0))
        except ValueError as err:
            raise DeviceError(str(err)) from err
        where = f'{bus.name} 0x{address:02x}'
        try:
            dev = bus.device(address)
            chip_id = dev.read_u8(CHIP_ID)
            if chip_id not in CHIP_IDS:
                raise DeviceError(f'{where}: not a BMP280: chip id 0x{chip_id:02x} (a BMP280 '
                                  'reads 0x58, a BME280 0x60)')
            try:
                cal = Calibration.from_bytes(dev.read_block(CALIBRATION, CALIBRATION_LENGTH))
            except CalibrationError as err:
                raise DeviceError(f'{where}: {err}') from err
            meas, conf = dev.read_u8(CTRL_MEAS), dev.read_u8(CONFIG)
            adc_p, adc_t = raw_values(dev.read_block(DATA, DATA_LENGTH))
        finally:
            bus.close()
    lines = [f'{CHIP_IDS[chip_id]} at {where}: ctrl_meas 0x{meas:02x}, config 0x{conf:02x}, '
             f'dig_T {", ".join(map(str, cal.t))}, dig_P {", ".join(map(str, cal.p))}']
    if meas & 0x3 == 0 or adc_t == SKIPPED:
        lines.append('asleep: nothing measured (a running driver puts it in normal mode)')
        return lines
    r = compensate(adc_p, adc_t, cal)
    pressure = 'skipped' if r.pressure is None else f'{r.pressure:.1f} Pa'
    lines.append(f'pressure {pressure}, temperature {r.temperature:.2f} degC '
                 f'(adc_P {adc_p}, adc_T {adc_t})')
    return lines
