"""Unit tests: the import rules of the ROV device plugins (IMU, thrusters, IO), read from the
source (every import, also those inside functions).

- A real driver imports neither its emulator, nor a simulated twin, nor ``enbarr
  check-device`` code: what a kind shares lives in its common module.
- An emulator imports neither the driver nor the driver's protocol module: it is written from
  the data sheet with its own copy of the numbers, so the tests that pin those numbers catch
  a wrong one on either side.
- A protocol module imports no other module of the package: it is the data sheet's numbers.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import enbarr_plugins
from support.layering import imports_in

PACKAGE = Path(enbarr_plugins.__file__).parent
DRIVERS = ['imu/lsm9ds1', 'imu/fxos8700', 'thrusters/pca9685', 'io/gpio_lights', 'io/stepper',
           'io/leak', 'power/ina219', 'hull/bmp280']
EMULATORS = {
    'imu/lsm9ds1_emulator': ['imu.lsm9ds1', 'imu.lsm9ds1_protocol'],
    'imu/fxos8700_emulator': ['imu.fxos8700', 'imu.fxos8700_protocol'],
    'imu/chip_emulator': ['imu.lsm9ds1', 'imu.lsm9ds1_protocol', 'imu.fxos8700',
                          'imu.fxos8700_protocol'],
    'thrusters/pca9685_emulator': ['thrusters.pca9685', 'thrusters.pca9685_protocol'],
    'power/ina219_emulator': ['power.ina219', 'power.ina219_protocol'],
    'hull/bmp280_emulator': ['hull.bmp280', 'hull.bmp280_protocol'],
}
PROTOCOLS = ['imu/lsm9ds1_protocol', 'imu/fxos8700_protocol', 'thrusters/pca9685_protocol',
             'power/ina219_protocol', 'hull/bmp280_protocol']


def imports(module: str) -> set[str]:
    """Every module ``module`` (a path below the package, without .py) imports, dotted."""
    return imports_in(PACKAGE / f'{module}.py')


def ours(module: str) -> set[str]:
    """The modules of this package that ``module`` imports, relative to it."""
    prefix = 'enbarr_plugins.'
    return {name[len(prefix):] for name in imports(module) if name.startswith(prefix)}


@pytest.mark.parametrize('driver', DRIVERS)
def test_a_driver_imports_no_emulator_simulator_or_check(driver):
    kind = driver.split('/')[0]
    wrong = {name for name in ours(driver)
             if name.startswith(f'{kind}.') and (name.endswith('_emulator')
                                                 or name.split('.')[1].startswith('sim')
                                                 or name.split('.')[1] == 'check')}
    assert not wrong, f'{driver} imports {sorted(wrong)}'


@pytest.mark.parametrize('emulator, forbidden', EMULATORS.items())
def test_an_emulator_imports_neither_its_driver_nor_the_protocol(emulator, forbidden):
    wrong = {name for name in ours(emulator)
             if any(name == f or name.startswith(f'{f}.') for f in forbidden)}
    assert not wrong, f'{emulator} imports {sorted(wrong)}'


@pytest.mark.parametrize('protocol', PROTOCOLS)
def test_a_protocol_module_imports_nothing_of_the_package(protocol):
    assert not ours(protocol), f'{protocol} imports {sorted(ours(protocol))}'
