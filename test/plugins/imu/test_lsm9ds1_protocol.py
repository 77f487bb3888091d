"""Unit tests: every LSM9DS1 number the driver relies on, pinned to its source document.

The tables below are typed from the sources, never read from the code under test. Each is
compared with the driver's protocol module (``lsm9ds1_protocol.py``) and exercised through the
emulator (``lsm9ds1_emulator.py``, which keeps its own copy), so a wrong number on either side
fails here; the last test runs the driver's chips against the emulator over every range.

Sources:
- ST DocID025715 "LSM9DS1 iNEMO inertial module" Rev 3: Table 3 (sensitivities LA_So, G_So,
  M_GN), section 6 (register map), sections 7 and 8 (register fields, ODR and FS codes).
- ST's reference driver, STMicroelectronics/STMems_Standard_C_drivers
  ``lsm9ds1_STdC/driver/lsm9ds1_reg.h`` (register addresses, bit fields, the FS and ODR enums,
  LSM9DS1_IMU_ID 0x68, LSM9DS1_MAG_ID 0x3D) and ``lsm9ds1_reg.c`` (``lsm9ds1_from_fs2g_to_mg``
  0.061 ... ``lsm9ds1_from_fs16gauss_to_mG`` 0.58).
- Linux ``drivers/iio/imu/st_lsm6dsx/st_lsm6dsx_core.c`` (LSM9DS1: accel 61/122/244/732 ug
  with FS codes 0/2/3/1, gyro 8750/17500/70000 udps with codes 0/1/3) and
  ``drivers/iio/magnetometer/st_magn_core.c`` (multi_read_bit for the magnetometer).
- SparkFun LSM9DS1 library (LSM9DS1_AG_ADDR 0x6A/0x6B, LSM9DS1_M_ADDR 0x1C/0x1E).
"""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_plugins.imu import lsm9ds1
from enbarr_plugins.imu import lsm9ds1_protocol as proto
from enbarr_plugins.imu.check import wait_sample
from enbarr_plugins.imu.chip_emulator import Truth
from enbarr_plugins.imu.common import Bus
from enbarr_plugins.imu.lsm9ds1_emulator import attach_lsm9ds1
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.imu import assert_ranges, close_in_scale, registered

G = 9.80665          # [m/s^2] standard gravity, the data sheet's g
GAUSS = 1e-4         # [T]

# Register map (section 6; lsm9ds1_reg.h).
REGISTERS = {
    'WHO_AM_I': 0x0F, 'CTRL_REG1_G': 0x10, 'STATUS_REG_G': 0x17, 'OUT_X_L_G': 0x18,
    'CTRL_REG4': 0x1E, 'CTRL_REG5_XL': 0x1F, 'CTRL_REG6_XL': 0x20, 'CTRL_REG8': 0x22,
    'STATUS_REG': 0x27, 'OUT_X_L_XL': 0x28,
    'CTRL_REG1_M': 0x20, 'CTRL_REG2_M': 0x21, 'CTRL_REG3_M': 0x22, 'CTRL_REG4_M': 0x23,
    'CTRL_REG5_M': 0x24, 'STATUS_REG_M': 0x27, 'OUT_X_L_M': 0x28,
}
# Addresses, identities, bits and field values (sections 6-8; lsm9ds1_reg.h bit fields).
VALUES = {
    'ADDRESS_AG': 0x6B, 'ADDRESS_M': 0x1E, 'WHO_AM_I_AG_VALUE': 0x68, 'WHO_AM_I_M_VALUE': 0x3D,
    'XLDA': 0x01, 'GDA': 0x02,                 # STATUS_REG bits 0, 1
    'BDU': 0x40, 'IF_ADD_INC': 0x04,           # CTRL_REG8 bits 6, 2 (BDU: CTRL_REG5_M bit 6 too)
    'XYZ_ENABLED': 0x38,                       # Zen, Yen, Xen: bits 5:3
    'ZYXDA': 0x08,                             # STATUS_REG_M bit 3
    'OM_ULTRA_HIGH': 0b11, 'MD_CONTINUOUS': 0b00,
    'AUTO_INCREMENT_M': 0x80,                  # sub-address MSB (st_magn multi_read_bit)
}
# Full scale -> (FS code, sensitivity). Table 3; lsm9ds1_reg.c; st_lsm6dsx.
GYRO = {245.0: (0, 8.75), 500.0: (1, 17.50), 2000.0: (3, 70.0)}                 # mdps/LSB
ACCEL = {2.0: (0, 0.061), 4.0: (2, 0.122), 8.0: (3, 0.244), 16.0: (1, 0.732)}   # mg/LSB
MAG = {4.0: (0, 0.14), 8.0: (1, 0.29), 12.0: (2, 0.43), 16.0: (3, 0.58)}        # mgauss/LSB
# Output data rate [Hz] -> code. ODR_G (gyro on; the accelerometer follows it), ODR_XL with
# the gyro powered down, DO of the magnetometer.
GYRO_ODR = {14.9: 1, 59.5: 2, 119.0: 3, 238.0: 4, 476.0: 5, 952.0: 6}
ACCEL_ONLY_ODR = {10.0: 1, 50.0: 2, 119.0: 3, 238.0: 4, 476.0: 5, 952.0: 6}
MAG_ODR = {0.625: 0, 1.25: 1, 2.5: 2, 5.0: 3, 10.0: 4, 20.0: 5, 40.0: 6, 80.0: 7}

FILL = 0.8           # the test signal, as a share of the full scale
#: Of the largest component: over the emulator's (seeded) noise, under the smallest wrong entry
#: that matters (0.292 for 0.29 mgauss/LSB is 0.7 %).
TOLERANCE = 0.004


@pytest.mark.parametrize('name, value', {**REGISTERS, **VALUES}.items())
def test_registers_bits_and_identities_match_the_data_sheet(name, value):
    assert getattr(proto, name) == value


def test_sensitivities_and_codes_match_the_data_sheet():
    assert_ranges(proto.GYRO_RANGE, GYRO, 1e-3)     # mdps -> dps
    assert_ranges(proto.ACCEL_RANGE, ACCEL, 1e-3)   # mg -> g
    assert_ranges(proto.MAG_RANGE, MAG, 1e-3)       # mgauss -> gauss
    assert proto.GYRO_ODR == GYRO_ODR and proto.MAG_ODR == MAG_ODR
    assert proto.GAUSS == GAUSS
    np.testing.assert_array_equal(proto.MAG_AXES, [-1.0, 1.0, 1.0])


# -- the emulator, written to and read through its registers ----------------------------------

@pytest.fixture
def chip():
    bus = FakeI2cBus()
    ag, m = attach_lsm9ds1(bus)
    assert set(bus.devices) == {0x6B, 0x1E}
    return ag, m


def close(measured: np.ndarray, expected: np.ndarray) -> None:
    close_in_scale(measured, expected, TOLERANCE)


def words(data: bytes) -> np.ndarray:
    return np.frombuffer(data, '<i2', 3).astype(float)


def test_the_emulator_answers_the_identities(chip):
    ag, m = chip
    assert ag.read(0x0F, 1) == bytes([0x68]) and m.read(0x0F, 1) == bytes([0x3D])


@pytest.mark.parametrize('full_scale', GYRO)
def test_the_emulator_scales_the_gyro_by_the_data_sheet(chip, full_scale):
    ag, _ = chip
    code, mdps = GYRO[full_scale]
    rate = FILL * full_scale * np.array([1.0, -0.5, 0.25])            # [dps]
    ag.set_truth(Truth(np.radians(rate), np.zeros(3), np.zeros(3)))
    ag.write(0x10, bytes([4 << 5 | code << 3]))                       # CTRL_REG1_G: 238 Hz
    ag.read(0x17, 1)                                                  # makes the due sample
    close(words(ag.read(0x18, 6)), rate / (mdps * 1e-3))


@pytest.mark.parametrize('full_scale', ACCEL)
def test_the_emulator_scales_the_accelerometer_by_the_data_sheet(chip, full_scale):
    ag, _ = chip
    code, mg = ACCEL[full_scale]
    f = FILL * full_scale * np.array([-0.25, 0.5, 1.0])               # [g]
    ag.set_truth(Truth(np.zeros(3), f * G, np.zeros(3)))
    ag.write(0x20, bytes([4 << 5 | code << 3]))                       # CTRL_REG6_XL: 238 Hz
    ag.read(0x27, 1)
    close(words(ag.read(0x28, 6)), f / (mg * 1e-3))


@pytest.mark.parametrize('full_scale', MAG)
def test_the_emulator_scales_the_magnetometer_by_the_data_sheet(chip, full_scale):
    _, m = chip
    code, mgauss = MAG[full_scale]
    field = FILL * full_scale * np.array([1.0, -0.5, 0.25])           # [gauss], FLU
    m.set_truth(Truth(np.zeros(3), np.zeros(3), field * GAUSS))
    m.write(0x21, bytes([code << 5]))                                 # CTRL_REG2_M: FS
    m.write(0x20, bytes([7 << 2]))                                    # CTRL_REG1_M: 80 Hz
    m.write(0x22, bytes([0x00]))                                      # CTRL_REG3_M: continuous
    m.read(0x27, 1)
    chip_axes = field * np.array([-1.0, 1.0, 1.0])                    # X_M opposite X_AG
    close(words(m.read(0x28 | 0x80, 6)), chip_axes / (mgauss * 1e-3))


def test_the_emulator_runs_at_the_data_sheet_rates(chip):
    ag, m = chip
    for hz, code in GYRO_ODR.items():
        ag.write(0x10, bytes([code << 5]))
        assert ag.odr() == hz
    ag.write(0x10, bytes([0]))                                        # gyro powered down
    for hz, code in ACCEL_ONLY_ODR.items():
        ag.write(0x20, bytes([code << 5]))
        assert ag.odr() == hz
    m.write(0x22, bytes([0x00]))
    for hz, code in MAG_ODR.items():
        m.write(0x20, bytes([code << 2]))
        assert m.odr() == hz


# -- the driver's chips against the emulator, every range -----------------------------------

@pytest.mark.parametrize('gyro_range, accel_range, mag_range', [
    (245.0, 2.0, 4.0), (500.0, 4.0, 8.0), (2000.0, 8.0, 12.0), (2000.0, 16.0, 16.0)])
def test_the_driver_reads_si_values_in_every_range(gyro_range, accel_range, mag_range):
    bus = FakeI2cBus()
    ag, m = attach_lsm9ds1(bus)
    truth = Truth(np.radians(FILL * gyro_range * np.array([0.5, -1.0, 0.25])),
                  FILL * accel_range * G * np.array([1.0, 0.25, -0.5]),
                  FILL * mag_range * GAUSS * np.array([-0.25, 0.5, 1.0]))
    ag.set_truth(truth)
    m.set_truth(truth)
    with registered(bus) as value:
        s = lsm9ds1.default_settings(bus=value, gyro_range=gyro_range,
                                     accel_range=accel_range, mag_range=mag_range)
        chips = lsm9ds1.Lsm9ds1Chips(Bus(value, 0.05), s)
        chips.open()
        sample = wait_sample(chips, 2.0)
    for measured, true in ((sample.gyro, truth.gyro), (sample.accel, truth.accel),
                           (sample.mag, truth.mag)):
        close(measured, true)
