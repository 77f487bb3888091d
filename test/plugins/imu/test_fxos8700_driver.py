"""FXOS8700CQ + FXAS21002C driver against the emulated pair: bytes, FLU values, faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.commands import main as cli
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.kinematics import quat_from_euler, quat_to_rotmat
from enbarr_interfaces import convert
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu import fxos8700
from enbarr_plugins.imu.check import check_fxos8700, wait_sample
from enbarr_plugins.imu.chip_emulator import Truth
from enbarr_plugins.imu.common import Bus, G
from enbarr_plugins.imu.fxos8700 import Fxos8700ImuNode
from enbarr_plugins.imu.fxos8700_emulator import attach_fxos8700, Fxos8700EmulatorNode
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.imu import registered, Rig

FIELD = np.array([0.0, 1.8e-5, -4.8e-5])


@pytest.fixture
def fake_bus():
    bus = FakeI2cBus()
    am, g = attach_fxos8700(bus)
    with registered(bus) as value:
        yield value, bus, am, g


def test_covariances_follow_each_chips_own_rate(fake_bus):
    """Gyro noise at gyro_odr, accelerometer noise at odr: data sheet densities x sqrt(ODR/2)."""
    value = fake_bus[0]
    s = fxos8700.default_settings(bus=value, odr=100.0, gyro_odr=400.0, rate=100.0)
    n = fxos8700.Fxos8700Chips(Bus(value, 0.05), s).noise()
    assert n.gyro == pytest.approx(0.025 * math.pi / 180 * math.sqrt(400 / 2))
    assert n.accel == pytest.approx(126e-6 * 9.80665 * math.sqrt(100 / 2))
    assert n.mag == 1e-6


def test_ranges_and_rates_go_to_the_data_sheet_registers_in_standby(fake_bus):
    value, bus, am, g = fake_bus
    s = fxos8700.default_settings(bus=value, odr=100.0, accel_range=8.0, gyro_odr=400.0,
                                  gyro_range=250.0, rate=100.0)
    fxos8700.Fxos8700Chips(Bus(value, 0.05), s).open()
    writes = [(a, r, v[0]) for op, a, r, v in bus.log if op == 'write']
    assert writes[:6] == [
        (0x1F, 0x2A, 0x00),            # CTRL_REG1: standby first
        (0x1F, 0x0E, 0x02),            # XYZ_DATA_CFG: 8 g
        (0x1F, 0x2B, 0x02),            # CTRL_REG2: high resolution
        (0x1F, 0x5B, 0x1F),            # M_CTRL_REG1: hybrid, OSR 7
        (0x1F, 0x5C, 0x20),            # M_CTRL_REG2: hybrid auto-increment
        (0x1F, 0x2A, 2 << 3 | 0x01),   # CTRL_REG1: 100 Hz hybrid, no LNOISE at 8 g, ACTIVE
    ]
    assert writes[6:] == [(0x21, 0x13, 0x00), (0x21, 0x0D, 0x03), (0x21, 0x13, 1 << 2 | 0x02)]
    assert am.registers[0x0E] == 0x02 and g.registers[0x0D] == 0x03


def test_fxos8700_ignores_range_writes_while_active(fake_bus):
    _, _, am, _ = fake_bus
    am.write(0x2A, bytes([0x01]))          # active
    am.write(0x0E, bytes([0x02]))          # XYZ_DATA_CFG: ignored while active
    assert am.registers[0x0E] == 0x00


def test_hybrid_auto_increment_reads_accel_then_magnetometer(fake_bus):
    _, _, am, g = fake_bus
    am.registers[0x01:0x07] = bytes(range(1, 7))
    am.registers[0x33:0x39] = bytes(range(0x33, 0x39))
    assert am.read(0x00, 13)[7:] == bytes(am.registers[0x07:0x0D])   # linear, no hybrid
    am.write(0x5C, bytes([0x20]))
    assert am.read(0x00, 13)[1:] == bytes(range(1, 7)) + bytes(range(0x33, 0x39))
    g.registers[0x00:0x07] = bytes([0xAA, 1, 2, 3, 4, 5, 6])
    assert g.read(0x05, 4) == bytes([5, 6, 0xAA, 1])       # wraps from 0x06 to 0x00


@pytest.mark.parametrize('name, value, allowed', [
    ('odr', 800.0, '400, 200, 100, 50, 25, 6.25, 3.125, 0.7813'),
    ('accel_range', 16.0, '2, 4, 8'),
    ('gyro_odr', 300.0, '800, 400, 200, 100, 50, 25, 12.5'),
    ('gyro_range', 245.0, '2000, 1000, 500, 250'),
])
def test_a_value_the_chip_lacks_is_refused_naming_parameter_and_set(name, value, allowed):
    with pytest.raises(ValueError, match=rf'^{name}: {value:g} is not one of .*{allowed}'):
        fxos8700.default_settings(**{name: value})


def test_wrong_identity_names_bus_address_and_value(fake_bus):
    value, _, _, g = fake_bus
    g.set_identity(0xD1)
    with pytest.raises(DeviceError, match=rf'{value} 0x21: WHO_AM_I \(0x0c\) reads 0xd1, '
                       r'expected 0xd7'):
        fxos8700.Fxos8700Chips(Bus(value, 0.05), fxos8700.default_settings(bus=value)).open()


def test_big_endian_14_bit_accel_and_si_values(fake_bus):
    value, _, am, g = fake_bus
    truth = Truth(np.array([0.4, 0.2, -0.3]), np.array([-G, 0.0, 0.0]),
                  np.array([2e-5, -1e-5, -4e-5]))
    am.set_truth(truth)
    g.set_truth(truth)
    chips = fxos8700.Fxos8700Chips(Bus(value, 0.05), fxos8700.default_settings(bus=value))
    chips.open()
    sample = wait_sample(chips, 3.0)
    word = int.from_bytes(am.registers[0x01:0x03], 'big', signed=True)
    assert word & 0x3 == 0                                   # left-justified 14 bits
    assert word >> 2 == pytest.approx(-1 / 0.488e-3, abs=60)  # -1 g at +-4 g
    np.testing.assert_allclose(sample.accel, truth.accel, atol=0.1)
    np.testing.assert_allclose(sample.gyro, truth.gyro, atol=0.05)
    np.testing.assert_allclose(sample.mag, truth.mag, atol=5e-6)


def test_check_device_and_command_line(capsys):
    lines = check_fxos8700(CheckTarget(bus='emulated'))
    assert 'WHO_AM_I 0xc7' in lines[0] and 'WHO_AM_I 0xd7' in lines[0]
    assert cli.main(['check-device', 'fxos8700', '--bus', 'emulated']) == 0
    assert 'FXOS8700CQ at' in capsys.readouterr().out
    assert cli.main(['check-device', 'fxos8700', '--bus', '98']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'i2c-98' in err[0]


def rig(context, executor, **kwargs):
    return Rig(context, executor, Fxos8700ImuNode, Fxos8700EmulatorNode, **kwargs)


def test_truth_reaches_imu_data_raw_in_flu(context, executor):
    r = rig(context, executor)
    rpy = (-0.2, math.pi / 2 - 0.1, -1.0)
    q = quat_from_euler(*rpy)
    f = quat_to_rotmat(q).T @ np.array([0.0, 0.0, G])
    omega = np.array([-0.3, 0.25, 0.5])
    r.truth(rpy, omega, f)
    n = len(r.raw)
    assert r.spin_until(lambda: len(r.raw) > n + 30)
    raws = r.raw[-15:]
    accel = np.mean([convert.vector3_to_array(m.linear_acceleration) for m in raws], axis=0)
    gyro = np.mean([convert.vector3_to_array(m.angular_velocity) for m in raws], axis=0)
    mags = np.mean([convert.vector3_to_array(m.magnetic_field) for m in r.mag[-15:]], axis=0)
    np.testing.assert_allclose(accel, f, atol=0.05)
    np.testing.assert_allclose(gyro, omega, atol=0.02)
    np.testing.assert_allclose(mags, quat_to_rotmat(q).T @ FIELD, atol=1e-6)
    assert r.raw[-1].orientation_covariance[0] == -1.0


def test_absent_then_present_and_unplugged_then_replugged(context, executor):
    r = rig(context, executor, emulator=False)
    assert not r.driver.connected and 'no i2c emulator' in r.driver.last_fault
    r.add_emulator()
    assert r.publishing()
    gyro = r.emulator.gyro
    r.bus.detach(0x21)
    assert r.spin_until(lambda: not r.driver.connected)
    assert '0x21' in r.driver.last_fault
    gyro.power_on()
    r.bus.attach(0x21, gyro)
    assert r.publishing()


def test_stall_and_stuck_data_ready_are_faults_then_resume(context, executor):
    r = rig(context, executor)
    assert r.publishing()
    r.bus.stall(0x1F, 4)
    assert r.spin_until(lambda: 'ETIMEDOUT' in r.driver.last_fault)
    assert r.publishing()
    r.emulator.accel_mag.data_ready_stuck = True
    assert r.spin_until(lambda: 'no new sample' in r.driver.last_fault)
    r.emulator.accel_mag.data_ready_stuck = False
    assert r.publishing()
