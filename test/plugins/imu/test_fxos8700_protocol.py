"""Unit tests: every FXOS8700CQ and FXAS21002C number the driver relies on, pinned to its
source document.

The tables below are typed from the sources, never read from the code under test. Each is
compared with the driver's protocol module (``fxos8700_protocol.py``) and exercised through
the emulator (``fxos8700_emulator.py``, which keeps its own copy); the last test runs the
driver's chips against the emulator over every range.

Sources:
- NXP FXOS8700CQ data sheet Rev 8: register map and descriptions (sections 14 and 15),
  accelerometer sensitivity 0.244/0.488/0.976 mg/LSB at +-2/4/8 g (14-bit), magnetometer
  0.1 uT/LSB, hybrid-mode ODR (CTRL_REG1 DR codes, half the single-sensor rates).
- NXP FXAS21002C data sheet Rev 2.1: register map (section 13), sensitivity 62.5/31.25/15.625/
  7.8125 mdps/LSB at +-2000/1000/500/250 dps, ODR 800 Hz >> DR.
- Linux ``drivers/iio/imu/fxos8700_core.c`` (FXOS8700_STATUS 0x00 ... M_CTRL_REG2 0x5c,
  FXOS8700_DEVICE_ID 0xC7, fxos8700_accel_scale 244/488/976, fxos8700_odr 800 ... 1.5625 Hz)
  and ``drivers/iio/gyro/fxas21002c.h``/``fxas21002c_core.c`` (FXAS21002C_REG_* 0x00 ... 0x15,
  CTRL_REG1 fields RST 6, DR 4:2, ACTIVE 1; CTRL_REG3 WRAPTOONE 3; chip ID 0xD7).
- Adafruit_FXOS8700 (FXOS8700_ADDRESS 0x1F, ACCEL_MG_LSB_2G ... 8G, MAG_UT_LSB 0.1; CTRL_REG2
  0x02 high resolution, M_CTRL_REG1 0x1F hybrid with OSR 7, M_CTRL_REG2 0x20 "jump to reg 0x33
  after reading 0x06", CTRL_REG1 0x15 = 100 Hz hybrid, low noise, active) and
  Adafruit_FXAS21002C (FXAS21002C_ADDRESS 0x21, GYRO_SENSITIVITY_250DPS 0.0078125 ...).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from enbarr_plugins.imu import fxos8700
from enbarr_plugins.imu import fxos8700_protocol as proto
from enbarr_plugins.imu.check import wait_sample
from enbarr_plugins.imu.chip_emulator import Truth
from enbarr_plugins.imu.common import Bus
from enbarr_plugins.imu.fxos8700_emulator import attach_fxos8700
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.imu import assert_ranges, close_in_scale, registered

G = 9.80665          # [m/s^2]

REGISTERS = {
    # FXOS8700CQ
    'STATUS': 0x00, 'OUT_X_MSB': 0x01, 'FXOS_WHO_AM_I': 0x0D, 'XYZ_DATA_CFG': 0x0E,
    'CTRL_REG1': 0x2A, 'CTRL_REG2': 0x2B, 'M_DR_STATUS': 0x32, 'M_OUT_X_MSB': 0x33,
    'M_CTRL_REG1': 0x5B, 'M_CTRL_REG2': 0x5C,
    # FXAS21002C
    'FXAS_WHO_AM_I': 0x0C, 'CTRL_REG0': 0x0D, 'G_CTRL_REG1': 0x13, 'G_CTRL_REG3': 0x15,
}
VALUES = {
    'ADDRESS': 0x1F, 'GYRO_ADDRESS': 0x21, 'FXOS_WHO_AM_I_VALUE': 0xC7,
    'FXAS_WHO_AM_I_VALUE': 0xD7,
    'ACTIVE': 0x01, 'LNOISE': 0x04,            # CTRL_REG1 bits 0, 2
    'MODS_HIGH_RESOLUTION': 0x02,              # CTRL_REG2 MODS = 2
    'M_HYBRID_OS7': 0x1F,                      # M_OS = 7 (bits 4:2), M_HMS = 3 (bits 1:0)
    'HYB_AUTOINC_MODE': 0x20,                  # M_CTRL_REG2 bit 5
    'ZYXDR': 0x08,                             # (M_)DR_STATUS bit 3
    'G_ACTIVE': 0x02, 'WRAPTOONE': 0x08,       # FXAS21002C CTRL_REG1 bit 1, CTRL_REG3 bit 3
}
ACCEL = {2.0: (0, 0.244), 4.0: (1, 0.488), 8.0: (2, 0.976)}                      # mg/LSB
GYRO = {2000.0: (0, 62.5), 1000.0: (1, 31.25), 500.0: (2, 15.625), 250.0: (3, 7.8125)}  # mdps
MAG_UT_PER_LSB = 0.1
MAG_FULL_SCALE = 1200.0  # [uT], fixed
HYBRID_ODR = {400.0: 0, 200.0: 1, 100.0: 2, 50.0: 3, 25.0: 4, 6.25: 5, 3.125: 6, 0.7813: 7}
GYRO_ODR = {800.0: 0, 400.0: 1, 200.0: 2, 100.0: 3, 50.0: 4, 25.0: 5, 12.5: 6}

FILL = 0.8
#: Of the largest component: over the emulator's (seeded) noise, under any wrong entry.
TOLERANCE = 0.004


@pytest.mark.parametrize('name, value', {**REGISTERS, **VALUES}.items())
def test_registers_bits_and_identities_match_the_data_sheets(name, value):
    assert getattr(proto, name) == value


def test_sensitivities_and_codes_match_the_data_sheets():
    assert_ranges(proto.ACCEL_RANGE, ACCEL, 1e-3)
    assert_ranges(proto.GYRO_RANGE, GYRO, 1e-3)
    assert proto.MAG_LSB == pytest.approx(MAG_UT_PER_LSB * 1e-6, rel=1e-9)
    assert proto.ACCEL_ODR == HYBRID_ODR and proto.GYRO_ODR == GYRO_ODR


# -- the emulators, written to and read through their registers -----------------------------

@pytest.fixture
def chips():
    bus = FakeI2cBus()
    am, g = attach_fxos8700(bus)
    assert set(bus.devices) == {0x1F, 0x21}
    return am, g


def close(measured: np.ndarray, expected: np.ndarray) -> None:
    close_in_scale(measured, expected, TOLERANCE)


def test_the_emulators_answer_the_identities(chips):
    am, g = chips
    assert am.read(0x0D, 1) == bytes([0xC7]) and g.read(0x0C, 1) == bytes([0xD7])


def hybrid(am, fs_code: int, dr_code: int = 2) -> None:
    """Configure the FXOS8700CQ as the data sheet says: standby, range, hybrid, active."""
    am.write(0x2A, bytes([0x00]))
    am.write(0x0E, bytes([fs_code]))
    am.write(0x5B, bytes([0x1F]))
    am.write(0x5C, bytes([0x20]))
    am.write(0x2A, bytes([dr_code << 3 | 0x01]))


@pytest.mark.parametrize('full_scale', ACCEL)
def test_the_emulator_scales_accelerometer_and_magnetometer_by_the_data_sheet(chips,
                                                                              full_scale):
    am, _ = chips
    code, mg = ACCEL[full_scale]
    f = FILL * full_scale * np.array([1.0, -0.5, 0.25])               # [g]
    field = FILL * MAG_FULL_SCALE * np.array([-0.5, 1.0, -0.25])     # [uT]
    am.set_truth(Truth(np.zeros(3), f * G, field * 1e-6))
    hybrid(am, code)
    block = am.read(0x00, 13)                                         # hybrid auto-increment
    accel = np.frombuffer(block, '>i2', 3, 1).astype(float)
    assert not np.any(accel.astype(int) & 0x3)                        # 14 bits, left-justified
    close(accel / 4.0, f / (mg * 1e-3))
    close(np.frombuffer(block, '>i2', 3, 7).astype(float), field / MAG_UT_PER_LSB)


def wait_gyro(g, timeout: float = 2.0) -> None:
    """Poll the FXAS21002C until it has a sample (1/ODR + 60 ms after turning active)."""
    deadline = time.monotonic() + timeout
    while not g.read(0x00, 1)[0] & 0x08:
        assert time.monotonic() < deadline, 'no gyro sample'
        time.sleep(0.005)


@pytest.mark.parametrize('full_scale', GYRO)
def test_the_emulator_scales_the_gyro_by_the_data_sheet(chips, full_scale):
    _, g = chips
    code, mdps = GYRO[full_scale]
    rate = FILL * full_scale * np.array([0.25, 1.0, -0.5])            # [dps]
    g.set_truth(Truth(np.radians(rate), np.zeros(3), np.zeros(3)))
    g.write(0x13, bytes([0x00]))                                      # standby
    g.write(0x0D, bytes([code]))                                      # CTRL_REG0: FS
    g.write(0x13, bytes([0 << 2 | 0x02]))                             # 800 Hz, ACTIVE
    wait_gyro(g)
    close(np.frombuffer(g.read(0x01, 6), '>i2', 3).astype(float), rate / (mdps * 1e-3))


def test_the_emulators_run_at_the_data_sheet_rates(chips):
    am, g = chips
    for hz, code in HYBRID_ODR.items():
        hybrid(am, 0, code)
        assert am.odr() == pytest.approx(hz, rel=1e-3)
    g.write(0x13, bytes([0x00]))
    g.write(0x13, bytes([6 << 2 | 0x02]))                             # 12.5 Hz, ACTIVE
    wait_gyro(g)
    for hz, code in GYRO_ODR.items():
        g.write(0x13, bytes([code << 2 | 0x02]))                      # stays active: no delay
        assert g.odr() == hz


# -- the driver's chips against the emulators, every range ----------------------------------

@pytest.mark.parametrize('accel_range, gyro_range', [
    (2.0, 250.0), (4.0, 500.0), (8.0, 1000.0), (8.0, 2000.0)])
def test_the_driver_reads_si_values_in_every_range(accel_range, gyro_range):
    bus = FakeI2cBus()
    am, g = attach_fxos8700(bus)
    truth = Truth(np.radians(FILL * gyro_range * np.array([-0.5, 0.25, 1.0])),
                  FILL * accel_range * G * np.array([0.25, 1.0, -0.5]),
                  FILL * MAG_FULL_SCALE * 1e-6 * np.array([0.25, -0.5, 1.0]))
    am.set_truth(truth)
    g.set_truth(truth)
    with registered(bus) as value:
        s = fxos8700.default_settings(bus=value, accel_range=accel_range,
                                      gyro_range=gyro_range)
        chips = fxos8700.Fxos8700Chips(Bus(value, 0.05), s)
        chips.open()
        sample = wait_sample(chips, 3.0)
    close(sample.gyro, truth.gyro)
    close(sample.accel, truth.accel)
    close(sample.mag, truth.mag)
