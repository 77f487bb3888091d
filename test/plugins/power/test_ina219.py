"""INA219 battery monitor: protocol numbers pinned to the data sheet, the driver against the
byte-level emulator (truth round trip, brown-out, bus faults) and the node on an executor."""

from __future__ import annotations

import itertools
import math

import pytest
from sensor_msgs.msg import BatteryState
from support.nodes import add, probe
from support.rov import overrides
from support.waiting import spin_until

from enbarr_core.framework.driver import ERROR
from enbarr_core.framework.errors import DeviceError
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.power import ina219_protocol as p
from enbarr_plugins.power.ina219 import Ina219Node, percentage
from enbarr_plugins.power.ina219_emulator import Ina219Chip, Ina219EmulatorNode
from enbarr_plugins.transport.i2c import FakeI2cBus

TIMEOUT = 10.0
_names = itertools.count()


# -- unit: the data sheet's numbers, typed from it (TI SBOS448; Adafruit's INA219 driver) ----
@pytest.mark.unit
def test_register_map_and_scales_are_the_data_sheets():
    assert (p.CONFIG, p.SHUNT_VOLTAGE, p.BUS_VOLTAGE, p.POWER, p.CURRENT, p.CALIBRATION) == (
        0x00, 0x01, 0x02, 0x03, 0x04, 0x05)
    assert p.ADDRESS == 0x40
    # BRNG 32 V | PGA /8 320 mV | BADC 12 bit | SADC 12 bit 1 sample | shunt+bus continuous:
    # the data sheet's power-on reset value of the configuration register.
    assert p.CONFIG_32V_320MV_12BIT == 0x399F
    assert p.CONFIG_RESET == 0x8000
    assert p.SHUNT_LSB == 10e-6 and p.BUS_LSB == 4e-3 and p.POWER_LSB_FACTOR == 20


@pytest.mark.unit
def test_calibration_is_the_data_sheets_formula():
    # Adafruit's worked examples with a 0.1 ohm shunt: 100 uA -> 4096, 40 uA -> 10240,
    # 50 uA -> 8192.
    assert p.calibration(0.0001, 0.1) == 4096
    assert p.calibration(0.00004, 0.1) == 10240
    assert p.calibration(0.00005, 0.1) == 8192
    assert p.calibration(0.001, 0.001) == 40960      # a 1 mOhm power module, 1 mA steps
    assert p.calibration(0.0003, 0.1) == 1364        # trunc(1365.33), bit 0 cleared
    assert p.calibration(0.00011, 0.1) == 3722       # trunc(3723.64), not rounded to 3724
    with pytest.raises(ValueError, match='calibration'):
        p.calibration(1e-6, 0.0001)


@pytest.mark.unit
def test_bus_voltage_drops_the_status_bits():
    # 12.000 V = 3000 steps of 4 mV, in bits 15..3, CNVR set.
    decoded = p.bus_voltage((3000 << 3) | 0x2)
    assert decoded.volts == pytest.approx(12.0) and decoded.ready and not decoded.overflow
    assert p.bus_voltage(0x5DC1).volts == pytest.approx(0x5DC1 // 8 * 0.004)
    assert p.bus_voltage(0x0001).overflow
    assert p.current(0xFFFF, 0.0001) == pytest.approx(-0.0001)
    assert p.shunt_voltage(0x7D00) == pytest.approx(0.32)


@pytest.mark.unit
def test_percentage_is_straight_per_cell_and_nan_without_cells():
    assert math.isnan(percentage(12.0, 0, 3.3, 4.2))
    assert percentage(4 * 3.75, 4, 3.3, 4.2) == pytest.approx(0.5)
    assert percentage(20.0, 4, 3.3, 4.2) == 1.0 and percentage(10.0, 4, 3.3, 4.2) == 0.0


# -- node: the driver against the emulated chip ---------------------------------------------
@pytest.fixture
def rig():
    bus = FakeI2cBus()
    chip = Ina219Chip(shunt=0.1, volts=14.8, amps=1.5)
    bus.attach(0x40, chip)
    name = f'ina219-test-{next(_names)}'
    emulation.register('i2c', name, bus)
    try:
        yield f'emulated:{name}', bus, chip
    finally:
        emulation.unregister('i2c', name)


def monitor(context, executor, bus_name, **extra):
    node = add(executor, Ina219Node(context=context, parameter_overrides=overrides(
        {'bus': bus_name, 'rate': 20.0, 'cells': 4, 'reconnect.initial_delay': 0.05,
         'reconnect.max_delay': 0.1, **extra})))
    return node


def listen(context, executor):
    got: list[BatteryState] = []
    probe(context, executor).create_subscription(
        BatteryState, topics.BATTERY.name, got.append, topics.BATTERY.qos)
    return got


@pytest.mark.node
def test_publishes_the_true_voltage_and_current(context, executor, rig):
    value, bus, chip = rig
    node = monitor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert chip.calibration == 4096 and chip.config == 0x399F
    assert spin_until(executor, lambda: len(got) >= 2, TIMEOUT)
    m = got[-1]
    assert m.voltage == pytest.approx(14.8, abs=0.004)
    assert m.current == pytest.approx(-1.5, abs=0.0002)        # discharging: negative
    assert m.percentage == pytest.approx((14.8 / 4 - 3.3) / 0.9, abs=0.01)
    assert math.isnan(m.temperature) and m.present
    chip.volts, chip.amps = 12.0, 0.25
    n = len(got)
    assert spin_until(executor, lambda: len(got) > n + 1, TIMEOUT)
    assert got[-1].voltage == pytest.approx(12.0, abs=0.004)
    assert got[-1].current == pytest.approx(-0.25, abs=0.0002)


@pytest.mark.node
def test_a_brown_out_is_recalibrated_and_counted(context, executor, rig):
    value, bus, chip = rig
    node = monitor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert spin_until(executor, lambda: len(got) >= 1, TIMEOUT)
    chip.brown_out()
    assert spin_until(executor, lambda: node.recalibrations == 1 and chip.calibration == 4096,
                      TIMEOUT)
    n = len(got)
    assert spin_until(executor, lambda: len(got) > n, TIMEOUT)
    assert all(m.current == pytest.approx(-1.5, abs=0.0002) for m in got)  # never a 0 read


@pytest.mark.node
def test_a_bus_fault_is_counted_reported_and_recovered(context, executor, rig):
    value, bus, chip = rig
    node = monitor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert spin_until(executor, lambda: len(got) >= 1, TIMEOUT)
    bus.detach(0x40)
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    level, message = node.status()
    assert level == ERROR and '0x40' in message
    bus.attach(0x40, chip)
    n = len(got)
    assert spin_until(executor, lambda: node.connected and len(got) > n, TIMEOUT)


@pytest.mark.node
def test_no_chip_is_a_clear_error(context, executor, rig):
    value, bus, chip = rig
    bus.detach(0x40)
    node = monitor(context, executor, value)
    node.start()
    assert not node.connected and 'no INA219 answers' in node.last_fault


@pytest.mark.node
def test_the_emulator_node_serves_the_driver_on_a_named_bus(context, executor):
    name = f'ina219-node-{next(_names)}'
    emulator = add(executor, Ina219EmulatorNode(context=context, parameter_overrides=overrides(
        {'name': name, 'volts': 11.1, 'amps': 2.0})))
    emulator.start()
    node = monitor(context, executor, f'emulated:{name}', cells=3)
    got = listen(context, executor)
    node.start()
    assert spin_until(executor, lambda: len(got) >= 1, TIMEOUT)
    assert got[-1].voltage == pytest.approx(11.1, abs=0.004)
    assert got[-1].current == pytest.approx(-2.0, abs=0.0002)
    for n in (node, emulator):
        executor.remove_node(n)
        n.destroy_node()
    with pytest.raises(DeviceError):
        emulation.lookup('i2c', f'emulated:{name}')  # the bus is withdrawn with its chip


@pytest.mark.node
def test_a_calibration_that_never_holds_is_a_fault(context, executor, rig):
    value, bus, chip = rig
    node = monitor(context, executor, value)
    node.start()
    assert node.connected
    chip.write = lambda register, data: None     # the chip now ignores every write
    chip.brown_out()
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    assert 'calibration does not hold' in node.last_fault and node.recalibrations >= 4


@pytest.mark.unit
def test_check_device_reads_the_emulated_chip_without_writing():
    from enbarr_plugins.check import CheckTarget
    from enbarr_plugins.power.check import check_ina219
    lines = check_ina219(CheckTarget(bus='emulated'))
    # The power-on configuration, calibration 0 (nothing written), 14.8 V, 1 A x 0.1 ohm.
    assert lines == ['INA219 at emulated:' + lines[0].split('emulated:')[1].split(' ')[0]
                     + ' 0x40: configuration 0x399f, calibration 0 (not set: current and '
                     'power read 0)', 'bus 14.800 V, shunt 100.00 mV']
