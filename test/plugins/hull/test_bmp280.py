"""BMP280 inside the hull: the protocol's numbers pinned to the data sheet (typed from it,
BST-BMP280-DS001), its worked example, the emulator's round trip, the driver against the
byte-level emulator (publishing, brown-out, bus faults, a wrong chip) and the simulated twin."""

from __future__ import annotations

import itertools

import pytest
from sensor_msgs.msg import FluidPressure, Temperature
from support.nodes import add, probe
from support.rov import overrides
from support.waiting import spin_until

from enbarr_core.framework.driver import ERROR
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.hull import bmp280_protocol as p
from enbarr_plugins.hull.bmp280 import Bmp280Node, Bmp280Settings, SPECS
from enbarr_plugins.hull.bmp280_emulator import Bmp280Chip
from enbarr_plugins.hull.sim import hull_air, SimHullNode, SimHullSettings
from enbarr_plugins.transport.i2c import FakeI2cBus

TIMEOUT = 10.0
_names = itertools.count()
#: The data sheet's worked example (3.12): trimming, raw values and results.
DIG_T = (27504, 26435, -1000)
DIG_P = (36477, -10685, 3024, 2855, 140, -7, 15500, -14600, 6000)
ADC_T, ADC_P = 519888, 415148


def example_trimming_bytes() -> bytes:
    """dig_T1..dig_P9 as the chip stores them from 0x88: 16-bit little-endian each."""
    out = b''
    for i, w in enumerate(DIG_T + DIG_P):
        out += w.to_bytes(2, 'little', signed=i not in (0, 3))   # T1 and P1 unsigned
    return out


# -- unit: the data sheet's numbers -----------------------------------------------------------
@pytest.mark.unit
def test_register_map_is_the_data_sheets():
    assert (p.CALIBRATION, p.CALIBRATION_LENGTH, p.CHIP_ID, p.RESET, p.RESET_WORD) == (
        0x88, 24, 0xD0, 0xE0, 0xB6)
    assert (p.STATUS, p.CTRL_MEAS, p.CONFIG, p.DATA, p.DATA_LENGTH) == (
        0xF3, 0xF4, 0xF5, 0xF7, 6)
    assert p.CHIP_IDS == {0x58: 'BMP280', 0x60: 'BME280'} and p.ADDRESSES == (0x76, 0x77)
    assert p.SKIPPED == 0x80000
    # ctrl_meas: osrs_t 7:5, osrs_p 4:2, mode 1:0 ("ultra high resolution": T x2, P x16)
    assert p.ctrl_meas(2, 16, p.MODE_NORMAL) == 0b010_101_11
    assert p.ctrl_meas(1, 0, p.MODE_FORCED) == 0b001_000_01
    # config: t_sb 7:5 (250 ms = 011), filter 4:2 (x4 = 010)
    assert p.config(250.0, 4) == 0b011_010_00 and p.config(4000.0, 16) == 0b111_100_00
    with pytest.raises(ValueError, match='osrs_p: 3'):
        p.ctrl_meas(1, 3, p.MODE_NORMAL)


@pytest.mark.unit
def test_measurement_time_is_the_tables():
    # Table "typical/maximum measurement time" (maxima): standard resolution (P x4, T x1)
    # 13.3 ms, ultra high resolution (P x16, T x2) 43.2 ms, ultra low power (x1, x1) 6.4 ms.
    assert p.measurement_time(1, 4) == pytest.approx(0.0133, abs=5e-5)
    assert p.measurement_time(2, 16) == pytest.approx(0.0432, abs=5e-5)
    assert p.measurement_time(1, 1) == pytest.approx(0.0064, abs=5e-5)


@pytest.mark.unit
def test_the_worked_example():
    cal = p.Calibration.from_bytes(example_trimming_bytes())
    assert cal.t == DIG_T and cal.p == DIG_P
    fine = p.t_fine(ADC_T, cal)
    assert fine == 128422
    assert p.temperature_centi(fine) == 2508                    # 25.08 degC
    # The sheet prints 25767236 (its floating-point result, 100653.27 Pa); the 64-bit integer
    # formula it publishes gives 25767233 when run, as other implementations also find.
    q = p.pressure_q24_8(ADC_P, fine, cal)
    assert q == 25767233
    assert q / 256.0 == pytest.approx(100653.27, abs=0.05)
    r = p.compensate(ADC_P, ADC_T, cal)
    assert r.temperature == pytest.approx(25.08) and r.pressure == pytest.approx(q / 256.0)
    assert p.compensate(p.SKIPPED, ADC_T, cal).pressure is None


@pytest.mark.unit
def test_raw_values_are_20_bits_msb_first():
    # 415148 = 0x655AC, 519888 = 0x7EED0: msb, lsb, xlsb in bits 7:4
    assert p.raw_values(bytes([0x65, 0x5A, 0xC0, 0x7E, 0xED, 0x00])) == (ADC_P, ADC_T)
    assert p.raw_values(bytes([0x80, 0x00, 0x00, 0x80, 0x00, 0x00])) == (p.SKIPPED, p.SKIPPED)


@pytest.mark.unit
def test_a_blank_trimming_is_refused():
    with pytest.raises(p.CalibrationError, match='dig_T1 or dig_P1 reads 0'):
        p.Calibration.from_bytes(bytes(24))
    with pytest.raises(p.CalibrationError, match='dig_T1 or dig_P1 reads 0'):
        p.Calibration.from_bytes(b'\xff' * 24)
    with pytest.raises(p.CalibrationError, match='expected 24 bytes'):
        p.Calibration.from_bytes(bytes(6))


@pytest.mark.unit
@pytest.mark.parametrize('pressure, temperature', [(101325.0, 25.0), (90000.0, -5.0),
                                                   (108000.0, 61.3), (100653.27, 25.08)])
def test_the_emulator_measures_the_truth_within_its_resolution(pressure, temperature):
    chip = Bmp280Chip(pressure=pressure, temperature=temperature)
    assert chip.read(p.CHIP_ID, 1) == b'\x58'
    assert chip.read(p.CALIBRATION, 24) == example_trimming_bytes()
    cal = p.Calibration.from_bytes(chip.read(p.CALIBRATION, 24))
    assert p.raw_values(chip.read(p.DATA, 6)) == (p.SKIPPED, p.SKIPPED)  # asleep since reset
    chip.write(p.CTRL_MEAS, bytes([p.ctrl_meas(2, 16, p.MODE_NORMAL)]))
    r = p.compensate(*p.raw_values(chip.read(p.DATA, 6)), cal)
    assert r.temperature == pytest.approx(temperature, abs=0.011)
    assert r.pressure == pytest.approx(pressure, abs=0.2)   # 20 bits: about 0.16 Pa a step
    chip.write(p.CTRL_MEAS, bytes([p.ctrl_meas(1, 1, p.MODE_NORMAL)]))
    coarse = p.compensate(*p.raw_values(chip.read(p.DATA, 6)), cal)
    assert coarse.pressure == pytest.approx(pressure, abs=3.0)   # 16 bits: about 2.6 Pa
    chip.write(p.RESET, bytes([p.RESET_WORD]))
    assert chip.read(p.CTRL_MEAS, 1) == b'\x00' and chip.resets == 1


@pytest.mark.unit
@pytest.mark.parametrize('name, value, text', [
    ('pressure_oversampling', 3, "pressure_oversampling: 3 is not one of the chip's"),
    ('temperature_oversampling', 0, "temperature_oversampling: 0 is not one of the chip's"),
    ('filter', 5, "filter: 5 is not one of the chip's"),
    ('standby', 300.0, "standby: 300 is not one of the chip's")])
def test_settings_name_the_bad_parameter(name, value, text):
    values = {s.name: s.default for s in SPECS}
    assert Bmp280Settings.from_params(values).ctrl_meas == 0b010_101_11
    with pytest.raises(ValueError, match=text):
        Bmp280Settings.from_params({**values, name: value})


@pytest.mark.unit
def test_the_simulated_hull_rises_and_heats_from_its_times():
    s = SimHullSettings(rate=2.0, pressure=101325.0, temperature=25.0, pressure_rise_at=10.0,
                        pressure_rise_rate=50.0, heat_at=-1.0, heat_rate=1.0,
                        pressure_noise=0.0, temperature_noise=0.0, seed=1)
    assert hull_air(s, 9.0) == (101325.0, 25.0)
    assert hull_air(s, 14.0) == (101325.0 + 200.0, 25.0)
    hot = SimHullSettings(**{**s.__dict__, 'heat_at': 0.0, 'heat_rate': 0.5})
    assert hull_air(hot, 20.0)[1] == pytest.approx(35.0)


@pytest.mark.unit
def test_check_device_reads_the_emulated_chip():
    from enbarr_plugins.check import CheckTarget
    from enbarr_plugins.hull.check import check_bmp280
    lines = check_bmp280(CheckTarget(bus='emulated'))
    assert lines[0].startswith('BMP280 at emulated') and 'ctrl_meas 0x57' in lines[0]
    assert 'dig_T 27504, 26435, -1000' in lines[0]
    assert float(lines[1].split()[1]) == pytest.approx(101325.0, abs=0.2)
    assert 'temperature 21.50 degC' in lines[1]


# -- node: the driver against the emulated chip ---------------------------------------------
@pytest.fixture
def rig():
    bus = FakeI2cBus()
    chip = Bmp280Chip(pressure=100500.0, temperature=31.0)
    bus.attach(0x77, chip)
    name = f'bmp280-test-{next(_names)}'
    emulation.register('i2c', name, bus)
    try:
        yield f'emulated:{name}', bus, chip
    finally:
        emulation.unregister('i2c', name)


def sensor(context, executor, bus_name, **extra):
    return add(executor, Bmp280Node(context=context, parameter_overrides=overrides(
        {'bus': bus_name, 'rate': 20.0, 'reconnect.initial_delay': 0.05,
         'reconnect.max_delay': 0.1, **extra})))


def listen(context, executor):
    got: dict[str, list] = {'p': [], 't': []}
    node = probe(context, executor)
    node.create_subscription(FluidPressure, topics.HULL_PRESSURE.name, got['p'].append,
                             topics.HULL_PRESSURE.qos)
    node.create_subscription(Temperature, topics.HULL_TEMPERATURE.name, got['t'].append,
                             topics.HULL_TEMPERATURE.qos)
    return got


@pytest.mark.node
def test_publishes_the_enclosures_pressure_and_temperature(context, executor, rig):
    value, bus, chip = rig
    node = sensor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert chip.ctrl_meas == 0x57 and chip.config == 0x68   # normal mode, 250 ms, filter 4
    assert spin_until(executor, lambda: len(got['p']) >= 2 and len(got['t']) >= 2, TIMEOUT)
    assert got['p'][-1].fluid_pressure == pytest.approx(100500.0, abs=0.2)
    assert got['p'][-1].variance == pytest.approx(1.3 ** 2)
    assert got['t'][-1].temperature == pytest.approx(31.0, abs=0.011)
    assert node.status_values()['chip'] == 'BMP280'
    chip.pressure, chip.temperature = 104000.0, 48.5
    n = len(got['t'])
    assert spin_until(executor, lambda: len(got['t']) > n + 1, TIMEOUT)
    assert got['p'][-1].fluid_pressure == pytest.approx(104000.0, abs=0.2)
    assert got['t'][-1].temperature == pytest.approx(48.5, abs=0.011)


@pytest.mark.node
def test_a_reset_chip_is_put_back_in_normal_mode_and_counted(context, executor, rig):
    value, bus, chip = rig
    node = sensor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert spin_until(executor, lambda: len(got['t']) >= 1, TIMEOUT)
    chip.write(p.RESET, bytes([p.RESET_WORD]))            # a supply dip: asleep, data 0x80000
    assert spin_until(executor, lambda: node.reconfigurations == 1 and chip.ctrl_meas == 0x57,
                      TIMEOUT)
    n = len(got['t'])
    assert spin_until(executor, lambda: len(got['t']) > n, TIMEOUT)
    assert all(m.temperature == pytest.approx(31.0, abs=0.011) for m in got['t'])


@pytest.mark.node
def test_a_bus_fault_is_counted_reported_and_recovered(context, executor, rig):
    value, bus, chip = rig
    node = sensor(context, executor, value)
    got = listen(context, executor)
    node.start()
    assert spin_until(executor, lambda: len(got['t']) >= 1, TIMEOUT)
    bus.detach(0x77)
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    level, message = node.status()
    assert level == ERROR and '0x77' in message
    bus.attach(0x77, chip)
    n = len(got['t'])
    assert spin_until(executor, lambda: node.connected and len(got['t']) > n, TIMEOUT)


@pytest.mark.node
def test_another_chip_at_the_address_is_named(context, executor, rig):
    value, bus, chip = rig
    chip.chip_id = 0x55
    node = sensor(context, executor, value)
    node.start()
    assert not node.connected
    assert 'not a BMP280: chip id 0x55 (a BMP280 reads 0x58, a BME280 0x60)' in node.last_fault


@pytest.mark.node
def test_a_chip_that_never_stays_in_normal_mode_is_a_fault(context, executor, rig):
    value, bus, chip = rig
    node = sensor(context, executor, value)
    node.start()
    assert node.connected
    chip.write(p.RESET, bytes([p.RESET_WORD]))
    chip.write = lambda register, data: None     # the chip now ignores every write
    assert spin_until(executor, lambda: node.faults >= 1, TIMEOUT)
    assert 'does not stay in normal mode' in node.last_fault and node.reconfigurations >= 4


@pytest.mark.node
def test_the_simulated_twin_publishes_the_same_topics(context, executor):
    twin = add(executor, SimHullNode(context=context, parameter_overrides=overrides(
        {'rate': 20.0, 'temperature': 40.0, 'pressure_noise': 0.0,
         'temperature_noise': 0.0})))
    got = listen(context, executor)
    twin.start()
    assert spin_until(executor, lambda: len(got['p']) >= 2 and len(got['t']) >= 2, TIMEOUT)
    assert got['p'][-1].fluid_pressure == 101325.0 and got['t'][-1].temperature == 40.0
