"""Driver of the Arduino Mega PWM board over USB serial (the CS Saucer's ESCs and servos).

The CS Saucer's Raspberry Pi sends duty cycles to an Arduino Mega over USB, which drives the
three azimuth motor drives (Torpedo 800) and the three azimuth servos at 4.3-9.4 % duty,
50 Hz (CS Saucer manual, Table 1.1 and section 3.2.4). ``ArduinoPwmNode`` takes
``pwm/duty_cycle`` with the checks its simulated twin makes (``arduino/common.py``: label,
size, the profile's duty limits, the command-rate rule) and sends them to the board's firmware
(``firmware/enbarr_arduino``) in the framed protocol of ``firmware/enbarr_arduino/link.h``
(``arduino/protocol.py``; frame of ``transport/serial_link.py``: 0xA5 | LEN | TYPE SEQ BODY |
CRC-16/CCITT-FALSE), documented again in ``docs/hardware.md``.

The device is named by ``port`` (its stable name
``/dev/serial/by-id/usb-Arduino__www.arduino.cc__0042_<serial>-if00``, or ``/dev/ttyACM0``, or
``emulated[:NAME]`` for the emulator of ``arduino/emulator.py``, looked up again at every
reconnection). Constructing the node opens nothing (opening the port resets a Mega through
DTR): ``start()`` does. Device I/O runs on the session's two threads, never on the executor or
the chain thread:

- the **writer** waits quietly for the board's boot HELLO (the Mega resets when the port
  opens, DTR; bytes sent into its bootloader would keep it there), then sends HELLO_REQ
  until a HELLO comes (``hello_timeout``), checks the identity (protocol version, board id,
  channel count: a wrong one is a ``DeviceError`` naming the port and what was read), sends
  CONFIG (duty limits and neutral duties from the profile, the board's own watchdog
  timeout ``board_timeout``), then the latest command (latest wins; resent until the board
  acknowledges it) and a HEARTBEAT every ``heartbeat_period`` in between;
- the **reader** decodes the board's HELLO and STATUS frames; CRC errors, truncated,
  malformed and out-of-order (board sequence not newer) frames are refused and counted. A
  HELLO after the handshake means that the board reset: counted, configured again, the
  latest command sent again.

Faults reach the node as ``DeviceError`` (port unplugged: read/write errors; stalled: no
STATUS for ``reply_timeout``; wrong identity; no HELLO) and ``supervise`` hands them to
``device_fault``: outputs neutral, port closed, reconnect with backoff. The firmware puts
the outputs neutral on its own when frames stop for ``board_timeout`` (the driver killed or
paused, the cable pulled), and this node sends neutral on ``safe_state`` and when duties
stop for ``command_timeout``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import threading
import time
from typing import Any

from std_msgs.msg import Float64MultiArray

from enbarr_core.allocation.layout_params import AZIMUTHS, pwm_layout_specs, PwmLayout
from enbarr_core.framework.driver import ActuatorDriver, WARN
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.health import OK, worst
from enbarr_core.framework.params import ParamSpec, refuse_live_value
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.arduino.common import DutyInput
from enbarr_plugins.arduino.protocol import (
    CHANNELS, config_body, config_problem, CONFIG, DEFAULT_DUTY_MAX, DEFAULT_DUTY_MIN,
    DEFAULT_NEUTRAL, DEFAULT_TIMEOUT_MS, duty_body, Hello, HEARTBEAT, HELLO_REQ, newer, parse,
    ProtocolError, RESULT_OK, RESULTS, SET_DUTY, Status, to_units)
from enbarr_plugins.transport.serial_link import open_serial, SerialLink


# -- the session: the two I/O threads --------------------------------------------------------
@dataclass(frozen=True)
class LinkSettings:
    """Timing and configuration of a session with the board."""

    heartbeat_period: float = 0.05   # [s]
    reply_timeout: float = 0.5       # [s] no STATUS this long: stalled
    boot_wait: float = 2.5           # [s] quiet wait for the boot HELLO after opening
    hello_timeout: float = 5.0       # [s] longest wait for a HELLO
    board_timeout_ms: int = DEFAULT_TIMEOUT_MS
    duty_min: int = DEFAULT_DUTY_MIN
    duty_max: int = DEFAULT_DUTY_MAX
    neutral: tuple[int, ...] = (DEFAULT_NEUTRAL,) * CHANNELS

    def __post_init__(self) -> None:
        """Refuse a configuration the board would refuse (``config_problem``) before sending."""
        problem = config_problem(self.duty_min, self.duty_max, self.board_timeout_ms,
                                 self.neutral)
        if problem:
            raise ValueError(problem)


class BoardSession:
    """One open connection to the board: handshake, commands, heartbeats, replies.

    ``start()`` runs the writer and reader threads; ``set_command()`` hands the latest duties
    (never blocks); ``fault`` is set (and ``on_fault`` called, on the I/O thread) when the
    link fails; ``stop()`` ends the threads (sending the latest command once more when the
    link works) and closes the port.
    """

    def __init__(self, link: SerialLink, settings: LinkSettings, name: str,
                 on_fault: Callable[[DeviceError], None] | None = None) -> None:
        self.link = link
        self.settings = settings
        self.name = name
        self.on_fault = on_fault
        self.hello: Hello | None = None
        self.fault: DeviceError | None = None
        self.ready = threading.Event()
        self.last_status: Status | None = None
        self.sent = 0
        self.acked = 0
        self.refused_by_board = 0
        self.statuses = 0
        self.out_of_order = 0
        self.malformed = 0
        self.board_resets = 0
        self._cond = threading.Condition()
        self._stop = False
        self._seq = 0
        self._board_seq: int | None = None
        self._hellos = 0
        self._last_reply_ns = 0
        self._command: tuple[int, ...] = settings.neutral
        self._command_id = 0
        self._confirmed_id = -1
        self._pending: dict[int, int] = {}   # seq of a SET_DUTY -> its command id
        self._acks: dict[int, Status] = {}
        self._reconfigure = False
        self._threads = [threading.Thread(target=self._writer, name=f'{name}_writer',
                                          daemon=True),
                         threading.Thread(target=self._reader, name=f'{name}_reader',
                                          daemon=True)]

    # -- API ----------------------------------------------------------------------------------
    def start(self) -> None:
        """Start the I/O threads."""
        for t in self._threads:
            t.start()

    def set_command(self, units: Sequence[int]) -> None:
        """Hand the latest duties [0.01 %] to the writer (latest wins)."""
        with self._cond:
            self._command = tuple(units)
            self._command_id += 1
            self._cond.notify_all()

    @property
    def confirmed(self) -> bool:
        """Whether the board acknowledged the latest command."""
        return self._confirmed_id == self._command_id

    def wait(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Wait until ``condition()`` or a fault, at most ``timeout`` [s]; return the condition."""
        with self._cond:
            self._cond.wait_for(lambda: condition() or self.fault is not None, timeout)
            return condition()

    def stop(self) -> None:
        """End the threads and close the port (bounded: the reader's read is cancelled)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        cancel = getattr(self.link.serial, 'cancel_read', None)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # noqa: BLE001 - a dead port may refuse anything
                pass
        for t in self._threads:
            if t.is_alive() and t is not threading.current_thread():
                t.join(timeout=1.0)
        self.link.close()

    # -- threads ------------------------------------------------------------------------------
    def _fail(self, err: DeviceError) -> None:
        with self._cond:
            if self.fault is not None or self._stop:
                return
            self.fault = err
            self._cond.notify_all()
        if self.on_fault is not None:
            self.on_fault(err)

    def _send(self, kind: int, body: bytes = b'') -> int:
        with self._cond:
            self._seq = (self._seq + 1) & 0xFF
            seq = self._seq
        self.link.write_frame(bytes([kind, seq]) + body)
        self.sent += 1
        return seq

    def _wait(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Wait (lock held by the caller's ``with``) until condition, stop or timeout."""
        self._cond.wait_for(lambda: self._stop or condition(), timeout)
        return condition() and not self._stop

    def _handshake(self) -> Hello:
        s = self.settings
        t0 = time.monotonic()
        with self._cond:
            self._wait(lambda: self._hellos > 0, s.boot_wait)  # quiet: the bootloader runs
        while not self._stop:
            with self._cond:
                before = self._hellos
            self._send(HELLO_REQ)
            left = s.hello_timeout - (time.monotonic() - t0)
            with self._cond:
                if self._wait(lambda: self._hellos > before, max(0.0, min(0.5, left))):
                    hello = self.hello
                    assert hello is not None
                    self._last_reply_ns = time.monotonic_ns()
                    return hello
            if time.monotonic() - t0 >= s.hello_timeout:
                d = self.link.decoder
                raise DeviceError(
                    f'{self.name}: no HELLO from the board within {s.hello_timeout:g} s '
                    f'({d.frames} frames, {d.garbage} stray bytes, {d.crc_errors} CRC errors '
                    'received); is the Enbarr firmware flashed (docs/hardware.md)?')
        raise DeviceError(f'{self.name}: stopped')

    def _request(self, kind: int, body: bytes, what: str) -> Status:
        seq = self._send(kind, body)
        with self._cond:
            if not self._wait(lambda: seq in self._acks, self.settings.reply_timeout):
                raise DeviceError(f'{self.name}: no answer to {what} within '
                                  f'{self.settings.reply_timeout:g} s')
            status = self._acks.pop(seq)
        if status.result != RESULT_OK:
            raise DeviceError(f'{self.name}: the board refused {what}: '
                              f'{RESULTS.get(status.result, status.result)}')
        return status

    def _configure(self) -> None:
        s = self.settings
        self._request(CONFIG, config_body(s.duty_min, s.duty_max, s.board_timeout_ms,
                                          s.neutral), 'CONFIG')

    def _check(self, hello: Hello) -> None:
        problem = hello.problem()
        if problem:
            raise DeviceError(f'{self.name}: {problem}')

    def _writer(self) -> None:
        try:
            self._check(self._handshake())
            self._configure()
            self.ready.set()
            self._serve()
        except DeviceError as err:
            self._fail(err)
        except Exception as err:  # noqa: BLE001 - any surprise is a link fault, not a crash
            self._fail(DeviceError(f'{self.name}: writer failed: {err!r}'))

    def _serve(self) -> None:
        s = self.settings
        period_ns = int(s.heartbeat_period * 1e9)
        last_send_ns = 0
        sent_id = -1
        while True:
            with self._cond:
                now = time.monotonic_ns()
                wait = max(0.0, (last_send_ns + period_ns - now) * 1e-9)
                self._cond.wait_for(lambda: self._stop or self._reconfigure
                                    or self._command_id != sent_id, wait)
                if self._stop:
                    break
                reconfigure, self._reconfigure = self._reconfigure, False
                command, command_id = self._command, self._command_id
                confirmed = self._confirmed_id == command_id
            if reconfigure:  # the board reset: its identity, configuration, duties again
                assert self.hello is not None
                self._check(self.hello)
                self._configure()
                sent_id = -1
            now = time.monotonic_ns()
            due = now - last_send_ns >= period_ns
            if command_id != sent_id or (not confirmed and due):
                seq = self._send(SET_DUTY, duty_body(command))
                with self._cond:
                    self._pending[seq] = command_id
                    if len(self._pending) > 64:
                        self._pending.pop(next(iter(self._pending)))
                sent_id, last_send_ns = command_id, now
            elif due:
                self._send(HEARTBEAT)
                last_send_ns = now
            silent = (time.monotonic_ns() - self._last_reply_ns) * 1e-9
            if silent > s.reply_timeout:
                raise DeviceError(f'{self.name}: stalled: no STATUS for {silent:.2f} s '
                                  f'({self.sent} frames sent, last reply '
                                  f'{self._describe_last()})')
        with self._cond:
            command, confirmed = self._command, self.confirmed
        if self.fault is None and not confirmed:
            try:  # the last word (neutral on shutdown): best effort, bounded by write_timeout
                self._send(SET_DUTY, duty_body(command))
            except DeviceError:
                pass

    def _describe_last(self) -> str:
        last = self.last_status
        return 'none' if last is None else f'seq {last.seq} acking {last.acked}'

    def _reader(self) -> None:
        try:
            while not self._stop:
                payloads = self.link.read_frames()
                for payload in payloads:
                    self._receive(payload)
        except DeviceError as err:
            self._fail(err)
        except Exception as err:  # noqa: BLE001 - any surprise is a link fault, not a crash
            self._fail(DeviceError(f'{self.name}: reader failed: {err!r}'))

    def _receive(self, payload: bytes) -> None:
        try:
            msg = parse(payload)
        except ProtocolError:
            self.malformed += 1
            return
        with self._cond:
            if isinstance(msg, Hello):
                self._board_seq = msg.seq  # a reset restarts the board's sequence
                self._hellos += 1
                self.hello = msg
                if self.ready.is_set():
                    self.board_resets += 1
                    self._reconfigure = True
                self._cond.notify_all()
                return
            if self._board_seq is not None and not newer(msg.seq, self._board_seq):
                self.out_of_order += 1
                return
            self._board_seq = msg.seq
            self._last_reply_ns = time.monotonic_ns()
            self.statuses += 1
            self.last_status = msg
            self._acks[msg.acked] = msg
            if len(self._acks) > 16:
                self._acks.pop(next(iter(self._acks)))
            command_id = self._pending.pop(msg.acked, None)
            if msg.result == RESULT_OK:
                self.acked += 1
                if command_id is not None and command_id == self._command_id:
                    self._confirmed_id = command_id
            else:
                self.refused_by_board += 1
            self._cond.notify_all()

    def counters(self) -> dict[str, Any]:
        """Link counters for ``/diagnostics``."""
        d = self.link.decoder
        out: dict[str, Any] = {
            'ready': self.ready.is_set(), 'sent': self.sent, 'acked': self.acked,
            'refused_by_board': self.refused_by_board, 'crc_errors': d.crc_errors,
            'truncated': d.truncated, 'garbage_bytes': d.garbage,
            'out_of_order': self.out_of_order, 'malformed': self.malformed,
            'board_resets': self.board_resets}
        last = self.last_status
        if last is not None:
            out.update({'board_neutral': last.neutral,
                        'board_watchdog_trips': last.watchdog_trips,
                        'board_crc_errors': last.crc_errors,
                        'board_seq_errors': last.seq_errors,
                        'board_refused': last.refused, 'board_truncated': last.truncated})
        if self.hello is not None:
            out['board_boot_count'] = self.hello.boot_count
        return out

    def error_count(self) -> int:
        """Sum of the link errors both ends counted (for 'errors since last report')."""
        d = self.link.decoder
        last = self.last_status
        board = 0 if last is None else last.crc_errors + last.seq_errors + last.truncated
        return (d.crc_errors + d.truncated + self.out_of_order + self.malformed
                + self.board_resets + board)


# -- the node ---------------------------------------------------------------------------------
LINK_SPECS = [
    ParamSpec('port', '/dev/ttyACM0', 'Serial port of the Arduino: its /dev/serial/by-id/... '
              'link (survives a re-plug; /dev/ttyACMn may change), or '
              "'emulated[:NAME]' for the emulator in this process", read_only=True),
    ParamSpec('baud', 115200, 'Serial speed (the firmware uses 115200)', 'baud', 1200,
              2000000, read_only=True),
    ParamSpec('heartbeat_period', 0.05, 'A HEARTBEAT when no command was sent for this long',
              's', 0.005, 1.0, read_only=True),
    ParamSpec('board_timeout', 0.25, "The board's own watchdog: outputs neutral when no frame "
              'comes for this long', 's', 0.02, 10.0, read_only=True),
    ParamSpec('reply_timeout', 0.5, 'Stalled (a device fault) when no STATUS comes for this '
              'long', 's', 0.02, 10.0, read_only=True),
    ParamSpec('boot_wait', 2.5, 'After opening the port, wait this long for the boot HELLO '
              'before asking (the Mega resets on open; bytes would hold its bootloader)',
              's', 0.0, 30.0, read_only=True),
    ParamSpec('hello_timeout', 5.0, 'Longest wait for the HELLO after opening the port', 's',
              0.05, 60.0, read_only=True),
]

#: How long link errors keep the status at WARN [s].
ERROR_MEMORY = 5.0


@dataclass(frozen=True)
class ArduinoPwmSettings:
    """Settings of ``ArduinoPwmNode`` (read only)."""

    layout: PwmLayout
    port: str
    baud: int
    link: LinkSettings

    @classmethod
    def from_params(cls, names: Sequence[str], v: Mapping[str, Any]) -> ArduinoPwmSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        layout = PwmLayout.from_params(names, v)
        azimuths, c = layout.azimuths, layout.calibration
        if 2 * len(azimuths) != CHANNELS:
            raise ValueError(f'azimuth_names: the board drives {CHANNELS // 2} azimuths '
                             f'(motor and servo each), got {len(azimuths)}')
        if not v['port']:
            raise ValueError('port: a serial port (/dev/serial/by-id/usb-Arduino...) or '
                             "'emulated' is needed")
        if v['board_timeout'] < 2.0 * v['heartbeat_period']:
            raise ValueError(f"board_timeout: {v['board_timeout']} s is shorter than two "
                             f"heartbeat_period ({v['heartbeat_period']} s): the board would "
                             'go neutral between heartbeats')
        if v['reply_timeout'] < 2.0 * v['heartbeat_period']:
            raise ValueError(f"reply_timeout: {v['reply_timeout']} s is shorter than two "
                             f"heartbeat_period ({v['heartbeat_period']} s)")
        if v['hello_timeout'] < v['boot_wait']:
            raise ValueError(f"hello_timeout: {v['hello_timeout']} s is shorter than "
                             f"boot_wait ({v['boot_wait']} s)")
        if to_units(c.duty_min_percent) < 1:
            raise ValueError(f'pwm.duty_min_percent: {c.duty_min_percent} % is below the '
                             "board's smallest duty, 0.01 % (a duty of 0 would hold its PWM "
                             'pins high; docs/hardware.md)')
        neutral = tuple(to_units(d) for _ in azimuths
                        for d in (c.neutral_thrust_duty, c.neutral_angle_duty))
        link = LinkSettings(v['heartbeat_period'], v['reply_timeout'], v['boot_wait'],
                            v['hello_timeout'], int(round(v['board_timeout'] * 1000)),
                            to_units(c.duty_min_percent), to_units(c.duty_max_percent),
                            neutral)
        return cls(layout, v['port'], v['baud'], link)


class ArduinoPwmNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'arduino', **kwargs: Any) -> None:
        self._session: BoardSession | None = None
        self._command: tuple[int, ...] | None = None
        self._neutral: tuple[int, ...] = ()
        self._fault: DeviceError | None = None
        self._fault_lock = threading.Lock()
        self._errors_seen = 0
        self._last_error_ns: int | None = None
        self._unready_faults = 0  # sessions in a row that failed before the board answered
        super().__init__(node_name, timeout_message='PWM input stopped: outputs neutral',
                         **kwargs)
        names = AZIMUTHS.names(self)
        self.settings: ArduinoPwmSettings = self.bind_settings(
            pwm_layout_specs(self, names) + LINK_SPECS,
            lambda v: ArduinoPwmSettings.from_params(names, v),
            lambda _: None).settings  # every parameter is read only
        self.names = list(names)
        self.calibration = self.settings.layout.calibration
        self.channels = CHANNELS
        self._neutral = self.settings.link.neutral
        self._command = self._neutral
        self.device = self.settings.port
        self.sessions = 0
        self.duties = DutyInput(self.calibration, CHANNELS)
        self.add_on_set_parameters_callback(
            refuse_live_value('command_timeout', self.duties.timeout_problem))
        self.create_topic_subscription(topics.PWM_DUTY, self._on_duty)

    @property
    def refused(self) -> int:
        """Duty messages refused since start."""
        return self.duties.refused

    # -- device -------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the port (looked up again when emulated) and start a session."""
        port = self.settings.port
        path = emulation.lookup('serial', port) if emulation.is_emulated(port) else port
        name = port if path == port else f'{port} ({path})'
        self.device = name
        link = SerialLink(open_serial(path, self.settings.baud, timeout=0.05,
                                      write_timeout=0.1), name)
        with self._fault_lock:
            self._fault = None
        session = BoardSession(link, self.settings.link, name, self._on_fault)
        session.set_command(self._command or self._neutral)
        self._errors_seen = 0
        self._session = session
        self.sessions += 1
        session.start()

    def close_device(self) -> None:
        """Stop the session's threads and close the port."""
        session, self._session = self._session, None
        if session is not None:
            session.stop()

    def connect(self) -> bool:
        """Open the port; the backoff keeps growing while sessions fail before the HELLO.

        The port opening is not the board answering (a wrong board, no firmware): without
        this, every retry would start again from ``reconnect.initial_delay``.
        """
        delay = self._backoff.delay
        ok = super().connect()
        if ok and self._unready_faults:
            self._backoff.delay = delay
        return ok

    def _on_fault(self, err: DeviceError) -> None:
        with self._fault_lock:  # on an I/O thread: the executor handles it in supervise()
            self._fault = err

    def supervise(self) -> None:
        """Hand a fault of the I/O threads to ``device_fault``; run the command watchdog."""
        with self._fault_lock:
            fault, self._fault = self._fault, None
        session = self._session
        if fault is not None:
            if session is not None and not session.ready.is_set():
                self._unready_faults += 1
            self.device_fault(fault)
        session = self._session
        if session is not None and session.ready.is_set() and self._unready_faults:
            self._unready_faults = 0
            self._backoff.reset()
        if session is not None:
            errors = session.error_count()
            if errors > self._errors_seen:
                self._errors_seen = errors
                self._last_error_ns = time.monotonic_ns()
                self.get_logger().warn(f'{self.device}: link errors: {session.counters()}',
                                       throttle_duration_sec=5.0)
        super().supervise()

    # -- commands -----------------------------------------------------------------------------
    def _on_duty(self, msg: Float64MultiArray) -> None:
        if not self.duties.accept(msg, self.now_ns()):  # the checks of sim_arduino
            return
        with self.commanding():
            self._set(tuple(to_units(d) for d in msg.data))

    def _set(self, units: tuple[int, ...]) -> None:
        self._command = units
        session = self._session
        if session is not None:
            session.set_command(units)

    def is_neutral(self) -> bool:
        """Return whether the command sent is every channel's neutral duty."""
        return self._command == self._neutral

    def write_neutral(self) -> None:
        """Send every channel's neutral duty (motors: no thrust, servos: angle 0)."""
        self._set(self._neutral)

    # -- status -------------------------------------------------------------------------------
    def status(self) -> tuple[int, str]:
        """Return ERROR while faulted; WARN during the handshake, on link errors or refusals."""
        level, message = super().status()
        if level != OK:
            return level, message
        session = self._session
        link = (OK, 'ok')
        if session is not None and not session.ready.is_set():
            link = (WARN, "waiting for the board's HELLO")
        elif (self._last_error_ns is not None
              and time.monotonic_ns() - self._last_error_ns < ERROR_MEMORY * 1e9):
            link = (WARN, f'link errors in the last {ERROR_MEMORY:g} s (corrupted, truncated, '
                    'out-of-order frames or a board reset: see the counters)')
        return worst((level, message), link, self.duties.status(
            self.watchdog.timeout_ns * 1e-9, self.report_problem))

    def status_values(self) -> dict[str, Any]:
        """Return the link and board counters."""
        out = {**super().status_values(), 'refused_inputs': self.refused,
               'sessions': self.sessions}
        session = self._session
        if session is not None:
            out.update(session.counters())
        return out
