"""MS5837-30BA driver against its byte-level emulator: the truth round trip, timing, faults."""

from __future__ import annotations

import itertools

import pytest
from rclpy.parameter import Parameter

from enbarr_core.framework.driver import ERROR, OK
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.imu.common import Bus
from enbarr_plugins.pressure import ms5837
from enbarr_plugins.pressure.check import check_ms5837
from enbarr_plugins.pressure.ms5837_emulator import attach_ms5837
from enbarr_plugins.pressure.ms5837_protocol import compensate
from enbarr_plugins.transport.i2c import FakeI2cBus
from support.devices import diagnostics_of
from support.waiting import spin_until

TIMEOUT = 10.0
_names = itertools.count()


@pytest.fixture
def rig():
    """A fake bus with an emulated MS5837 registered as emulated:<unique>."""
    bus = FakeI2cBus()
    chip = attach_ms5837(bus, pressure=200000.0, temperature=12.5)
    name = f'ms5837-test-{next(_names)}'
    emulation.register('i2c', name, bus)
    try:
        yield f'emulated:{name}', bus, chip
    finally:
        emulation.unregister('i2c', name)


# -- unit: the driver's device code on the fake bus -----------------------------------------

@pytest.mark.parametrize('osr', [256, 512, 1024, 2048, 4096])
def test_driver_reads_the_truth_at_every_osr_and_never_early(rig, osr):
    value, bus, chip = rig
    dev = ms5837.Ms5837Device(Bus(value, 0.05).device(0x76), osr)
    cal = dev.open()
    assert cal.coefficients == (34982, 36352, 20328, 22354, 26646, 26146)
    for pressure, temperature in ((200000.0, 12.5), (101325.0, 22.0), (2_900_000.0, 2.0)):
        chip.pressure, chip.temperature = pressure, temperature
        d2 = dev.convert(d1=False)
        d1 = dev.convert(d1=True)
        r = compensate(cal, d1, d2)
        assert abs(r.pressure_pa - pressure) <= 10.0       # 0.1 mbar steps
        assert abs(r.temperature_c - temperature) <= 0.01
    assert chip.early_reads == 0 and chip.protocol_errors == 0
    # The bytes: reset, 7 PROM reads, then D2 and D1 commands with this OSR's offset.
    commands = [(op, reg) for op, _, reg, _ in bus.log]
    offset = {256: 0, 512: 2, 1024: 4, 2048: 6, 4096: 8}[osr]
    assert commands[:8] == [('write', 0x1E)] + [('read', 0xA0 + 2 * i) for i in range(7)]
    assert commands[8:12] == [('write', 0x50 + offset), ('read', 0x00),
                              ('write', 0x40 + offset), ('read', 0x00)]


def test_prom_crc_mismatch_at_open_is_a_device_error_naming_bus_and_address(rig):
    value, _, chip = rig
    chip.prom[2] ^= 0x0040
    dev = ms5837.Ms5837Device(Bus(value, 0.05).device(0x76), 4096)
    with pytest.raises(DeviceError, match=rf'^{value} 0x76: PROM CRC-4 mismatch: .*PROM read: '
                                          r'0x9340 0x88a6 0x8e40'):
        dev.open()


def test_settings_refuse_osr_8192_and_a_rate_too_fast_for_the_conversions():
    base = {spec.name: spec.default for spec in ms5837.SPECS}
    with pytest.raises(ValueError, match='^osr: 8192 is not one'):
        ms5837.Ms5837Settings.from_params({**base, 'osr': 8192})
    # OSR 4096: two conversions of 9 ms waited, at most 55 samples a second.
    with pytest.raises(ValueError, match='^rate: 60 Hz is faster'):
        ms5837.Ms5837Settings.from_params({**base, 'rate': 60.0})
    assert ms5837.Ms5837Settings.from_params({**base, 'rate': 55.0}).rate == 55.0


def test_check_device_against_the_emulator():
    lines = check_ms5837(CheckTarget(bus='emulated'))
    assert 'PROM CRC ok, C1..C6 34982, 36352, 20328, 22354, 26646, 26146' in lines[0]
    assert lines[1].startswith('pressure 101320 Pa (1013.2 mbar), temperature 20.00 degC')


# -- node: publishing, faults ---------------------------------------------------------------

def make_node(context, executor, value, **params):
    overrides = {'bus': value, 'rate': 20.0, 'reconnect.initial_delay': 0.05,
                 'reconnect.max_delay': 0.2}
    overrides.update(params)
    node = ms5837.Ms5837Node(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in overrides.items()])
    executor.add_node(node)
    return node


def test_node_publishes_pressure_temperature_and_depth(context, executor, rig):
    value, _, chip = rig
    probe = EnbarrNode('probe', context=context)
    executor.add_node(probe)
    got: dict[str, list] = {'p': [], 't': [], 'd': []}
    probe.create_topic_subscription(topics.PRESSURE, got['p'].append)
    probe.create_topic_subscription(topics.PRESSURE_TEMPERATURE, got['t'].append)
    probe.create_topic_subscription(topics.DEPTH, got['d'].append)
    node = make_node(context, executor, value, fluid_density=1029.0)
    node.start()
    assert node.connected
    assert spin_until(executor, lambda: len(got['d']) >= 2, TIMEOUT)
    p, t, d = got['p'][-1], got['t'][-1], got['d'][-1]
    assert p.fluid_pressure == pytest.approx(200000.0, abs=10.0)
    assert p.header.frame_id == 'pressure_link'
    assert t.temperature == pytest.approx(12.5, abs=0.01)
    # (200000 - 101325) / (1029 * 9.80665) = 9.77841 m in salt water.
    assert d.pose.pose.position.z == pytest.approx(-9.77841, abs=0.002)
    assert d.header.frame_id == 'odom'
    assert d.pose.covariance[14] == pytest.approx(0.002 ** 2)
    assert chip.early_reads == 0
    # Re-zero: surface_pressure 0 takes the next reading as the surface.
    node.set_parameters([Parameter('surface_pressure', value=0.0)])
    n = len(got['d'])
    assert spin_until(executor, lambda: len(got['d']) >= n + 2, TIMEOUT)
    assert got['d'][-1].pose.pose.position.z == pytest.approx(0.0, abs=0.002)
    chip.pressure = 200000.0 + 1029.0 * 9.80665   # one metre deeper
    n = len(got['d'])
    assert spin_until(executor, lambda: len(got['d']) >= n + 3, TIMEOUT)
    assert got['d'][-1].pose.pose.position.z == pytest.approx(-1.0, abs=0.002)


def test_absent_device_at_start_names_bus_and_address(context, executor, rig):
    value, bus, _ = rig
    bus.detach(0x76)
    node = make_node(context, executor, value)
    node.start()
    assert not node.connected
    assert node.last_fault.startswith(f'{value} 0x76: no MS5837-30BA answers: command 0x1e ')
    assert 'EREMOTEIO' in node.last_fault


def test_bus_fault_at_run_time_is_counted_reported_and_recovered(context, executor, rig):
    value, bus, chip = rig
    probe = EnbarrNode('probe', context=context)
    executor.add_node(probe)
    diag = diagnostics_of(probe, 'depth_sensor')
    pressures: list = []
    probe.create_topic_subscription(topics.PRESSURE, pressures.append)
    node = make_node(context, executor, value)
    node.start()
    assert spin_until(executor, lambda: len(pressures) >= 2, TIMEOUT)
    bus.detach(0x76)     # unplugged: every transfer NACKs until it is back
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    assert spin_until(executor, lambda: any(s.level == bytes([ERROR]) for s in diag), TIMEOUT)
    fault = next(s for s in diag if s.level == bytes([ERROR]))
    assert f'{value} 0x76' in fault.message and 'EREMOTEIO' in fault.message
    bus.attach(0x76, chip)
    n = len(pressures)
    assert spin_until(executor, lambda: len(pressures) >= n + 2 and node.connected, TIMEOUT)
    assert spin_until(executor, lambda: diag[-1].level == bytes([OK]), TIMEOUT)
    assert chip.resets >= 2   # the reopen reset the chip and read its PROM again


def test_emulator_node_feeds_the_simulated_depth_to_the_driver(context, executor):
    from enbarr_interfaces.links import LinkBus
    from enbarr_plugins.pressure.ms5837_emulator import Ms5837EmulatorNode
    from nav_msgs.msg import Odometry
    name = f'ms5837-node-{next(_names)}'
    emulator = Ms5837EmulatorNode(context=context, parameter_overrides=[
        Parameter('name', value=name), Parameter('water_density', value=1029.0),
        Parameter('pressure_noise', value=0.0)])
    executor.add_node(emulator)
    emulator.start()
    probe = EnbarrNode('simulator', context=context)
    executor.add_node(probe)
    truth = probe.create_topic_publisher(topics.SIM_ODOMETRY)
    depths: list = []
    probe.create_topic_subscription(topics.DEPTH, depths.append)
    LinkBus.of(context).connect()
    msg = Odometry()
    msg.pose.pose.position.z = -4.0
    truth.publish(msg)
    node = make_node(context, executor, f'emulated:{name}', fluid_density=1029.0)
    node.start()
    assert node.connected
    assert spin_until(executor, lambda: len(depths) >= 2, TIMEOUT)
    # 4 m of salt water, the sensor told the same density: 4 m within a 10 Pa step (1 mm).
    assert depths[-1].pose.pose.position.z == pytest.approx(-4.0, abs=0.0015)
    assert emulator.chip.early_reads == 0
    node.stop()
    executor.remove_node(emulator)
    emulator.destroy_node()   # unplugged, and the bus withdrawn: nothing else sat on it
    with pytest.raises(DeviceError):
        emulation.lookup('i2c', f'emulated:{name}')


def test_lost_conversions_are_dropped_counted_and_a_fault_when_they_persist(context, executor,
                                                                             rig):
    value, _, chip = rig
    node = make_node(context, executor, value)
    node.start()
    assert spin_until(executor, lambda: node.samples >= 2, TIMEOUT)
    chip.lose_conversions = True     # ADC reads 0: no sample may be published from them
    n = node.samples
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    assert node.samples == n
    assert node.zero_reads >= 5
    assert 'ADC reads of 0 in a row' in node.last_fault and f'{value} 0x76' in node.last_fault
    chip.lose_conversions = False
    assert spin_until(executor, lambda: node.samples >= n + 2 and node.connected, TIMEOUT)
