"""Thrusters on ESCs driven by an NXP PCA9685 16-channel PWM controller over I2C.

The real twin of ``sim_thrusters``: the same input (``thruster_commands``, -1..1 per named
thruster, same validation, time policy, ``InputHealth`` and clipping counts) and output
(``thruster_output``: what was written to the chip, neutral included), but the commands become
ESC pulse widths on the chip's channels.

Registers, bits and the prescale/counts arithmetic: ``pca9685_protocol.py`` (NXP PCA9685 data
sheet Rev. 4). The internal oscillator is 25 MHz nominal but varies between chips
(``oscillator`` calibrates it: measure a pulse with a scope and scale).

What the driver does:

- **open** (``Pca9685.open``), when the node starts (building it touches nothing, so a
  profile check leaves a running chip alone): read MODE1; sleep with AI set (SUB/ALLCALL
  off, as the Linux driver does, against address collisions), MODE2 = OUTDRV, PRE_SCALE;
  write every channel to its neutral pulse (unmapped channels full off) in auto-increment
  blocks while asleep; then read back MODE1, MODE2, PRE_SCALE and the channel block. The
  PCA9685 has no identity register: a device that does not hold what was written (another
  chip at 0x40, a bus that returns garbage) is refused with the bus, address and values
  read. Then wake and restart.
- **arming**: an ESC arms only after it saw its neutral pulse for a while (Blue Robotics:
  1500 us for about a second before driving, and a new arming after the signal stopped for a
  few seconds: discuss.bluerobotics.com threads 380 and 2214). After every connect or
  reconnect the driver holds neutral for ``arming_time`` before applying any command
  (commands in that time are published as neutral and counted as ``held_arming``).
- **writer thread**: the chain calls the subscription on its own thread; it only validates
  and hands the latest command over. A writer thread maps it to pulse counts and writes all
  mapped channels in one auto-increment block (8 channels = 32 bytes = one I2C transfer), at
  most once per PWM period (an ESC reads one pulse per period) and at most ``write_rate``
  times a second (the bus is shared with the IMU: at the Pi's default 100 kHz one block takes
  3.3 ms). A higher ``frequency`` still helps: the pulse resolution is (prescale + 1) / 25 MHz,
  4.9 us at 50 Hz (1.3 % of the 1100-1900 us range, enough to bias small commands, which sit
  at the dead band's edge) and 1.2 us at 200 Hz.
  It reads MODE1 back every ``verify_period``: a chip that browned out or was replugged comes
  back asleep (MODE1 0x11), outputs off, and is a fault.
- **faults**: an I2C error (NACK: unplugged; ETIMEDOUT: stalled), a readback that does not
  match, or a wrong device at open are ``DeviceError``s naming the bus, address and values;
  the node then reports ERROR on ``/diagnostics``, goes neutral (as far as the chip can still
  be written) and reopens with backoff; arming starts again once it is back. A stalled bus
  blocks only the writer thread, except a reconnect attempt: ``open_device`` runs on the
  executor (the ``DeviceNode`` contract): about ten transfers, the first failure ends it, each
  bounded by the 20 ms adapter timeout and one retry.
- **neutral** at start, on every stop path (``safe_state``), when commands stop
  (``command_timeout``) and on faults. Note that the chip keeps generating the last pulses on
  its own: if the Pi dies without a stop path the ESCs keep their last command; wire the
  PCA9685's OE pin or the ESC power through a kill switch.

Camera tilt servo (``servo.*``, optional: ``servo.channel`` -1 is none): a hobby servo on a
spare channel (``servo.py``: pulse for an angle, the angle rate-limited toward its goal). An
``io_request`` addressed to ``servo.executor`` (``camera_tilt``) with a number sets the goal
angle [deg] (clamped; anything else is refused and counted); a timer moves the angle at
``servo.rate`` deg/s while it is on its way, and the writer thread writes the servo's channel
alone (4 bytes) when its counts change, so the thrusters' block stays one transfer. The servo
starts centred, holds its angle through a thruster fault or neutral (it is no thruster: a
camera that swings back on every fault would hide what went wrong), and is written again
with the chip's first block after a reconnect.

Pulse calibration per thruster (``pca9685.pulse.<name>.*``, microseconds): ``neutral``,
``min`` (full reverse), ``max`` (full forward), ``dead_band`` (half-width of the ESC's
dead band around neutral; a non-zero command starts just outside it, so a small command
produces thrust; Blue Robotics Basic ESC: 1100-1900 us, stopped 1500 us, +-25 us) and
``reversed`` (propeller or motor wiring turns the other way). Channel map:
``pca9685.channels.<name>`` (0..15), vessel data without default.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
import threading
import time
from typing import Any

import numpy as np
from rcl_interfaces.msg import Parameter

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec, SettingsBinding
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.thrusters.common import MAX_FUTURE_SPEC, ThrusterDriver
from enbarr_plugins.thrusters.pca9685_protocol import (
    AI, CHANNELS, counts_for, channel_bytes, DEFAULT_ADDRESS, frequency_of, FULL, COUNTS,
    led_register, LED0_ON_L, MODE1, MODE2, OSCILLATOR, OUTDRV, PRE_SCALE, prescale_for,
    pulse_of, RESTART, SLEEP, WAKE_DELAY)
from enbarr_plugins.thrusters.servo import ServoSettings, ServoSlew
from enbarr_plugins.transport.i2c import MAX_BLOCK, I2cDevice, open_i2c

class Pca9685:
    """The chip's registers, over one ``I2cDevice``; every failure is a ``DeviceError``."""

    def __init__(self, device: I2cDevice, oscillator: float = OSCILLATOR) -> None:
        self.device = device
        self.oscillator = oscillator
        self.prescale = 0
        self.mode1_awake = AI
        self.writes = 0
        self.verified = 0

    @property
    def name(self) -> str:
        """Bus and address (``i2c-1 0x40``)."""
        return self.device.name

    def open(self, frequency: float, counts: Mapping[int, int]) -> dict[str, Any]:
        """Configure the chip, check it holds what was written, wake it; return its state.

        ``counts``: channel -> pulse counts at start (neutral); other channels full off.
        """
        self.prescale = prescale_for(frequency, self.oscillator)
        before = self.device.read_u8(MODE1)
        asleep = AI | SLEEP
        self.device.write_u8(MODE1, asleep)   # ALLCALL and SUBx off, RESTART not written
        self.device.write_u8(MODE2, OUTDRV)
        self.device.write_u8(PRE_SCALE, self.prescale)
        block = self._block(counts)
        self._write_channels(block)
        got = {'MODE1': self.device.read_u8(MODE1), 'MODE2': self.device.read_u8(MODE2),
               'PRE_SCALE': self.device.read_u8(PRE_SCALE)}
        want = {'MODE1': asleep, 'MODE2': OUTDRV, 'PRE_SCALE': self.prescale}
        wrong = {k: v for k, v in got.items() if (v & ~RESTART if k == 'MODE1' else v) != want[k]}
        if wrong:
            raise DeviceError(f'{self.name}: not a PCA9685 (or not answering like one): '
                              + ', '.join(f'{k} read 0x{got[k]:02x}, wrote 0x{want[k]:02x}'
                                          for k in wrong))
        for start in range(0, len(block), MAX_BLOCK):
            read = self.device.read_block(LED0_ON_L + start,
                                          min(MAX_BLOCK, len(block) - start))
            if read != block[start:start + len(read)]:
                raise DeviceError(f'{self.name}: channel registers from 0x'
                                  f'{LED0_ON_L + start:02x} read {read.hex(" ")}, wrote '
                                  f'{block[start:start + len(read)].hex(" ")}')
        self.device.write_u8(MODE1, AI)       # wake
        time.sleep(WAKE_DELAY)
        mode1 = self.device.read_u8(MODE1)
        if mode1 & RESTART:                   # PWM was running before the sleep: restart it
            self.device.write_u8(MODE1, AI | RESTART)
        self.mode1_awake = AI
        return {'mode1_before': before, 'prescale': self.prescale,
                'frequency': frequency_of(self.prescale, self.oscillator)}

    def _block(self, counts: Mapping[int, int | None]) -> bytes:
        """LED registers of channels 0..max mapped channel (unmapped: full off)."""
        last = max(counts) if counts else -1
        return b''.join(channel_bytes(counts.get(c)) for c in range(last + 1))

    def _write_channels(self, block: bytes, first: int = 0) -> None:
        for start in range(0, len(block), MAX_BLOCK):
            self.device.write_block(led_register(first) + start, block[start:start + MAX_BLOCK])

    def write(self, counts: Mapping[int, int | None]) -> bytes:
        """Write the pulses of ``counts`` (channel -> counts, None: off); return the bytes.

        One auto-increment block from the lowest channel to the highest (32 bytes a transfer).
        """
        first, last = min(counts), max(counts)
        block = b''.join(channel_bytes(counts.get(c)) for c in range(first, last + 1))
        self._write_channels(block, first)
        self.writes += 1
        return block

    def verify(self) -> None:
        """Check the chip is still awake and configured (a replugged chip wakes asleep)."""
        mode1 = self.device.read_u8(MODE1)
        if mode1 & ~RESTART != self.mode1_awake:
            raise DeviceError(f'{self.name}: MODE1 read 0x{mode1:02x}, expected '
                              f'0x{self.mode1_awake:02x}: the chip was reset (power or '
                              'replug) or the bus returns garbage')
        self.verified += 1

    def read_state(self, channel: int = 0) -> dict[str, Any]:
        """MODE1, PRE_SCALE, frequency and the pulse of ``channel`` as the chip holds them."""
        mode1 = self.device.read_u8(MODE1)
        mode2 = self.device.read_u8(MODE2)
        prescale = self.device.read_u8(PRE_SCALE)
        on_l, on_h, off_l, off_h = self.device.read_block(led_register(channel), 4)
        if off_h & FULL:
            pulse = 0.0
        elif on_h & FULL:
            pulse = math.inf
        else:
            counts = ((((off_h & 0x0F) << 8) | off_l) - (((on_h & 0x0F) << 8) | on_l)) % COUNTS
            pulse = pulse_of(counts, prescale, self.oscillator)
        return {'mode1': mode1, 'mode2': mode2, 'prescale': prescale,
                'frequency': frequency_of(max(prescale, 1), self.oscillator), 'pulse': pulse}

    def close(self) -> None:
        """Close the bus (when owned); never raises."""
        self.device.close()


# -- parameters ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Pulse:
    """ESC pulse calibration of one thruster [us]."""

    neutral: float
    min: float
    max: float
    dead_band: float
    reversed: bool

    def width(self, command: float) -> float:
        """Pulse width [us] for a command in -1..1 (0: exactly neutral)."""
        c = -command if self.reversed else command
        if c > 0.0:
            low = self.neutral + self.dead_band
            return low + c * (self.max - low)
        if c < 0.0:
            high = self.neutral - self.dead_band
            return high + c * (high - self.min)
        return self.neutral


PULSE_FIELDS = (
    ('neutral', 1500.0, 'Pulse width that stops the thruster'),
    ('min', 1100.0, 'Pulse width of full reverse (command -1)'),
    ('max', 1900.0, 'Pulse width of full forward (command +1)'),
    ('dead_band', 25.0, 'Half-width of the ESC dead band around neutral (a non-zero '
     'command starts outside it)'),
)


def pulse_specs(names: Sequence[str]) -> list[ParamSpec]:
    """Per-thruster pulse calibration and channel parameters (read only)."""
    specs = []
    for n in names:
        specs.append(ParamSpec(f'pca9685.channels.{n}', 0, f'PCA9685 channel of thruster {n}',
                               '', 0, CHANNELS - 1, read_only=True, required=True))
        for key, default, text in PULSE_FIELDS:
            specs.append(ParamSpec(f'pca9685.pulse.{n}.{key}', default, f'{text} ({n})', 'us',
                                   0.0, 1e5, read_only=True))
        specs.append(ParamSpec(f'pca9685.pulse.{n}.reversed', False,
                               f'Thruster {n} turns the other way for the same pulse',
                               read_only=True))
    return specs


def pulses_from_params(names: Sequence[str], v: Mapping[str, Any],
                       period_us: float) -> tuple[tuple[int, ...], tuple[Pulse, ...]]:
    """Channels and pulses of ``names``; ValueError naming the parameter that does not fit."""
    channels = tuple(v[f'pca9685.channels.{n}'] for n in names)
    if len(set(channels)) != len(channels):
        raise ValueError(f'pca9685.channels: two thrusters on one channel: '
                         f'{dict(zip(names, channels))}')
    pulses = []
    for n in names:
        p = Pulse(*(v[f'pca9685.pulse.{n}.{k}'] for k, _, _ in PULSE_FIELDS),
                  reversed=v[f'pca9685.pulse.{n}.reversed'])
        if not p.min < p.neutral - p.dead_band <= p.neutral + p.dead_band < p.max:
            raise ValueError(f'pca9685.pulse.{n}: need min < neutral - dead_band <= neutral + '
                             f'dead_band < max, got {p}')
        if p.max >= period_us:
            raise ValueError(f'pca9685.pulse.{n}.max: {p.max} us does not fit in the PWM '
                             f'period of {period_us:.0f} us (lower frequency)')
        pulses.append(p)
    return channels, tuple(pulses)


SPECS = [
    ParamSpec('bus', '1', "I2C bus: '1' or '/dev/i2c-1', or 'emulated[:NAME]'",
              read_only=True),
    ParamSpec('address', DEFAULT_ADDRESS, 'I2C address of the PCA9685', '', 0x03, 0x77,
              read_only=True),
    ParamSpec('frequency', 50.0, 'PWM frequency (ESCs: 50..400)', 'Hz', 24.0, 1526.0,
              read_only=True),
    ParamSpec('oscillator', OSCILLATOR, 'Oscillator frequency of this chip (calibration)',
              'Hz', 20e6, 30e6, read_only=True),
    ParamSpec('write_rate', 50.0, 'Most channel-block writes per second (also at most one per '
              'PWM period); each is a 33-byte I2C transfer, 3.3 ms at 100 kHz', 'Hz', 1.0,
              1526.0),
    ParamSpec('arming_time', 2.0, 'Neutral held after (re)connecting before commands apply',
              's', 0.0, 30.0),
    ParamSpec('verify_period', 1.0, 'How often MODE1 is read back to catch a reset chip', 's',
              0.05, 60.0),
    MAX_FUTURE_SPEC,
    ParamSpec('servo.channel', -1, 'PCA9685 channel of the camera tilt servo (-1: none)', '',
              -1, CHANNELS - 1, read_only=True),
    ParamSpec('servo.min_pulse', 1100.0, 'Servo pulse width at servo.min_angle', 'us', 0.0,
              1e5, read_only=True),
    ParamSpec('servo.centre_pulse', 1500.0, 'Servo pulse width at 0 deg (the centre)', 'us',
              0.0, 1e5, read_only=True),
    ParamSpec('servo.max_pulse', 1900.0, 'Servo pulse width at servo.max_angle', 'us', 0.0,
              1e5, read_only=True),
    ParamSpec('servo.min_angle', -45.0, 'Lowest servo angle (camera down)', 'deg', -180.0, 0.0,
              read_only=True),
    ParamSpec('servo.max_angle', 45.0, 'Highest servo angle (camera up)', 'deg', 0.0, 180.0,
              read_only=True),
    ParamSpec('servo.rate', 60.0, 'Fastest servo motion toward a new angle', 'deg/s', 1.0,
              1000.0),
    ParamSpec('servo.executor', 'camera_tilt', 'io_request name of the servo (an angle [deg])',
              read_only=True),
]

#: How often the servo's angle moves while on its way to a goal [Hz].
SERVO_UPDATE_RATE = 25.0


@dataclass(frozen=True)
class Pca9685Settings:
    """Settings of ``Pca9685ThrustersNode`` (see ``SPECS`` and ``pulse_specs``)."""

    bus: str
    address: int
    frequency: float       # [Hz]
    oscillator: float      # [Hz]
    write_rate: float      # [Hz]
    arming_time: float     # [s]
    verify_period: float   # [s]
    max_future: float      # [s]
    channels: tuple[int, ...]
    pulses: tuple[Pulse, ...]
    prescale: int
    servo: ServoSettings

    @classmethod
    def build(cls, names: Sequence[str], v: Mapping[str, Any]) -> Pca9685Settings:
        """Build from the parameter values; ValueError names the parameter."""
        bus = v['bus'].strip()
        if not emulation.is_emulated(bus):
            bus_number(bus)   # ValueError when it is no bus
        prescale = prescale_for(v['frequency'], v['oscillator'])
        period_us = 1e6 / frequency_of(prescale, v['oscillator'])
        channels, pulses = pulses_from_params(names, v, period_us)
        servo = ServoSettings(
            channel=v['servo.channel'], min_pulse=v['servo.min_pulse'],
            centre_pulse=v['servo.centre_pulse'], max_pulse=v['servo.max_pulse'],
            min_angle=v['servo.min_angle'], max_angle=v['servo.max_angle'],
            rate=v['servo.rate'], executor=v['servo.executor'].strip())
        servo.validate(period_us)
        if servo.channel in channels:
            raise ValueError(f'servo.channel: {servo.channel} is already a thruster channel '
                             f'({dict(zip(names, channels))})')
        return cls(bus=bus, address=v['address'], frequency=v['frequency'],
                   oscillator=v['oscillator'], write_rate=v['write_rate'],
                   arming_time=v['arming_time'],
                   verify_period=v['verify_period'], max_future=v['max_future'],
                   channels=channels, pulses=pulses, prescale=prescale, servo=servo)

    def counts(self, command: np.ndarray) -> dict[int, int]:
        """Channel -> counts of a normalized command (one entry per thruster)."""
        return {ch: counts_for(p.width(float(c)), self.prescale, self.oscillator)
                for ch, p, c in zip(self.channels, self.pulses, command)}

    def servo_counts(self, angle: float) -> int:
        """Return the counts of the servo's pulse at ``angle`` [deg]."""
        return counts_for(self.servo.pulse(angle), self.prescale, self.oscillator)


def bus_number(text: str) -> int:
    """Return the bus number of ``'1'`` or ``'/dev/i2c-1'``; ValueError names the parameter."""
    tail = text.removeprefix('/dev/i2c-')
    if not tail.isdigit():
        raise ValueError(f"bus: {text!r} is not an I2C bus ('1', '/dev/i2c-1') or "
                         "'emulated[:NAME]'")
    return int(tail)


def open_device(bus: str, address: int) -> tuple[I2cDevice, bool]:
    """Return the I2C device at ``address`` on ``bus`` and whether we own (close) the bus."""
    if emulation.is_emulated(bus):
        return I2cDevice(emulation.lookup('i2c', bus), address, bus_name=bus, retries=1), False
    n = bus_number(bus)
    # 20 ms adapter timeout: a 33-byte block takes 3.3 ms at 100 kHz; a stalled bus then costs
    # at most 2 x 20 ms per transfer (one retry).
    return I2cDevice(open_i2c(n, timeout=0.02), address, bus_name=f'i2c-{n}', retries=1), True


# -- the node ------------------------------------------------------------------------------

class Pca9685ThrustersNode(ThrusterDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_control', **kwargs: Any) -> None:
        self.chip: Pca9685 | None = None
        self._owns_bus = False
        self._cond = threading.Condition()
        self._pending: np.ndarray | None = None
        self._stop = False
        self._thread: threading.Thread | None = None
        self._fault: DeviceError | None = None
        self._armed_ns = 0
        super().__init__(node_name, **kwargs)
        self.settings: Pca9685Settings
        SettingsBinding(self, SPECS + pulse_specs(self.names),
                        lambda v: Pca9685Settings.build(self.names, v), self._apply)
        self.device = f'{self.settings.bus} 0x{self.settings.address:02x}'
        self.applied = np.zeros(len(self.names))   # last written to the chip
        self.held_arming = 0
        self.written: bytes = b''                  # last channel block written
        self.subscribe_commands()
        self.servo = ServoSlew(self.settings.servo)
        self.servo_refused = 0
        self._servo_pending: int | None = None     # servo counts for the writer
        self._servo_counts = self.settings.servo_counts(0.0)   # last handed to the writer
        if self.settings.servo.channel >= 0:
            self.create_topic_subscription(topics.IO_REQUEST, self._on_io_request)
            self._servo_timer = self.create_timer(1.0 / SERVO_UPDATE_RATE, self._move_servo)
            self._servo_timer.cancel()             # runs only while the servo is on its way
            self._servo_last_ns = 0

    def _apply(self, settings: Pca9685Settings) -> None:
        self.settings = settings
        servo = getattr(self, 'servo', None)
        if servo is not None:   # servo.rate is live
            servo.settings = settings.servo
        self.commands.set_max_future(settings.max_future)

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the bus, configure and check the chip, start the writer (neutral, arming)."""
        s = self.settings
        device, self._owns_bus = open_device(s.bus, s.address)
        chip = Pca9685(device, s.oscillator)
        counts: dict[int, int] = s.counts(np.zeros(len(self.names)))
        if s.servo.channel >= 0:
            counts[s.servo.channel] = self._servo_counts
        try:
            chip.open(s.frequency, counts)
        except DeviceError:
            if self._owns_bus:
                chip.close()
            raise
        self.chip = chip
        self.written = b''
        self._fault = None
        self._armed_ns = time.monotonic_ns() + int(s.arming_time * 1e9)
        with self._cond:
            self._stop = False
            self._pending = np.zeros(len(self.names))
        self._thread = threading.Thread(target=self._write_loop, name=f'{self.get_name()}_i2c',
                                        daemon=True)
        self._thread.start()
        hz = frequency_of(s.prescale, s.oscillator)
        self.get_logger().info(f'{chip.name}: PCA9685 at {hz:.1f} Hz (prescale {s.prescale}), '
                               f'arming for {s.arming_time} s')

    def close_device(self) -> None:
        """Stop the writer after it wrote neutral (whatever came last); close the bus."""
        with self._cond:
            self._stop = True
            self._pending = np.zeros(len(self.names))
            self._cond.notify()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(1.0)
        chip, self.chip = self.chip, None
        if chip is not None and self._owns_bus:
            chip.close()

    @property
    def armed(self) -> bool:
        """Whether the arming time after the last connect is over."""
        return self.connected and time.monotonic_ns() >= self._armed_ns

    def _write_loop(self) -> None:
        """Writer thread: the latest command to the chip, MODE1 checked every verify_period."""
        chip = self.chip
        if chip is None:
            return
        next_verify = time.monotonic() + self.settings.verify_period
        last_write = 0.0
        try:
            while True:
                with self._cond:
                    while (self._pending is None and self._servo_pending is None
                           and not self._stop):
                        timeout = next_verify - time.monotonic()
                        if timeout <= 0.0:
                            break
                        self._cond.wait(timeout)
                    cmd, self._pending = self._pending, None
                    servo, self._servo_pending = self._servo_pending, None
                    stop = self._stop
                if servo is not None:
                    chip.write({self.settings.servo.channel: servo})
                if cmd is not None:
                    # One write per PWM period at most (the ESC reads one pulse per period),
                    # and at most write_rate: the bus is shared with the IMU.
                    s = self.settings
                    wait = last_write + 1.0 / min(s.frequency, s.write_rate) - time.monotonic()
                    if wait > 0.0 and not stop:
                        time.sleep(wait)
                        with self._cond:   # a newer command came meanwhile: take it
                            if self._pending is not None:
                                cmd, self._pending = self._pending, None
                    self._write(chip, cmd)
                    last_write = time.monotonic()
                if stop:
                    return
                if time.monotonic() >= next_verify:
                    chip.verify()
                    next_verify = time.monotonic() + self.settings.verify_period
        except DeviceError as err:
            self._fault = err   # handled on the executor by supervise(): safe state, reconnect

    def _write(self, chip: Pca9685, cmd: np.ndarray) -> None:
        if np.any(cmd) and time.monotonic_ns() < self._armed_ns:
            self.held_arming += 1
            cmd = np.zeros(len(self.names))
        counts: dict[int, int | None] = dict(self.settings.counts(cmd))
        servo = self.settings.servo.channel
        if servo >= 0 and min(counts) < servo < max(counts):
            counts[servo] = self._servo_counts   # inside the block: keep its pulse
        self.written = chip.write(counts)
        self.applied = cmd
        self.publish_output(cmd, self.now_ns())

    def _hand_over(self, cmd: np.ndarray) -> None:
        with self._cond:
            self._pending = cmd
            self._cond.notify()

    # -- camera tilt servo ---------------------------------------------------------------------
    def _on_io_request(self, msg: Parameter) -> None:
        if msg.name != self.settings.servo.executor:
            return
        value = convert.parameter_value_to_python(msg.value)
        reason = self.servo.request(value)
        if reason:
            self.servo_refused += 1
            self.get_logger().warn(f'{msg.name}: refused {value!r}: {reason}')
            return
        if self._servo_timer.is_canceled():
            self._servo_last_ns = self.now_ns()
            self._servo_timer.reset()

    def _move_servo(self) -> None:
        now = self.now_ns()
        angle = self.servo.step((now - self._servo_last_ns) * 1e-9)
        self._servo_last_ns = now
        counts = self.settings.servo_counts(angle)
        if counts != self._servo_counts:
            self._servo_counts = counts
            with self._cond:
                self._servo_pending = counts
                self._cond.notify()
        if angle == self.servo.goal:
            self._servo_timer.cancel()

    def supervise(self) -> None:
        """Run the command watchdog; turn a writer failure into a device fault."""
        super().supervise()
        fault = self._fault
        if fault is not None and self.connected:
            self._fault = None
            self.device_fault(fault)

    # -- commands ----------------------------------------------------------------------------
    def apply(self, command: np.ndarray, now_ns: int) -> None:
        """Hand an accepted command to the writer (the watchdog's lock held)."""
        self.command = command
        self.neutral = not np.any(command)
        self._hand_over(command)

    def write_neutral(self) -> None:
        """Hand neutral to the writer (it writes within one PWM period when connected)."""
        self.neutral = True
        self.command = np.zeros(len(self.names))
        self._hand_over(self.command)

    def status_values(self) -> dict[str, Any]:
        """Return the driver counters."""
        chip = self.chip
        servo = ({'servo_angle': round(self.servo.angle, 2), 'servo_refused': self.servo_refused}
                 if self.settings.servo.channel >= 0 else {})
        return {**super().status_values(), **servo, 'armed': self.armed,
                'held_arming': self.held_arming, 'writes': chip.writes if chip else 0,
                'i2c_errors': chip.device.errors if chip else 0}
