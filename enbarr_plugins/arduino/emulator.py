"""Emulator of the Arduino Mega PWM board: its own firmware, compiled for the host, on a pty.

``ArduinoEmulator`` runs the board's protocol and watchdog code (``firmware/enbarr_arduino/
link.c``, built and loaded by ``arduino/firmware.py``) behind a pseudo-terminal: the driver
opens the slave path with pyserial exactly like ``/dev/ttyACM0``; the emulator's thread
serves the master side (raw mode), feeds every byte to the firmware's ``enb_rx``, ticks it
from the monotonic clock (``millis()``) and writes back what it sends. Like a Mega it resets
when the port is opened (DTR; ``reset_on_open``) and answers only after ``boot_delay``
(bytes sent meanwhile are lost, as in the bootloader).

Faults to inject (for the tests, and ``enbarr check-device``): ``unplug()`` (the pty closes:
the driver's reads fail) and ``replug()`` (a new pty, a new path, the board powered up
again); ``corrupt_replies(n)`` and ``truncate_replies(n)`` (bits flipped in, or the tail cut
off, the next n frames the board sends); ``replay_replies(n)`` (the previous STATUS sent
again: an out-of-order frame); ``stall()``/``resume()`` (no byte passes either way);
``wrong_identity(board_id, version)`` (HELLO from another board); ``reset()`` (the board
resets: outputs neutral, its sequence restarts, a HELLO).

``ArduinoEmulatorNode`` (registry name ``arduino_emulator``) wraps one for a profile: when it
starts (constructing it opens nothing) it opens the pty and registers its path with
``enbarr_plugins.emulation`` as serial endpoint ``name``; it turns the board's output duties
into ``sim/azimuth_command`` through the profile's PWM calibration exactly as ``arduino/sim.py``
does (so ``saucer_emulated`` flies the simulated vessel), publishes the duties on
``emulator/arduino`` (``sensor_msgs/JointState``: channel names, position = duty [%]) every
PWM period (50 Hz) while the board is powered, and reports the board's counters on
``/diagnostics``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import os
import select
import threading
import time
import tty
from typing import Any

from sensor_msgs.msg import JointState

from enbarr_core.allocation.layout_params import AZIMUTHS, pwm_layout_specs, PwmLayout
from enbarr_core.framework.driver import REPORT_PERIOD
from enbarr_core.framework.health import OK, DEGRADED
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_interfaces.topics import SENSOR_QOS, TopicSpec
from enbarr_plugins import emulation
from enbarr_plugins.arduino.firmware import Board, defines
from enbarr_plugins.transport.serial_link import encode_frame

#: What the emulated board outputs: one entry per channel, position = duty [%].
EMULATOR_OUTPUT = TopicSpec(
    'emulator/arduino', JointState, SENSOR_QOS, 'duty cycle %', '',
    'Duty cycle the emulated Arduino outputs on each channel (name: <azimuth>/motor, '
    '<azimuth>/servo; position: duty %), every PWM period (50 Hz) while powered. A link '
    "topic: a recorder in the process takes it at once, the drivers' safe state included.",
    fast=True)

PWM_PERIOD = 0.02  # [s] 50 Hz
SKETCH_CHUNK = 32  # bytes the sketch's loop() takes from Serial before it sends the replies
UNITS_PER_PERCENT = 100  # link.h: duties travel in units of 0.01 %


def _now_ms() -> int:
    return time.monotonic_ns() // 1_000_000


class ArduinoEmulator:
    """The board behind a pty; see the module docstring.

    ``on_output(duties_percent)`` is called on the emulator's thread every PWM period while
    the board is powered.
    """

    def __init__(self, *, reset_on_open: bool = True, boot_delay: float = 0.05,
                 on_output: Callable[[list[float]], None] | None = None,
                 record: bool = False) -> None:
        self.reset_on_open = reset_on_open
        self.boot_delay = boot_delay
        self.on_output = on_output
        self.board = Board(_now_ms())
        self.boot_count = 1
        self.path: str | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.frames_out = 0
        self.resets = 0
        self.lost_bytes = 0  # received while booting or stalled
        self.dropped_bytes = 0  # sent while the driver did not read (the line buffer full)
        #: Every byte received from the driver (when ``record``, for tests: it only grows).
        self.received: bytearray | None = bytearray() if record else None
        self._lock = threading.RLock()
        self._master: int | None = None
        self._port_open = False
        self._booting_until = 0
        self._corrupt = 0
        self._truncate = 0
        self._replay = 0
        self._stalled = False
        self._identity: tuple[int, int] | None = None
        self._last_status: bytes | None = None
        self._running = False
        self._thread: threading.Thread | None = None
        self._poll = select.poll()

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty and serve it; return the slave path the driver opens."""
        with self._lock:
            path = self._open_pty()
            self._running = True
        self._thread = threading.Thread(target=self._run, name='arduino_emulator',
                                        daemon=True)
        self._thread.start()
        return path

    def stop(self) -> None:
        """Stop serving and close the pty."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        with self._lock:
            self._close_pty()

    def _open_pty(self) -> str:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing before pyserial configures it
        tty.setraw(master)
        self.path = os.ttyname(slave)
        os.close(slave)  # the master sees POLLHUP until a driver opens the slave
        os.set_blocking(master, False)  # a driver that stops reading must not hang the board
        self._master = master
        self._poll = select.poll()
        self._poll.register(master, select.POLLIN)
        self._port_open = False
        return self.path

    def _close_pty(self) -> None:
        if self._master is not None:
            try:
                os.close(self._master)
            except OSError:
                pass
            self._master = None

    # -- faults -------------------------------------------------------------------------------
    def reset(self) -> None:
        """Reset the board: outputs neutral, sequence restarts, HELLO after ``boot_delay``."""
        with self._lock:
            self._reset_board()

    def _reset_board(self) -> None:
        self.boot_count += 1
        self.resets += 1
        now = _now_ms()
        self.board.reset(now, self.boot_count, 0x02)  # MCUSR EXTRF: reset by DTR
        self._booting_until = now + int(self.boot_delay * 1000)
        self._last_status = None

    def unplug(self) -> None:
        """Pull the USB cable: the pty closes, the board loses power."""
        with self._lock:
            self._close_pty()
            self.path = None

    def replug(self) -> str:
        """Plug it in again: a new pty (a new path), the board powered up; the new path."""
        with self._lock:
            self._close_pty()
            path = self._open_pty()
            self.board.reset(_now_ms(), self.boot_count + 1, 0x01)  # PORF: power on
            self.boot_count += 1
            self._booting_until = _now_ms() + int(self.boot_delay * 1000)
        return path

    def corrupt_replies(self, n: int = 1) -> None:
        """Flip one bit in each of the next ``n`` frames the board sends."""
        with self._lock:
            self._corrupt += n

    def truncate_replies(self, n: int = 1) -> None:
        """Cut off the second half of each of the next ``n`` frames the board sends."""
        with self._lock:
            self._truncate += n

    def replay_replies(self, n: int = 1) -> None:
        """Send the previous STATUS again after each of the next ``n`` ones (out of order)."""
        with self._lock:
            self._replay += n

    def clear_faults(self) -> None:
        """Stop every injected reply fault (corruption, truncation, replay, stall, identity)."""
        with self._lock:
            self._corrupt = self._truncate = self._replay = 0
            self._stalled = False
            self._identity = None

    def stall(self) -> None:
        """Stop passing bytes in either direction (a hung USB-serial bridge)."""
        with self._lock:
            self._stalled = True

    def resume(self) -> None:
        """Pass bytes again after ``stall``."""
        with self._lock:
            self._stalled = False

    def wrong_identity(self, board_id: int = 0x1234, version: int | None = None) -> None:
        """Answer HELLO as another board (``board_id``, protocol ``version``)."""
        with self._lock:
            self._identity = (board_id, defines()['ENB_PROTOCOL_VERSION'] if version is None
                              else version)

    def right_identity(self) -> None:
        """Answer HELLO as the Enbarr board again."""
        with self._lock:
            self._identity = None

    # -- state --------------------------------------------------------------------------------
    @property
    def powered(self) -> bool:
        """Whether the board has power (its pty exists)."""
        return self._master is not None

    def duties(self) -> list[float]:
        """Output duty of each channel [%]."""
        with self._lock:
            return [u / UNITS_PER_PERCENT for u in self.board.duties()]

    @property
    def neutral(self) -> bool:
        """Whether the board's outputs are all at their neutral duty."""
        with self._lock:
            return bool(self.board.flags & defines()['ENB_FLAG_NEUTRAL'])

    def counters(self) -> dict[str, int]:
        """Return the board's counters and the emulator's own."""
        with self._lock:
            return {**self.board.counters(), 'bytes_out': self.bytes_out,
                    'frames_out': self.frames_out, 'resets': self.resets,
                    'lost_bytes': self.lost_bytes, 'dropped_bytes': self.dropped_bytes,
                    'boot_count': self.boot_count}

    # -- the serving thread -------------------------------------------------------------------
    def _run(self) -> None:
        next_pwm = time.monotonic()
        while self._running:
            with self._lock:
                master = self._master
                poll = self._poll
            if master is None:
                time.sleep(0.01)
                next_pwm = time.monotonic()
                continue
            try:
                events = poll.poll(5)
            except (OSError, ValueError):
                continue
            hup = any(e & select.POLLHUP for _, e in events)
            readable = any(e & select.POLLIN for _, e in events)
            duties = None
            with self._lock:
                if master != self._master:
                    continue
                now = _now_ms()
                if hup:
                    self._port_open = False
                elif not self._port_open:
                    self._port_open = True
                    if self.reset_on_open:
                        self._reset_board()
                if readable:
                    self._read(master, now)
                self.board.tick(now)
                if now >= self._booting_until and not self._stalled and self._port_open:
                    self._write(master, self.board.tx())
                elif self._stalled:
                    self.board.tx()  # what the board sends is lost in the stalled bridge
                if time.monotonic() >= next_pwm:
                    next_pwm = max(next_pwm + PWM_PERIOD, time.monotonic() - PWM_PERIOD)
                    duties = [u / UNITS_PER_PERCENT for u in self.board.duties()]
            if hup:
                time.sleep(0.01)  # nobody has the port open: poll returns at once
            if duties is not None and self.on_output is not None:
                try:
                    self.on_output(duties)
                except Exception:  # noqa: BLE001 - a publisher during shutdown
                    pass

    def _read(self, master: int, now: int) -> None:
        try:
            data = os.read(master, 4096)
        except OSError:
            return
        self.bytes_in += len(data)
        if self.received is not None:
            self.received += data
        if self._stalled or now < self._booting_until:
            self.lost_bytes += len(data)
            return
        for i in range(0, len(data), SKETCH_CHUNK):  # as the sketch's loop() does
            self.board.rx(data[i:i + SKETCH_CHUNK], now)
            if self._port_open:
                self._write(master, self.board.tx())

    def _write(self, master: int, data: bytes) -> None:
        out = bytearray()
        i = 0
        while i + 1 < len(data):  # the board sends whole frames: 0xA5 LEN ... CRC CRC
            n = data[i + 1] + 4
            out += self._fault(bytes(data[i:i + n]))
            i += n
        if not out:
            return
        try:
            n = os.write(master, bytes(out))
        except BlockingIOError:
            n = 0
        except OSError:
            return
        self.bytes_out += n
        self.dropped_bytes += len(out) - n

    def _fault(self, frame: bytes) -> bytes:
        self.frames_out += 1
        payload = frame[2:-2]
        extra = b''
        hello, status = defines()['ENB_HELLO'], defines()['ENB_STATUS']
        if payload[:1] == bytes([hello]) and self._identity is not None:
            board_id, version = self._identity
            body = bytearray(payload)
            body[2] = version
            body[3:5] = board_id.to_bytes(2, 'big')
            frame = encode_frame(bytes(body))
        if payload[:1] == bytes([status]):
            if self._replay and self._last_status is not None:
                self._replay -= 1
                extra = self._last_status
            self._last_status = frame
        if self._corrupt:
            self._corrupt -= 1
            b = bytearray(frame)
            b[3] ^= 0x10  # a bit of the payload (the sequence number)
            frame = bytes(b)
        elif self._truncate:
            self._truncate -= 1
            frame = frame[:len(frame) // 2]
        return frame + extra


EMULATOR_SPECS = [
    ParamSpec('name', 'default', "Name under which the driver finds it: port 'emulated' "
              "(default) or 'emulated:NAME'", read_only=True),
    ParamSpec('boot_delay', 0.05, 'The board answers this long after the port opens (a Mega '
              'boots in 1-2 s)', 's', 0.0, 10.0, read_only=True),
    ParamSpec('reset_on_open', True, 'Reset the board when the port opens (DTR)',
              read_only=True),
]


@dataclass(frozen=True)
class ArduinoEmulatorSettings:
    """Settings of ``ArduinoEmulatorNode`` (read only)."""

    layout: PwmLayout
    name: str
    boot_delay: float   # [s]
    reset_on_open: bool

    @classmethod
    def from_params(cls, names: Sequence[str], v: Mapping[str, Any]) -> ArduinoEmulatorSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        layout = PwmLayout.from_params(names, v)
        azimuths = layout.azimuths
        channels = defines()['ENB_CHANNELS']
        if 2 * len(azimuths) != channels:
            raise ValueError(f'azimuth_names: the board drives {channels // 2} '
                             f'azimuths (motor and servo each), got {len(azimuths)}')
        if not v['name'] or ':' in v['name']:
            raise ValueError(f"name: a word without ':', got {v['name']!r}")
        return cls(layout, v['name'], v['boot_delay'], v['reset_on_open'])


class ArduinoEmulatorNode(EnbarrNode):
    """See the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'arduino_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        names = AZIMUTHS.names(self)
        self.settings: ArduinoEmulatorSettings = self.bind_settings(
            pwm_layout_specs(self, names) + EMULATOR_SPECS,
            lambda v: ArduinoEmulatorSettings.from_params(names, v),
            lambda _: None).settings  # every parameter is read only
        self.calibration = self.settings.layout.calibration
        self.name = self.settings.name
        self.names = list(names)
        self.channel_names = self.settings.layout.channels
        self._sim_pub = self.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
        self._out_pub = self.create_topic_publisher(EMULATOR_OUTPUT)
        self.emulator = ArduinoEmulator(reset_on_open=self.settings.reset_on_open,
                                        boot_delay=self.settings.boot_delay,
                                        on_output=self._on_output)
        self._registered: str | None = None
        self._serving = False
        self._last_trips = 0
        self.create_periodic(REPORT_PERIOD, self._report)

    def start(self) -> None:
        """Open the pty, serve it and register its path (once), then start the sources.

        Bringup starts the emulators before the drivers, so the driver finds the path when it
        opens its port.
        """
        if not self._serving:
            self._serving = True
            self._register(self.emulator.start())
        super().start()

    def _register(self, path: str) -> None:
        self._registered = path
        emulation.register('serial', self.name, path, owner=self)

    def unplug(self) -> None:
        """Pull the cable (the registered path goes away)."""
        if self._registered is not None:
            emulation.unregister('serial', self.name, self._registered)
            self._registered = None
        self.emulator.unplug()

    def replug(self) -> str:
        """Plug the cable in again: a new pty registered under the same name."""
        path = self.emulator.replug()
        self._register(path)
        return path

    def _on_output(self, duties: list[float]) -> None:
        c = self.calibration
        stamp = self.get_clock().now().to_msg()
        out = JointState(name=self.channel_names, position=list(duties))
        out.header.stamp = stamp
        self._out_pub.publish(out)
        cmd = JointState(name=self.names, effort=[c.duty_to_thrust(d) for d in duties[0::2]],
                         position=[c.duty_to_angle(d) for d in duties[1::2]])
        cmd.header.stamp = stamp
        self._sim_pub.publish(cmd)

    def _report(self) -> None:
        counters = self.emulator.counters()
        level, message = OK, 'ok'
        trips = counters['watchdog_trips']
        if trips > self._last_trips:
            level, message = DEGRADED, 'the board watchdog put the outputs neutral'
        self._last_trips = trips
        if not self.emulator.powered:
            level, message = DEGRADED, 'unplugged'
        self.publish_diagnostics(level, message, {
            'path': self.emulator.path, 'neutral': self.emulator.neutral,
            'duties': ' '.join(f'{d:.2f}' for d in self.emulator.duties()), **counters})

    def destroy_node(self) -> None:
        """Stop the emulator and withdraw its endpoint."""
        if self._registered is not None:
            emulation.unregister('serial', self.name, self._registered)
            self._registered = None
        self.emulator.stop()
        super().destroy_node()
