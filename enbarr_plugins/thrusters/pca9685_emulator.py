"""Emulator of a PCA9685 PWM controller with ESCs and thrusters on its channels.

``Pca9685Emulator`` is the chip's register file behind ``transport.i2c.FakeI2cBus``, written
from the NXP PCA9685 product data sheet (Rev. 4, 16 April 2015), section 7.3, with its own
copy of the register map:

- power-on state: MODE1 0x11 (SLEEP, ALLCALL), MODE2 0x04 (OUTDRV), every LEDn full off
  (LEDn_OFF_H 0x10), PRE_SCALE 0x1E (200 Hz);
- auto-increment (MODE1.AI): the register pointer advances after each byte of a transfer,
  from 0x45 back to 0x00 and from 0xFE to 0x00; without AI every byte goes to the register
  the transfer names;
- PRE_SCALE is written only while SLEEP is set (otherwise the write is ignored, counted in
  ``prescale_blocked``);
- SLEEP stops the oscillator: no pulses. Setting SLEEP while PWM runs sets RESTART; after
  SLEEP is cleared the oscillator needs 500 us, then writing 1 to RESTART resumes the PWM
  (a RESTART written earlier is ignored and counted in ``early_restart``; writing any LED
  register also resumes the outputs, with the new values); writing 0 to RESTART does nothing;
- ALL_LED_ON_L..OFF_H (0xFA-0xFD) load the same register of every channel; they read 0
  (the Linux driver notes the hardware cannot read the all-LED channel back);
- full on (bit 4 of LEDn_ON_H) and full off (bit 4 of LEDn_OFF_H, which wins): no pulse.

``pulse_us(channel)`` decodes what a channel outputs from PRE_SCALE and the ON/OFF counts:
``(OFF - ON) mod 4096`` counts of ``(prescale + 1) / oscillator`` seconds.

Faults for tests and users: ``FakeI2cBus.detach``/``nack`` (unplugged, NACK), ``stall_time``
(each transfer blocks that long then times out, as an adapter whose SCL is held low),
``corrupt`` (reads return bit-flipped bytes), ``power_cycle()`` (the chip resets to its
power-on state: a brown-out or a replug) and ``WrongDevice`` (another chip at the address,
which does not hold what is written).

``EscModel`` stands for a Blue Robotics Basic ESC and a T200 (discuss.bluerobotics.com
threads 380 and 2214, the Basic ESC documentation): it arms after its neutral pulse (within
the dead band) was held for ``arming_time``, gives no thrust before (it beeps), disarms when
the pulse stops for ``signal_timeout`` (the forum: "3-10 seconds"), and maps the pulse
linearly outside the dead band to the thruster's ``max_forward``/``max_reverse`` (the common
``thrusters`` parameters; a linear stand-in for the T200's curve).

A servo on another channel (``servo.channel``, the camera tilt) is decoded the same way and
shown in the node's report (``servo_pulse_us``); a servo makes no thrust.

``Pca9685EmulatorNode``, once started, attaches the chip at ``address`` on the shared emulated
bus ``emulated:<name>`` (the IMU emulator sits on the same one), and at ``rate`` publishes the
thrust the ESCs produce on ``sim/thrust`` (for ``rov_simulator``) and the pulse of every
thruster's channel on ``emulator/pca9685`` (``sensor_msgs/JointState``: name = thruster,
position = pulse width [us], 0 = no pulse).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import errno
import threading
import time
from typing import Any

import numpy as np
from sensor_msgs.msg import JointState

from enbarr_core.allocation.layout_params import declare_thrusters
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec, SettingsBinding
from enbarr_interfaces import convert, topics

from enbarr_interfaces.topics import SENSOR_QOS, TopicSpec
from enbarr_plugins import emulation
from enbarr_plugins.transport.i2c import FakeI2cBus

# The data sheet's registers and bits (table 4, 7.3), typed again for the emulator: it imports
# neither the driver nor its protocol module, so that neither can hide the other's mistake.
MODE1, MODE2, LED0_ON_L, ALL_LED_ON_L, PRE_SCALE = 0x00, 0x01, 0x06, 0xFA, 0xFE
RESTART, AI, SLEEP = 0x80, 0x20, 0x10          # MODE1
FULL = 0x10                                    # bit 4 of LEDn_ON_H / LEDn_OFF_H
CHANNELS = 16
COUNTS = 4096                                  # counter steps of one PWM period
PRESCALE_MIN = 3                               # the hardware clamps PRE_SCALE below 3
OSCILLATOR = 25e6                              # internal oscillator, nominal [Hz]
WAKE_DELAY = 500e-6                            # oscillator start-up after waking [s]
DEFAULT_ADDRESS = 0x40                         # A5..A0 = 0

#: What the emulated chip outputs, for end-to-end checks of the bytes it received.
EMULATOR_PCA9685 = TopicSpec(
    'emulator/pca9685', JointState, SENSOR_QOS, 'us (position)', topics.BODY_FRAME,
    'Pulse width each thruster channel of the emulated PCA9685 outputs (0: no pulse); the '
    "last one is published when the emulator closes, after the drivers' safe state.",
    fast=True)

LAST_LED = LED0_ON_L + 4 * CHANNELS - 1   # 0x45
POWER_ON = {MODE1: 0x11, MODE2: 0x04, PRE_SCALE: 0x1E}   # SLEEP | ALLCALL, OUTDRV, 200 Hz


class Pca9685Emulator:
    """The register file of one PCA9685; see the module docstring."""

    def __init__(self, oscillator: float = OSCILLATOR) -> None:
        self.oscillator = oscillator
        self.clock = time.monotonic_ns   # [ns]; a test may replace it
        self.lock = threading.Lock()
        self.stall_time = 0.0
        self.corrupt = False
        self.transfers = 0
        self.bytes = 0
        self.prescale_blocked = 0
        self.early_restart = 0
        self.power_cycle()

    def power_cycle(self) -> None:
        """Reset to the power-on state (brown-out, replug)."""
        with getattr(self, 'lock', threading.Lock()):
            self.regs = bytearray(256)
            for register, value in POWER_ON.items():
                self.regs[register] = value
            for c in range(CHANNELS):
                self.regs[LED0_ON_L + 4 * c + 3] = FULL
            self.running = False        # PWM outputs active
            self._awake_ns = 0          # when SLEEP was cleared
            self.outputs = [0.0] * CHANNELS            # pulse widths after the last write [us]
            self.since_ns = [self.clock()] * CHANNELS  # when each began (clock) [ns]

    # -- the RegisterEmulator interface --------------------------------------------------------
    def read(self, register: int, length: int) -> bytes:
        """``length`` bytes from ``register`` (auto-increment per MODE1.AI)."""
        self._stall()
        with self.lock:
            out = bytearray()
            for r in self._pointers(register, length):
                value = 0 if ALL_LED_ON_L <= r < PRE_SCALE else self.regs[r]
                out.append(value ^ 0x5A if self.corrupt else value)
            self.transfers += 1
            self.bytes += length
            return bytes(out)

    def write(self, register: int, data: bytes) -> None:
        """Take ``data`` from ``register`` on (auto-increment per MODE1.AI)."""
        self._stall()
        with self.lock:
            for r, value in zip(self._pointers(register, len(data)), data):
                self._write_one(r, value)
            self.transfers += 1
            self.bytes += len(data)
        self._note_outputs()

    def _note_outputs(self) -> None:
        """Note when each channel's pulse width changed.

        The chip outputs a pulse from the write on, whether or not anyone samples it: an ESC
        arms on the neutral it has seen since then.
        """
        now = self.clock()
        for c in range(CHANNELS):
            pulse = self.pulse_us(c)
            if pulse != self.outputs[c]:
                self.outputs[c] = pulse
                self.since_ns[c] = now

    def _stall(self) -> None:
        if self.stall_time > 0.0:
            time.sleep(self.stall_time)
            raise OSError(errno.ETIMEDOUT, 'Connection timed out')

    def _pointers(self, register: int, length: int) -> list[int]:
        if not self.regs[MODE1] & AI:
            return [register] * length
        out, r = [], register
        for _ in range(length):
            out.append(r)
            r = 0 if r in (LAST_LED, PRE_SCALE, 0xFF) else (r + 1) & 0xFF
        return out

    def _write_one(self, r: int, value: int) -> None:
        if r == MODE1:
            self._write_mode1(value)
        elif r == PRE_SCALE:
            if self.regs[MODE1] & SLEEP:
                self.regs[PRE_SCALE] = value
            else:
                self.prescale_blocked += 1
        elif LED0_ON_L <= r <= LAST_LED:
            self.regs[r] = value
            self._led_written()
        elif ALL_LED_ON_L <= r < PRE_SCALE:
            for c in range(CHANNELS):
                self.regs[LED0_ON_L + 4 * c + (r - ALL_LED_ON_L)] = value
            self._led_written()
        elif r != 0xFF:   # 0xFF: TestMode, reserved
            self.regs[r] = value

    def _led_written(self) -> None:
        if not self.regs[MODE1] & SLEEP:
            self.running = True
            self.regs[MODE1] &= ~RESTART & 0xFF

    def _write_mode1(self, value: int) -> None:
        old = self.regs[MODE1]
        new = (value & ~RESTART & 0xFF) | (old & RESTART)
        if value & SLEEP and not old & SLEEP:        # going to sleep
            if self.running:
                new |= RESTART
            self.running = False
        if old & SLEEP and not value & SLEEP:        # waking: oscillator starts
            self._awake_ns = self.clock()
        if value & RESTART and old & RESTART and not new & SLEEP:
            if self.clock() - self._awake_ns < WAKE_DELAY * 1e9:
                self.early_restart += 1
            else:
                new &= ~RESTART & 0xFF
                self.running = True
        self.regs[MODE1] = new

    # -- what the chip outputs -----------------------------------------------------------------
    @property
    def prescale(self) -> int:
        """PRE_SCALE now."""
        return self.regs[PRE_SCALE]

    @property
    def period_us(self) -> float:
        """PWM period [us]."""
        return COUNTS * (max(self.prescale, PRESCALE_MIN) + 1) / self.oscillator * 1e6

    def pulse_us(self, channel: int) -> float:
        """Pulse width [us] that ``channel`` outputs now; 0 when it outputs no pulse."""
        with self.lock:
            if self.regs[MODE1] & SLEEP or not self._oscillating():
                return 0.0
            base = LED0_ON_L + 4 * channel
            on_l, on_h, off_l, off_h = self.regs[base:base + 4]
        if off_h & FULL or on_h & FULL:
            return 0.0   # constant low or high: no pulse an ESC could read
        counts = ((((off_h & 0x0F) << 8) | off_l) - (((on_h & 0x0F) << 8) | on_l)) % COUNTS
        return counts * (max(self.prescale, PRESCALE_MIN) + 1) / self.oscillator * 1e6

    def _oscillating(self) -> bool:
        # Outputs run once started after the last wake (RESTART or an LED write) or when
        # nothing ran before the sleep (a first configuration), 500 us after waking.
        if self.clock() - self._awake_ns < WAKE_DELAY * 1e9:
            return False
        return self.running or not self.regs[MODE1] & RESTART


class WrongDevice:
    """Another chip at the address: answers, but holds nothing that is written."""

    def __init__(self, value: int = 0xFF) -> None:
        self.value = value

    def read(self, register: int, length: int) -> bytes:
        """Return the same byte everywhere."""
        return bytes([self.value] * length)

    def write(self, register: int, data: bytes) -> None:
        """Ignored."""


@dataclass(frozen=True)
class EscSpec:
    """One ESC and its thruster."""

    neutral: float        # [us]
    dead_band: float      # [us] half width
    min: float            # full reverse [us]
    max: float            # full forward [us]
    arming_time: float    # neutral held this long arms it [s]
    signal_timeout: float  # no pulse this long disarms it [s]
    max_forward: float    # thrust at max [N]
    max_reverse: float    # thrust magnitude at min [N]
    reversed: bool        # the propeller pushes the other way for the same pulse


class EscModel:
    """An ESC fed one pulse width per update; see the module docstring."""

    def __init__(self, spec: EscSpec) -> None:
        self.spec = spec
        self.armed = False
        self.beeps = 0              # updates with a drive pulse while unarmed
        self._neutral_since: float | None = None
        self._signal_at: float | None = None

    def update(self, pulse_us: float, now: float, since: float | None = None) -> float:
        """Thrust [N] at ``now`` [s] for ``pulse_us`` (0: no pulse), output since ``since``.

        ``since`` [s, same clock]: when the chip began to output this pulse width (the ESC
        saw it from then on, however rarely the emulator samples); None: from ``now``.
        """
        s = self.spec
        if pulse_us <= 0.0:
            self._neutral_since = None
            if self._signal_at is not None and now - self._signal_at >= s.signal_timeout:
                self.armed = False
            return 0.0
        self._signal_at = now
        if abs(pulse_us - s.neutral) <= s.dead_band:
            if self._neutral_since is None:
                self._neutral_since = now if since is None else min(since, now)
            if now - self._neutral_since >= s.arming_time:
                self.armed = True
            return 0.0
        self._neutral_since = None
        if not self.armed:
            self.beeps += 1
            return 0.0
        if pulse_us > s.neutral:
            low = s.neutral + s.dead_band
            f = s.max_forward * min(1.0, (pulse_us - low) / (s.max - low))
        else:
            high = s.neutral - s.dead_band
            f = -s.max_reverse * min(1.0, (high - pulse_us) / (high - s.min))
        return -f if s.reversed else f


SPECS = [
    ParamSpec('name', 'default', "Emulated bus name (drivers use bus 'emulated:<name>')",
              read_only=True),
    ParamSpec('address', DEFAULT_ADDRESS, 'I2C address of the emulated chip', '', 0x03, 0x77,
              read_only=True),
    ParamSpec('oscillator', OSCILLATOR, 'True oscillator frequency of the emulated chip',
              'Hz', 20e6, 30e6, read_only=True),
    ParamSpec('rate', 100.0, 'Rate of sim/thrust and emulator/pca9685', 'Hz', 1.0, 1000.0,
              read_only=True),
    ParamSpec('esc.neutral', 1500.0, 'ESC stop pulse', 'us', 500.0, 2500.0, read_only=True),
    ParamSpec('esc.dead_band', 25.0, 'ESC dead band half width', 'us', 0.0, 200.0,
              read_only=True),
    ParamSpec('esc.min', 1100.0, 'ESC full reverse pulse', 'us', 500.0, 2500.0,
              read_only=True),
    ParamSpec('esc.max', 1900.0, 'ESC full forward pulse', 'us', 500.0, 2500.0,
              read_only=True),
    ParamSpec('esc.arming_time', 1.0, 'Neutral held this long arms an ESC', 's', 0.0, 30.0,
              read_only=True),
    ParamSpec('esc.signal_timeout', 3.0, 'No pulse this long disarms an ESC', 's', 0.0, 60.0,
              read_only=True),
    ParamSpec('servo.channel', -1, 'Channel of a servo whose pulse the report shows (-1: none)',
              '', -1, CHANNELS - 1, read_only=True),
]


@dataclass(frozen=True)
class EmulatorSettings:
    """Settings of ``Pca9685EmulatorNode``."""

    name: str
    address: int
    oscillator: float
    rate: float
    channels: tuple[int, ...]
    escs: tuple[EscSpec, ...]
    servo_channel: int = -1


class Pca9685EmulatorNode(EnbarrNode):
    """See the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'pca9685_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.thrusters = declare_thrusters(self)
        self.names = [t.name for t in self.thrusters]
        specs = [ParamSpec(f'pca9685.channels.{n}', 0, f'PCA9685 channel of thruster {n}',
                           '', 0, CHANNELS - 1, read_only=True, required=True)
                 for n in self.names]
        specs += [ParamSpec(f'pca9685.pulse.{n}.reversed', False, f'Thruster {n} pushes the '
                            'other way for the same pulse', read_only=True) for n in self.names]
        self.settings: EmulatorSettings = SettingsBinding(
            self, SPECS + specs, self._build, lambda s: None).settings
        s = self.settings
        self.chip = Pca9685Emulator(s.oscillator)
        self.escs = [EscModel(e) for e in s.escs]
        self.bus: FakeI2cBus | None = None   # the shared emulated bus, once started
        self.thrust = np.zeros(len(self.names))
        self.pulses = np.zeros(len(self.names))
        self._thrust_pub = self.create_topic_publisher(topics.SIM_THRUST)
        self._pulse_pub = self.create_topic_publisher(EMULATOR_PCA9685)
        self.loop = self.create_rate_loop(s.rate, self.tick)
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Put the chip on the shared emulated bus, then start publishing its outputs.

        The chip is plugged in here, not in the constructor: a profile check builds the node
        and must leave no bus behind. It stays plugged in until the node is destroyed (the
        drivers write their neutral pulses after every node has stopped).
        """
        if self.bus is None:
            self.bus = emulation.plug_i2c(self.settings.name, {self.settings.address: self.chip})
        super().start()

    def _build(self, v: dict[str, Any]) -> EmulatorSettings:
        channels = tuple(v[f'pca9685.channels.{n}'] for n in self.names)
        if len(set(channels)) != len(channels):
            raise ValueError(f'pca9685.channels: two thrusters on one channel: {channels}')
        if not v['esc.min'] < v['esc.neutral'] - v['esc.dead_band'] \
                <= v['esc.neutral'] + v['esc.dead_band'] < v['esc.max']:
            raise ValueError('esc: need min < neutral - dead_band <= neutral + dead_band < max')
        escs = tuple(EscSpec(v['esc.neutral'], v['esc.dead_band'], v['esc.min'], v['esc.max'],
                             v['esc.arming_time'], v['esc.signal_timeout'], t.max_forward,
                             t.max_reverse, v[f'pca9685.pulse.{t.name}.reversed'])
                     for t in self.thrusters)
        if v['servo.channel'] in channels:
            raise ValueError(f'servo.channel: {v["servo.channel"]} is a thruster channel')
        return EmulatorSettings(v['name'], v['address'], v['oscillator'], v['rate'], channels,
                                escs, v['servo.channel'])

    def tick(self) -> None:
        """Decode the pulses, run the ESCs, publish thrust and pulses (the bridge's source)."""
        now = time.monotonic()
        channels = self.settings.channels
        self.pulses = np.array([self.chip.pulse_us(c) for c in channels])
        since = [self.chip.since_ns[c] * 1e-9 for c in channels]
        self.thrust = np.array([esc.update(p, now, t)
                                for esc, p, t in zip(self.escs, self.pulses, since)])
        stamp = convert.ns_to_stamp(self.now_ns())
        thrust = JointState(name=self.names, effort=self.thrust.tolist())
        thrust.header.stamp = stamp
        thrust.header.frame_id = topics.BODY_FRAME
        self._thrust_pub.publish(thrust)
        pulses = JointState(name=self.names, position=self.pulses.tolist())
        pulses.header.stamp = stamp
        pulses.header.frame_id = topics.BODY_FRAME
        self._pulse_pub.publish(pulses)

    def servo_pulse(self) -> float:
        """Pulse width [us] on the servo's channel (0: no pulse, NaN: no servo)."""
        channel = self.settings.servo_channel
        return self.chip.pulse_us(channel) if channel >= 0 else float('nan')

    def _report(self) -> None:
        if not self.started:
            return
        c = self.chip
        servo = ({'servo_pulse_us': f'{self.servo_pulse():.0f}'}
                 if self.settings.servo_channel >= 0 else {})
        self.publish_diagnostics(0, 'emulating a PCA9685', {
            'bus': f'emulated:{self.settings.name}', 'address': f'0x{self.settings.address:02x}',
            'transfers': c.transfers, 'bytes': c.bytes, 'prescale': c.prescale,
            'prescale_blocked': c.prescale_blocked, 'early_restart': c.early_restart,
            'armed': sum(e.armed for e in self.escs), 'beeps': sum(e.beeps for e in self.escs),
            'pulses_us': ' '.join(f'{p:.0f}' for p in self.pulses), **servo})

    def destroy_node(self) -> None:
        """Publish the outputs once more, unplug the chip, withdraw the bus if it is empty.

        The last report shows the drivers' safe state (bringup destroys emulators after the
        drivers, before the recorders).
        """
        bus, self.bus = self.bus, None
        if bus is not None:
            if not self.loop.running:
                try:
                    self.tick()
                except Exception as err:  # noqa: BLE001 - the unplugging must still happen
                    self.get_logger().warn(f'last output report failed: {err!r}')
            emulation.unplug_i2c(self.settings.name, bus, {self.settings.address: self.chip})
        super().destroy_node()


def start_check_emulator(bus: str, address: int) -> Callable[[], None]:
    """For ``enbarr check-device pca9685 --bus emulated``: a chip on the emulated bus.

    Uses the emulator of this process if one runs; else attaches a power-on chip on a new bus.
    Returns the clean-up to call afterwards.
    """
    name = emulation.emulator_name(bus)
    fake: FakeI2cBus = emulation.get_or_create('i2c', name, FakeI2cBus)
    if address in fake.devices:
        return lambda: None
    chip = fake.attach(address, Pca9685Emulator())
    return lambda: emulation.unplug_i2c(name, fake, {address: chip})
