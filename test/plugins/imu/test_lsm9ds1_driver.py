"""LSM9DS1 driver against its register-level emulator: bytes, SI values in FLU, every fault."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from rclpy.parameter import Parameter

from enbarr_core.commands import main as cli
from enbarr_core.framework.driver import ERROR, OK
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_core.framework.kinematics import quat_from_euler, quat_to_rotmat
from enbarr_interfaces import convert
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu import lsm9ds1
from enbarr_plugins.imu.check import check_lsm9ds1, wait_sample
from enbarr_plugins.imu.chip_emulator import Truth
from enbarr_plugins.imu.common import Bus, G
from enbarr_plugins.imu.lsm9ds1 import Lsm9ds1ImuNode
from enbarr_plugins.imu.lsm9ds1_emulator import attach_lsm9ds1, Lsm9ds1EmulatorNode
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.imu import registered, Rig

TIMEOUT = 10.0
FIELD = np.array([0.0, 1.8e-5, -4.8e-5])


@pytest.fixture
def fake_bus():
    """A fake bus with an LSM9DS1, registered as emulated:<unique>; unregistered after."""
    bus = FakeI2cBus()
    ag, m = attach_lsm9ds1(bus)
    with registered(bus) as value:
        yield value, bus, ag, m


# -- unit: bytes and settings ---------------------------------------------------------------

def test_ranges_and_rates_go_to_the_data_sheet_registers(fake_bus):
    value, bus, _, _ = fake_bus
    s = lsm9ds1.default_settings(bus=value, odr=952.0, gyro_range=2000.0, accel_range=16.0,
                                 mag_odr=40.0, mag_range=12.0, rate=200.0)
    lsm9ds1.Lsm9ds1Chips(Bus(value, 0.05), s).open()
    writes = {(a, r): v for op, a, r, v in bus.log if op == 'write'}
    assert writes[(0x6B, 0x10)] == bytes([6 << 5 | 3 << 3])   # CTRL_REG1_G: 952 Hz, 2000 dps
    assert writes[(0x6B, 0x20)] == bytes([6 << 5 | 1 << 3])   # CTRL_REG6_XL: 952 Hz, 16 g
    assert writes[(0x6B, 0x22)] == bytes([0x44])              # CTRL_REG8: BDU + IF_ADD_INC
    assert writes[(0x1E, 0x20)] == bytes([0x60 | 6 << 2])     # CTRL_REG1_M: UHP, 40 Hz
    assert writes[(0x1E, 0x21)] == bytes([2 << 5])            # CTRL_REG2_M: 12 gauss
    assert writes[(0x1E, 0x22)] == bytes([0x00])              # CTRL_REG3_M: continuous
    reads = [(a, r) for op, a, r, _ in bus.log if op == 'read']
    assert reads[:2] == [(0x6B, 0x0F), (0x1E, 0x0F)]          # WHO_AM_Is first


@pytest.mark.parametrize('name, value, allowed', [
    ('odr', 300.0, '14.9, 59.5, 119, 238, 476, 952'),
    ('gyro_range', 1000.0, '245, 500, 2000'),
    ('accel_range', 6.0, '2, 4, 8, 16'),
    ('mag_odr', 100.0, '0.625, 1.25'),
    ('mag_range', 2.0, '4, 8, 12, 16'),
])
def test_a_value_the_chip_lacks_is_refused_naming_parameter_and_set(name, value, allowed):
    with pytest.raises(ValueError, match=rf'^{name}: {value:g} is not one of .*{allowed}'):
        lsm9ds1.default_settings(**{name: value})


def test_bad_bus_and_rate_name_the_parameter():
    with pytest.raises(ValueError, match='^bus: '):
        lsm9ds1.default_settings(bus='i2c one')
    with pytest.raises(ValueError, match='^rate: 400 Hz polls faster'):
        lsm9ds1.default_settings(rate=400.0, odr=238.0)


def test_wrong_identity_names_bus_address_and_value(fake_bus):
    value, _, ag, _ = fake_bus
    ag.set_identity(0x69)
    with pytest.raises(DeviceError, match=rf'{value} 0x6b: WHO_AM_I \(0x0f\) reads 0x69, '
                       r'expected 0x68'):
        lsm9ds1.Lsm9ds1Chips(Bus(value, 0.05), lsm9ds1.default_settings(bus=value)).open()


def test_registers_hold_chip_axes_and_the_driver_returns_flu(fake_bus):
    """Nose down 90 deg: the specific force is on -x; the magnetometer's X is reversed."""
    value, _, ag, m = fake_bus
    s = lsm9ds1.default_settings(bus=value)
    truth = Truth(np.array([0.5, -0.25, 0.125]), np.array([-G, 0.0, 0.0]),
                  np.array([3e-5, 1e-5, -2e-5]))
    ag.set_truth(truth)
    m.set_truth(truth)
    chips = lsm9ds1.Lsm9ds1Chips(Bus(value, 0.05), s)
    chips.open()
    sample = wait_sample(chips, 2.0)
    accel_x = int.from_bytes(ag.registers[0x28:0x2A], 'little', signed=True)
    assert accel_x == pytest.approx(-G / (0.122e-3 * G), abs=200)  # chip X register, LSB
    mag_x = int.from_bytes(m.registers[0x28:0x2A], 'little', signed=True)
    assert mag_x == pytest.approx(-3e-5 / 1.4e-8, abs=100)         # chip mag X = -FLU x
    np.testing.assert_allclose(sample.accel, truth.accel, atol=0.1)
    np.testing.assert_allclose(sample.gyro, truth.gyro, atol=0.02)
    np.testing.assert_allclose(sample.mag, truth.mag, atol=3e-6)


def test_magnetometer_bursts_need_the_sub_address_msb(fake_bus):
    value, _, _, m = fake_bus
    m.registers[0x28:0x2E] = bytes([1, 2, 3, 4, 5, 6])
    assert m.read(0x28, 3) == bytes([1, 1, 1])                 # no MSB: one register again
    assert m.read(0x28 | 0x80, 3) == bytes([1, 2, 3])


def test_check_device_against_the_emulator_and_an_absent_bus():
    lines = check_lsm9ds1(CheckTarget(bus='emulated'))
    assert 'WHO_AM_I 0x68' in lines[0] and 'WHO_AM_I 0x3d' in lines[0]
    assert any(line.startswith('accel [m/s^2] (FLU):') for line in lines)
    with pytest.raises(DeviceError, match='i2c-97'):
        check_lsm9ds1(CheckTarget(bus='97'))


def test_check_device_command_line(capsys):
    assert cli.main(['check-device', 'lsm9ds1', '--bus', 'emulated']) == 0
    assert 'LSM9DS1 accel/gyro at' in capsys.readouterr().out
    assert cli.main(['check-device', 'lsm9ds1', '--bus', '97']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'i2c-97' in err[0]


# -- node: driver + emulator ----------------------------------------------------------------

def test_truth_reaches_imu_data_raw_in_flu_with_covariances(context, executor):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode)
    rpy = (0.1, math.pi / 2 - 0.05, 0.7)  # pitched nose down
    q = quat_from_euler(*rpy)
    f = quat_to_rotmat(q).T @ np.array([0.0, 0.0, G])   # specific force at rest, imu_link
    omega = np.array([0.3, -0.2, 0.1])
    rig.truth(rpy, omega, f)
    assert f[0] < -9.0                                   # the reaction to gravity is on -x
    n = len(rig.raw)
    assert rig.spin_until(lambda: len(rig.raw) > n + 20 and len(rig.mag) > 5)
    raws = rig.raw[-10:]
    accel = np.mean([convert.vector3_to_array(m.linear_acceleration) for m in raws], axis=0)
    gyro = np.mean([convert.vector3_to_array(m.angular_velocity) for m in raws], axis=0)
    mag = convert.vector3_to_array(rig.mag[-1].magnetic_field)
    np.testing.assert_allclose(accel, f, atol=0.05)
    np.testing.assert_allclose(gyro, omega, atol=0.01)
    np.testing.assert_allclose(mag, quat_to_rotmat(q).T @ FIELD, atol=3e-6)
    last = rig.raw[-1]
    assert last.header.frame_id == 'imu_link' and last.orientation_covariance[0] == -1.0
    sigma_g = 0.015 * math.pi / 180 * math.sqrt(238 / 2)
    assert last.angular_velocity_covariance[0] == pytest.approx(sigma_g ** 2)
    assert last.linear_acceleration_covariance[8] > 0.0
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in rig.raw[-20:]]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert rig.driver.status()[0] == OK


def test_absent_at_start_reported_then_found_when_the_emulator_comes(context, executor):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode, emulator=False)
    assert not rig.driver.connected and rig.driver.faults == 1
    assert 'no i2c emulator named' in rig.driver.last_fault
    assert rig.driver.status()[0] == ERROR
    rig.add_emulator()
    assert rig.publishing()
    assert rig.driver.connected


def test_unplugged_and_replugged_reconfigures_and_resumes(context, executor):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode)
    assert rig.publishing()
    ag = rig.emulator.accel_gyro
    rig.bus.detach(0x6B)
    assert rig.spin_until(lambda: not rig.driver.connected)
    assert f'{rig.driver.settings.bus} 0x6b' in rig.driver.last_fault
    assert 'EREMOTEIO' in rig.driver.last_fault
    ag.power_on()                       # the replugged chip has lost its configuration
    rig.bus.attach(0x6B, ag)
    assert rig.publishing()
    assert ag.registers[0x10] == 4 << 5 | 1 << 3   # configured again (238 Hz, 500 dps)


def test_a_stalled_bus_is_a_fault_and_the_driver_resumes(context, executor):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode)
    assert rig.publishing()
    rig.bus.stall(0x6B, 4)
    assert rig.spin_until(lambda: rig.driver.faults >= 1)
    assert 'ETIMEDOUT' in rig.driver.last_fault
    assert rig.publishing() and rig.driver.connected


def test_wrong_identity_at_start_then_the_right_chip(context, executor):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode)
    assert rig.publishing()
    rig.emulator.magnetometer.set_identity(0x40)
    rig.bus.nack(0x6B, 2)                    # a glitch makes the driver open it again
    assert rig.spin_until(lambda: 'WHO_AM_I' in rig.driver.last_fault)
    assert '0x1e: WHO_AM_I (0x0f) reads 0x40, expected 0x3d' in rig.driver.last_fault
    assert not rig.driver.connected
    rig.emulator.magnetometer.set_identity(0x3D)
    assert rig.publishing()


@pytest.mark.parametrize('fault, message', [
    ('data_ready_stuck', 'no new sample for .* data-ready clear'),   # stale: reconfigure
    ('corrupt', 'corrupted reads in a row'),                        # SDA stuck high
    ('truncate', 'expected 23 bytes, got 22'),                      # a burst one byte short
])
def test_a_chip_fault_is_a_device_fault_then_the_driver_resumes(context, executor, fault,
                                                                 message):
    rig = Rig(context, executor, Lsm9ds1ImuNode, Lsm9ds1EmulatorNode)
    assert rig.publishing()
    setattr(rig.emulator.accel_gyro, fault, True)
    assert rig.spin_until(lambda: re.search(message, rig.driver.last_fault) is not None)
    if fault == 'corrupt':
        assert rig.driver.corrupted >= 5                            # dropped and counted
    setattr(rig.emulator.accel_gyro, fault, False)
    assert rig.publishing()


def test_a_bad_parameter_is_a_clear_error(context):
    with pytest.raises(ConfigurationError, match='odr: 300 is not one of') as info:
        lsm9ds1.Lsm9ds1ImuNode(context=context, parameter_overrides=[
            Parameter('odr', value=300.0), Parameter('bus', value='emulated:none')])
    assert info.value.parameter == 'odr'
