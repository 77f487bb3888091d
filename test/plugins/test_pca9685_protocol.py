"""Unit tests: every PCA9685 number the driver relies on, pinned to its source document.

The tables below are typed from the sources, never read from the code under test. Each is
compared with the driver's protocol module (``pca9685_protocol.py``) and exercised through the
emulator (``pca9685_emulator.py``, which keeps its own copy). ``test_pca9685.py`` and the node
tests exercise the same numbers further (power-on state, the restart rule, exact blocks).

Sources:
- NXP PCA9685 product data sheet Rev. 4, 16 April 2015: table 4 (register summary: MODE1
  0x00, MODE2 0x01, LED0_ON_L 0x06 and four registers per channel up to LED15_OFF_H 0x45,
  ALL_LED_ON_L 0xFA, PRE_SCALE 0xFE); 7.3.1 MODE1 (RESTART bit 7, AI bit 5, SLEEP bit 4,
  ALLCALL bit 0; power-on 0x11); 7.3.2 MODE2 (OUTDRV bit 2, bits 7:5 reserved; power-on 0x04);
  7.3.3 (bit 4 of LEDn_ON_H full on, of LEDn_OFF_H full off); 7.3.5 (equation 1:
  prescale = round(osc_clock / (4096 x update_rate)) - 1, 25 MHz internal oscillator, the
  hardware forces a minimum of 3, maximum 0xFF, power-on 0x1E = 200 Hz); 7.3.1.1 (500 us
  for the oscillator after SLEEP is cleared); 7.1 (address 1 A5..A0: 0x40 with all low).
- Linux ``drivers/pwm/pwm-pca9685.c``: PCA9685_MODE1 ... PCA9685_PRESCALE, MODE1_RESTART
  BIT(7), MODE1_SLEEP BIT(4), MODE1_ALLCALL BIT(0), MODE2_OUTDRV BIT(2), LED_FULL BIT(4),
  PCA9685_PRESCALE_MIN 0x03, PCA9685_PRESCALE_MAX 0xFF, PCA9685_COUNTER_RANGE 4096,
  PCA9685_OSC_CLOCK_MHZ 25, PCA9685_PRESCALE_DEF 0x1E, "Wait 500us for the oscillator".
- Adafruit-PWM-Servo-Driver-Library: MODE1_AI 0x20, PCA9685_I2C_ADDRESS 0x40.
"""

from __future__ import annotations

import pytest

from enbarr_plugins.thrusters import pca9685_protocol as proto
from enbarr_plugins.thrusters.pca9685_emulator import Pca9685Emulator
from enbarr_plugins.transport.i2c import FakeI2cBus, I2cDevice

REGISTERS = {'MODE1': 0x00, 'MODE2': 0x01, 'LED0_ON_L': 0x06, 'ALL_LED_ON_L': 0xFA,
             'PRE_SCALE': 0xFE}
VALUES = {
    'RESTART': 0x80, 'AI': 0x20, 'SLEEP': 0x10, 'ALLCALL': 0x01,      # MODE1
    'OUTDRV': 0x04, 'MODE2_RESERVED': 0xE0,                           # MODE2
    'FULL': 0x10,                                                     # LEDn_ON_H / OFF_H bit 4
    'COUNTS': 4096, 'CHANNELS': 16, 'PRESCALE_MIN': 3, 'PRESCALE_MAX': 255,
    'OSCILLATOR': 25e6, 'WAKE_DELAY': 500e-6, 'DEFAULT_ADDRESS': 0x40,
}
OSC = 25e6           # [Hz]


def prescale(rate: float) -> int:
    """Equation 1 of the data sheet, typed again."""
    return round(OSC / (4096 * rate)) - 1


@pytest.mark.parametrize('name, value', {**REGISTERS, **VALUES}.items())
def test_registers_bits_and_limits_match_the_data_sheet(name, value):
    assert getattr(proto, name) == value


def test_four_registers_per_channel_from_0x06():
    assert [proto.led_register(c) for c in range(16)] == list(range(0x06, 0x46, 4))
    assert proto.led_register(15) + 3 == 0x45                         # LED15_OFF_H


@pytest.mark.parametrize('rate', [24.0, 50.0, 60.0, 100.0, 200.0, 333.0, 400.0, 1000.0, 1526.0])
def test_prescale_is_equation_1(rate):
    assert proto.prescale_for(rate) == prescale(rate)
    assert proto.frequency_of(prescale(rate)) == pytest.approx(OSC / (4096 * (prescale(rate)
                                                                              + 1)))


def test_counts_are_oscillator_ticks_of_the_prescaled_clock():
    # 1500 us at 50 Hz: prescale 121, one count = 122 / 25 MHz = 4.88 us -> 307 counts.
    assert proto.counts_for(1500.0, 121) == 307
    assert proto.pulse_of(307, 121) == pytest.approx(307 * 122 / 25.0)
    assert proto.channel_bytes(307) == bytes([0x00, 0x00, 307 & 0xFF, 307 >> 8])  # ON 0
    assert proto.channel_bytes(None) == bytes([0x00, 0x00, 0x00, 0x10])           # full off


# -- the emulator, written to and read through its registers --------------------------------

@pytest.fixture
def chip():
    bus = FakeI2cBus()
    emulator = bus.attach(0x40, Pca9685Emulator())
    now = [1_000_000_000]
    emulator.clock = lambda: now[0]
    return emulator, I2cDevice(bus, 0x40, bus_name='fake'), now


def test_the_emulator_powers_on_as_the_data_sheet_says(chip):
    _, dev, _ = chip
    assert dev.read_u8(0x00) == 0x11 and dev.read_u8(0x01) == 0x04 and dev.read_u8(0xFE) == 0x1E
    leds = [dev.read_u8(r) for r in range(0x06, 0x46)]      # AI is off: one at a time
    assert leds == [0, 0, 0, 0x10] * 16                      # every channel full off


@pytest.mark.parametrize('channel', range(16))
def test_the_emulator_outputs_each_channel_from_its_four_registers(chip, channel):
    emulator, dev, now = chip
    dev.write_u8(0x00, 0x30)                                # SLEEP | AI
    dev.write_u8(0xFE, prescale(50.0))
    counts = 250 + 10 * channel
    dev.write_block(0x06 + 4 * channel, bytes([0, 0, counts & 0xFF, counts >> 8]))
    dev.write_u8(0x00, 0x20)                                # wake
    now[0] += 500_000                                       # the oscillator's 500 us
    tick_us = (prescale(50.0) + 1) / 25.0
    assert emulator.period_us == pytest.approx(4096 * tick_us)
    assert [emulator.pulse_us(c) for c in range(16)] == [
        pytest.approx(counts * tick_us) if c == channel else 0.0 for c in range(16)]


def test_the_emulator_needs_500_us_after_waking(chip):
    emulator, dev, now = chip
    dev.write_u8(0x00, 0x30)
    dev.write_block(0x06, bytes([0, 0, 0x33, 0x01]))
    dev.write_u8(0x00, 0x20)
    now[0] += 499_000
    assert emulator.pulse_us(0) == 0.0
    now[0] += 1_000
    assert emulator.pulse_us(0) > 0.0


def test_the_emulator_loads_every_channel_from_all_led(chip):
    _, dev, _ = chip
    dev.write_u8(0x00, 0x30)
    dev.write_block(0xFA, bytes([0x01, 0x00, 0x34, 0x01]))
    assert all(dev.read_block(0x06 + 4 * c, 4) == bytes([0x01, 0x00, 0x34, 0x01])
               for c in range(16))
