"""Unit tests: PCA9685 register arithmetic, the emulated chip's data-sheet semantics, the ESC
model, the driver's chip class over the fake bus, and ``enbarr check-device pca9685``.
"""

from __future__ import annotations

import time

import pytest

from enbarr_core.commands.main import main
from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.thrusters import pca9685 as pca
from enbarr_plugins.thrusters import pca9685_protocol as proto
from enbarr_plugins.thrusters.check import check_pca9685
from enbarr_plugins.thrusters.pca9685_emulator import (
    EscModel, EscSpec, Pca9685Emulator, WrongDevice)
from enbarr_plugins.transport.i2c import FakeI2cBus, I2cDevice


@pytest.mark.parametrize('frequency, prescale', [(50.0, 121), (400.0, 14), (200.0, 30),
                                                 (1526.0, 3), (24.0, 253)])
def test_prescale_follows_equation_1_of_the_data_sheet(frequency, prescale):
    assert proto.prescale_for(frequency) == prescale
    # The power-on value 0x1E is 200 Hz (data sheet 7.3.5).
    assert proto.prescale_for(200.0) == 0x1E


def test_prescale_outside_3_255_is_refused():
    with pytest.raises(ValueError, match='frequency: 2000'):
        proto.prescale_for(2000.0)
    with pytest.raises(ValueError, match='frequency: 20'):
        proto.prescale_for(20.0)


def test_pulse_counts_round_trip():
    assert proto.counts_for(1500.0, 121) == round(1500.0 / (122 / 25.0))
    assert proto.pulse_of(proto.counts_for(1500.0, 121), 121) == pytest.approx(1500.0, abs=2.5)
    assert proto.channel_bytes(307) == bytes([0, 0, 307 & 0xFF, 1])
    assert proto.channel_bytes(None) == bytes([0, 0, 0, 0x10])


def test_pulse_calibration_dead_band_and_reversal():
    p = pca.Pulse(1500.0, 1100.0, 1900.0, 25.0, False)
    assert p.width(0.0) == 1500.0
    assert p.width(1.0) == 1900.0 and p.width(-1.0) == 1100.0
    assert p.width(1e-6) == pytest.approx(1525.0) and p.width(-1e-6) == pytest.approx(1475.0)
    assert p.width(0.5) == pytest.approx(1712.5)
    r = pca.Pulse(1500.0, 1100.0, 1900.0, 0.0, True)
    assert r.width(1.0) == 1100.0 and r.width(-0.5) == 1700.0


# -- the emulated chip --------------------------------------------------------------------------

def chip_on_bus() -> tuple[Pca9685Emulator, I2cDevice]:
    bus = FakeI2cBus()
    chip = bus.attach(0x40, Pca9685Emulator())
    return chip, I2cDevice(bus, 0x40, bus_name='fake')


def test_power_on_state():
    chip, dev = chip_on_bus()
    assert dev.read_u8(0x00) == 0x11 and dev.read_u8(0x01) == 0x04 and dev.read_u8(0xFE) == 0x1E
    assert dev.read_u8(0x09) == 0x10           # LED0 full off
    assert chip.pulse_us(0) == 0.0             # asleep: no pulse


def test_prescale_is_written_only_while_asleep():
    chip, dev = chip_on_bus()
    dev.write_u8(0xFE, 121)                    # asleep at power-on: taken
    dev.write_u8(0x00, 0x20)                   # wake
    dev.write_u8(0xFE, 30)                     # awake: ignored
    assert dev.read_u8(0xFE) == 121 and chip.prescale_blocked == 1


def test_auto_increment_and_its_wrap():
    chip, dev = chip_on_bus()
    dev.write_u8(0x00, 0x10)                   # AI off
    dev.write_block(0x06, bytes([1, 2, 3]))    # all three bytes go to 0x06
    assert dev.read_block(0x06, 3) == bytes([3, 3, 3])   # AI off: reads repeat too
    dev.write_u8(0x00, 0x30)                   # AI on
    dev.write_block(0x06, bytes([1, 2, 3]))
    assert dev.read_block(0x06, 3) == bytes([1, 2, 3])
    dev.write_block(0x44, bytes([7, 8, 0x31]))   # 0x44, 0x45, then MODE1 (wrap)
    assert dev.read_u8(0x45) == 8 and dev.read_u8(0x00) == 0x31


def test_all_led_registers_load_every_channel_and_read_zero():
    chip, dev = chip_on_bus()
    dev.write_u8(0x00, 0x30)                   # AI on
    dev.write_block(0xFA, bytes([0, 0, 0x33, 0x01]))
    assert all(dev.read_block(0x06 + 4 * c, 4) == bytes([0, 0, 0x33, 0x01]) for c in range(16))
    assert dev.read_block(0xFA, 4) == bytes(4)


def test_pulse_decoding_full_on_full_off_and_the_restart_rule():
    chip, dev = chip_on_bus()
    now = [0]
    chip.clock = lambda: now[0]
    dev.write_u8(0x00, 0x30)
    dev.write_u8(0xFE, 121)
    dev.write_block(0x06, bytes([0x10, 0, 0x45, 0x01]))    # ON 16, OFF 325: 309 counts
    dev.write_u8(0x00, 0x20)                                # wake
    assert chip.pulse_us(0) == 0.0                          # oscillator starting
    now[0] += 500_000
    assert chip.pulse_us(0) == pytest.approx(309 * 122 / 25.0)
    dev.write_u8(0x07, 0x10)                                # full on: no pulse
    assert chip.pulse_us(0) == 0.0
    dev.write_block(0x06, bytes([0, 0x10, 0x45, 0x11]))    # full off wins over full on
    assert chip.pulse_us(0) == 0.0
    dev.write_block(0x06, bytes([0, 0, 0x45, 0x01]))
    assert chip.pulse_us(0) > 0.0
    dev.write_u8(0x00, 0x30)                                # sleep while running
    assert dev.read_u8(0x00) == 0xB0                        # RESTART set (7.3.1.1)
    dev.write_u8(0x00, 0x20)                                # wake: outputs still stopped
    now[0] += 100_000
    dev.write_u8(0x00, 0xA0)                                # RESTART too early: ignored
    assert chip.early_restart == 1 and dev.read_u8(0x00) == 0xA0
    now[0] += 500_000
    assert chip.pulse_us(0) == 0.0
    dev.write_u8(0x00, 0xA0)                                # RESTART after 500 us
    assert dev.read_u8(0x00) == 0x20 and chip.pulse_us(0) == pytest.approx(325 * 122 / 25.0)


def test_driver_chip_opens_the_emulator_and_refuses_a_wrong_device():
    chip, dev = chip_on_bus()
    driver = pca.Pca9685(dev)
    state = driver.open(50.0, {0: 307, 2: 400})
    assert state['prescale'] == 121 and state['mode1_before'] == 0x11
    time.sleep(proto.WAKE_DELAY * 2)
    assert chip.pulse_us(0) == pytest.approx(307 * 122 / 25.0)
    assert chip.pulse_us(1) == 0.0                          # unmapped: full off
    driver.verify()
    chip.power_cycle()
    with pytest.raises(DeviceError, match='fake 0x40: MODE1 read 0x11, expected 0x20'):
        driver.verify()
    dev.bus.attach(0x40, WrongDevice(0x00))
    with pytest.raises(DeviceError, match='fake 0x40: not a PCA9685 .*MODE1 read 0x00, '
                                          'wrote 0x30'):
        pca.Pca9685(dev).open(50.0, {0: 307})


def test_esc_arms_after_neutral_and_beeps_before():
    esc = EscModel(EscSpec(1500.0, 25.0, 1100.0, 1900.0, 1.0, 3.0, 50.0, 40.0, False))
    assert esc.update(1900.0, 0.0) == 0.0 and esc.beeps == 1       # not armed
    assert esc.update(1500.0, 0.1) == 0.0 and not esc.armed
    assert esc.update(1510.0, 1.2) == 0.0 and esc.armed            # in the dead band
    assert esc.update(1900.0, 1.3) == pytest.approx(50.0)
    assert esc.update(1100.0, 1.4) == pytest.approx(-40.0)
    assert esc.update(1712.5, 1.5) == pytest.approx(25.0)
    assert esc.update(0.0, 2.0) == 0.0 and esc.armed               # signal lost ...
    assert esc.update(0.0, 5.0) == 0.0 and not esc.armed           # ... for 3 s: disarmed


def test_esc_arms_on_the_neutral_the_chip_output_before_anyone_sampled_it():
    """The chip outputs a pulse from the write on: the ESC saw the neutral a driver wrote at
    connect even if the emulator's loop started later (bringup's discovery wait)."""
    chip, dev = chip_on_bus()
    now = [10_000_000_000]
    chip.clock = lambda: now[0]
    dev.write_u8(0x00, 0x30)
    dev.write_u8(0xFE, 121)                                  # 50 Hz
    dev.write_block(0x06, bytes([0, 0, 0x33, 0x01]))        # 307 counts: 1498.4 us, neutral
    dev.write_u8(0x00, 0x20)
    now[0] += 500_000
    dev.write_u8(0x01, 0x04)                                 # any later write notes the output
    since = chip.since_ns[0] * 1e-9
    assert since == pytest.approx(10.0005)
    spec = EscSpec(1500.0, 25.0, 1100.0, 1900.0, 1.0, 3.0, 50.0, 40.0, False)
    sampled_late = EscModel(spec)
    assert sampled_late.update(chip.pulse_us(0), 12.0, since) == 0.0 and sampled_late.armed
    assert sampled_late.update(1900.0, 12.01, since) == pytest.approx(50.0)
    no_history = EscModel(spec)                              # the same, counted from 12.0
    no_history.update(chip.pulse_us(0), 12.0)
    assert not no_history.armed


# -- enbarr check-device pca9685 ------------------------------------------------------------------

def test_check_device_reads_the_emulated_chip():
    lines = check_pca9685(CheckTarget(bus='emulated:check'))
    assert lines[0] == 'PCA9685 at emulated:check 0x40'
    assert 'MODE1 0x11 (asleep)' in lines[1]
    assert lines[2].startswith('PRE_SCALE 30 -> 196.9 Hz')
    assert lines[3] == 'channel 0: full off'
    with pytest.raises(DeviceError):                        # cleaned up afterwards
        emulation.lookup('i2c', 'emulated:check')


def test_check_device_refuses_a_wrong_device_and_an_absent_bus():
    bus = emulation.get_or_create('i2c', 'wrong', FakeI2cBus)
    bus.attach(0x40, WrongDevice(0xFF))
    try:
        with pytest.raises(DeviceError, match='emulated:wrong 0x40: not a PCA9685: MODE2 0xff'):
            check_pca9685(CheckTarget(bus='emulated:wrong'))
    finally:
        emulation.unregister('i2c', 'wrong')
    with pytest.raises(DeviceError, match='i2c-57: cannot open /dev/i2c-57'):
        check_pca9685(CheckTarget(bus='57'))


def test_check_device_command_line(capsys):
    assert main(['check-device', 'pca9685', '--bus', 'emulated']) == 0
    out = capsys.readouterr().out
    assert 'PCA9685 at emulated 0x40' in out and 'PRE_SCALE 30' in out
    assert main(['check-device', 'pca9685', '--bus', '57']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'i2c-57' in err[0]
