"""NXP PCA9685 PWM controller over I2C: registers, bits, prescale and pulse arithmetic.

The numbers of the driver (``pca9685.py``), from the NXP PCA9685 product data sheet Rev. 4
(16 April 2015): section 7.3 "Register definitions" (table 4), 7.3.1 MODE1, 7.3.2 MODE2,
7.3.3 LED output and PWM control, 7.3.5 PWM frequency PRE_SCALE (equation 1); checked against
Linux ``drivers/pwm/pwm-pca9685.c`` (PCA9685_MODE1 ... PCA9685_PRESCALE, MODE1_RESTART,
MODE1_SLEEP, MODE1_ALLCALL, MODE2_OUTDRV, LED_FULL, PCA9685_PRESCALE_MIN 0x03 / MAX 0xFF,
PCA9685_COUNTER_RANGE 4096, PCA9685_OSC_CLOCK_MHZ 25, "Wait 500us for the oscillator to be
back up") and Adafruit-PWM-Servo-Driver-Library (MODE1_AI 0x20).
``test/plugins/test_pca9685_protocol.py`` pins every number here to those sources; the
emulator keeps its own copy (``pca9685_emulator.py``).

MODE1 power-on 0x11 (SLEEP, ALLCALL); MODE2 power-on 0x04 (OUTDRV, totem-pole outputs);
LEDn_ON_L/ON_H/OFF_L/OFF_H at 0x06 + 4n, bit 4 of ON_H = full on, bit 4 of OFF_H = full off
(it wins); ALL_LED 0xFA-0xFD; PRE_SCALE 0xFE (power-on 0x1E), writable only while MODE1.SLEEP
is set. The PWM period is 4096 counts of the oscillator divided by prescale + 1, so
``prescale = round(osc / (4096 f)) - 1`` (3..255). Waking: clear SLEEP, wait 500 us for the
oscillator, then write 1 to RESTART if it reads 1 (7.3.1.1).
"""

from __future__ import annotations

MODE1 = 0x00
MODE2 = 0x01
LED0_ON_L = 0x06
ALL_LED_ON_L = 0xFA
PRE_SCALE = 0xFE
RESTART = 0x80
AI = 0x20
SLEEP = 0x10
ALLCALL = 0x01
OUTDRV = 0x04
MODE2_RESERVED = 0xE0  # bits 7..5 of MODE2 read 0
FULL = 0x10            # bit 4 of LEDn_ON_H (full on) / LEDn_OFF_H (full off)
COUNTS = 4096          # one PWM period
CHANNELS = 16
PRESCALE_MIN, PRESCALE_MAX = 3, 255
OSCILLATOR = 25e6      # internal oscillator, nominal [Hz]
WAKE_DELAY = 500e-6    # oscillator start-up after SLEEP is cleared [s]
DEFAULT_ADDRESS = 0x40

#: Channel registers of a channel that is off: ON = 0, OFF = full off.
OFF_BYTES = bytes((0, 0, 0, FULL))


def led_register(channel: int) -> int:
    """Return the LEDn_ON_L register of ``channel`` (0..15)."""
    return LED0_ON_L + 4 * channel


def prescale_for(frequency: float, oscillator: float = OSCILLATOR) -> int:
    """PRE_SCALE for a PWM ``frequency`` [Hz] (data sheet equation 1); ValueError outside."""
    prescale = round(oscillator / (COUNTS * frequency)) - 1
    if not PRESCALE_MIN <= prescale <= PRESCALE_MAX:
        raise ValueError(f'frequency: {frequency} Hz needs prescale {prescale}, outside '
                         f'{PRESCALE_MIN}..{PRESCALE_MAX} (with a {oscillator:.4g} Hz '
                         'oscillator: about 24..1526 Hz)')
    return prescale


def frequency_of(prescale: int, oscillator: float = OSCILLATOR) -> float:
    """PWM frequency [Hz] that ``prescale`` gives."""
    return oscillator / (COUNTS * (prescale + 1))


def counts_for(pulse_us: float, prescale: int, oscillator: float = OSCILLATOR) -> int:
    """Return the counts of one period (0..4095) that make a ``pulse_us`` [us] pulse."""
    return min(COUNTS - 1, max(0, round(pulse_us * 1e-6 * oscillator / (prescale + 1))))


def pulse_of(counts: int, prescale: int, oscillator: float = OSCILLATOR) -> float:
    """Pulse width [us] of ``counts``."""
    return counts * (prescale + 1) / oscillator * 1e6


def channel_bytes(counts: int | None) -> bytes:
    """LEDn_ON_L..OFF_H of a pulse of ``counts`` starting at count 0 (None: full off)."""
    if counts is None:
        return OFF_BYTES
    return bytes((0, 0, counts & 0xFF, (counts >> 8) & 0x0F))
