"""Keyboard teleoperation: an operator at a terminal drives the ROV.

A surface station in a pinch. Keys change the velocity goal in steps; the goal is sent at
``rate`` with a fresh stamp, so when the operator stops the node (or the terminal goes away)
the command receiver's failsafe stops the vehicle.

    w / s   surge ahead / astern        a / d   sway left / right
    r / f   heave up / down             q / e   yaw left / right
    space   all stop                    l       lights on / off (``lights_executor``)
    m / n   manipulator +/- ``manipulator_step`` steps (``manipulator_executor``)

The terminal is ``device`` (default: this process's standard input when it is a terminal),
switched to cbreak mode while the node runs and restored when it is destroyed. Ctrl-C stops
the run (cbreak mode keeps it a signal), and with it the commands: the failsafe stops the
vehicle.

What the keys command is shown on the terminal's last line (``status_line``): the velocity
goal, the lights, the manipulator steps asked for, and how to quit. The lines above it scroll
on their own (a VT100 scrolling region), so the simulator's or the drivers' log lines pass
above the status line instead of breaking it; the region is reset when the node is destroyed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import fcntl
import os
import select
import struct
import termios
import threading
import tty
from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics

_AXES = {'w': (0, 1), 's': (0, -1), 'a': (1, 1), 'd': (1, -1), 'r': (2, 1), 'f': (2, -1),
         'q': (5, 1), 'e': (5, -1)}


@dataclass(frozen=True)
class KeyState:
    """Velocity goal [u, v, w, p, q, r] and the io state the keys have built up."""

    nu: tuple[float, ...] = (0.0,) * 6
    lights: bool = False
    manipulator: int = 0   # net manipulator key presses (m: +1, n: -1) since the start


def apply_key(state: KeyState, key: str, linear_step: float, angular_step: float,
              max_linear: float, max_angular: float) -> tuple[KeyState, tuple[str, Any] | None]:
    """Return the state after ``key``, and an io request (executor role, value) if any.

    Velocities stay within +/- the maxima; unknown keys change nothing.
    """
    if key == ' ':
        return replace(state, nu=(0.0,) * 6), None
    if key == 'l':
        new = replace(state, lights=not state.lights)
        return new, ('lights', new.lights)
    if key in ('m', 'n'):
        sign = 1 if key == 'm' else -1
        return replace(state, manipulator=state.manipulator + sign), ('manipulator', sign)
    if key in _AXES:
        i, sign = _AXES[key]
        step, limit = (linear_step, max_linear) if i < 3 else (angular_step, max_angular)
        nu = list(state.nu)
        nu[i] = round(max(-limit, min(limit, nu[i] + sign * step)), 9)
        return replace(state, nu=tuple(nu)), None
    return state, None


#: How to quit, as the status line says it.
QUIT_HINT = 'Ctrl-C quits'


def status_line(state: KeyState, manipulator_step: int, width: int = 0) -> str:
    """Return what the keys command, one line: goal, lights, manipulator, how to quit.

    ``width`` > 0 cuts the line to that many characters (a terminal's columns): a line that
    wrapped would push the one above out of place on every redraw.
    """
    u, v, w, _, _, r = state.nu
    line = (f'goal u {u:+.2f} v {v:+.2f} w {w:+.2f} m/s r {r:+.2f} rad/s | '
            f'lights {"on" if state.lights else "off"} | '
            f'manipulator {state.manipulator * manipulator_step:+d} steps | {QUIT_HINT}')
    return line[:width] if width > 0 else line


# VT100 control sequences (DEC VT100 User Guide, ANSI X3.64): the status line's.
SAVE_CURSOR = '\x1b7'          # DECSC
RESTORE_CURSOR = '\x1b8'       # DECRC
CLEAR_LINE = '\x1b[2K'         # EL 2: the whole line
RESET_REGION = '\x1b[r'        # DECSTBM without arguments: the whole screen scrolls


def set_region(last_row: int) -> str:
    """DECSTBM: rows 1 to ``last_row`` scroll; the rows below stay where they are."""
    return f'\x1b[1;{last_row}r'


def move_to(row: int) -> str:
    """CUP: the cursor to the first column of ``row`` (1-based)."""
    return f'\x1b[{row};1H'


def terminal_size(fd: int) -> tuple[int, int]:
    """(rows, columns) of the terminal ``fd``, (0, 0) when it does not say."""
    try:
        rows, cols, _, _ = struct.unpack('HHHH', fcntl.ioctl(fd, termios.TIOCGWINSZ,
                                                             bytes(8)))
    except OSError:
        return 0, 0
    return rows, cols


class StatusLine:
    """The terminal's last row kept for one line of status; the rows above scroll.

    ``draw`` redraws it (cheap: one write); a change of the terminal's size moves the region.
    A terminal that gives no size (or too few rows) gets the line redrawn in place with
    a carriage return instead, which log lines may then break until the next redraw.
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.rows = 0   # the rows the scrolling region was set for (0: none set)

    def _write(self, text: str) -> None:
        try:
            os.write(self.fd, text.encode())
        except OSError:  # the terminal went away: the reader notices and stops
            pass

    def draw(self, line: str) -> None:
        """Show ``line`` on the last row (cut to the terminal's width)."""
        rows, cols = terminal_size(self.fd)
        line = line[:cols - 1] if cols > 1 else line
        if rows < 3:
            self._write(f'\r{CLEAR_LINE}{line}')
            return
        out = ''
        if rows != self.rows:
            # Make room for the status row, then keep the cursor where it was in the region
            # (DECSTBM homes the cursor).
            out += f'\n{SAVE_CURSOR}{set_region(rows - 1)}{RESTORE_CURSOR}\x1b[1A'
            self.rows = rows
        self._write(f'{out}{SAVE_CURSOR}{move_to(rows)}{CLEAR_LINE}{line}{RESTORE_CURSOR}')

    def close(self) -> None:
        """Give the whole screen back to scrolling and clear the status row."""
        if self.rows:
            self._write(f'{SAVE_CURSOR}{RESET_REGION}{RESTORE_CURSOR}'
                        f'{SAVE_CURSOR}{move_to(self.rows)}{CLEAR_LINE}{RESTORE_CURSOR}')
            self.rows = 0
        else:
            self._write(f'\r{CLEAR_LINE}')


SPECS = [
    ParamSpec('device', '', 'Terminal to read keys from; empty: standard input', read_only=True),
    ParamSpec('rate', 10.0, 'Rate at which the goal is sent', 'Hz', 1.0, 100.0,
              read_only=True),
    ParamSpec('linear_step', 0.05, 'Velocity change per key press', 'm/s', 1e-3, 1.0),
    ParamSpec('angular_step', 0.1, 'Yaw rate change per key press', 'rad/s', 1e-3, 2.0),
    ParamSpec('max_linear', 0.5, 'Largest linear velocity goal', 'm/s', 0.0, 5.0),
    ParamSpec('max_angular', 0.5, 'Largest yaw rate goal', 'rad/s', 0.0, 5.0),
    ParamSpec('lights_executor', 'gpio_12', 'Executor of the lights'),
    ParamSpec('manipulator_executor', 'manipulator', 'Executor of the manipulator'),
    ParamSpec('manipulator_step', 50, 'Steps per manipulator key press', 'steps', 1, 100000),
]


@dataclass(frozen=True)
class KeyboardTeleopSettings:
    """Settings of ``KeyboardTeleopNode`` (see ``SPECS``)."""

    device: str                # terminal to read ('' : standard input)
    rate: float                # goal sending rate [Hz]
    linear_step: float         # [m/s] per key press
    angular_step: float        # [rad/s] per key press
    max_linear: float          # [m/s]
    max_angular: float         # [rad/s]
    lights_executor: str
    manipulator_executor: str
    manipulator_step: int      # [steps] per key press

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> KeyboardTeleopSettings:
        """Build from the declared parameters' values."""
        return cls(**{name: v[name] for name in cls.__dataclass_fields__})


class KeyboardTeleopNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'keyboard', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: KeyboardTeleopSettings
        self.bind_settings(SPECS, KeyboardTeleopSettings.from_params, self._apply)
        if not self.settings.device and not os.isatty(0):  # a check can tell without opening
            raise ConfigurationError(self._not_a_terminal('not a tty'), parameter='device')
        self._fd = -1  # the terminal is opened at start: constructing opens nothing
        self._status: StatusLine | None = None
        self._saved: list[Any] = []
        self.state = KeyState()
        self._twist_pub = self.create_topic_publisher(topics.SURFACE_TWIST)
        self._io_pub = self.create_topic_publisher(topics.SURFACE_IO)
        self.create_source_timer(1.0 / self.settings.rate, self._send)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name='keyboard', daemon=True)

    def _apply(self, settings: KeyboardTeleopSettings) -> None:
        self.settings = settings

    def _not_a_terminal(self, why: object) -> str:
        return (f'node {self.get_name()!r}: {self.settings.device or "standard input"} is not '
                f'a terminal ({why}); run bringup in a terminal or set device')

    def start(self) -> None:
        """Open the terminal, switch it to cbreak mode and start reading keys."""
        device = self.settings.device
        try:
            self._fd = os.open(device, os.O_RDONLY | os.O_NOCTTY) if device else os.dup(0)
            self._saved = termios.tcgetattr(self._fd)
        except (OSError, termios.error) as err:
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1
            raise ConfigurationError(self._not_a_terminal(err), parameter='device') from err
        super().start()
        tty.setcbreak(self._fd)
        self.get_logger().info('keys: w/s surge, a/d sway, r/f heave, q/e yaw, space stop, '
                               f'l lights, m/n manipulator; {QUIT_HINT}')
        out = self._open_output()
        if out >= 0:
            self._status = StatusLine(out)
            self._draw()
        self._thread.start()

    def _open_output(self) -> int:
        """Open the terminal the status line is written to: ``device``, or standard output."""
        try:
            if self.settings.device:
                return os.open(self.settings.device, os.O_WRONLY | os.O_NOCTTY)
            return os.dup(1) if os.isatty(1) else -1
        except OSError as err:  # the keys still work: only the status line is missing
            self.get_logger().warn(f'no status line: {err.strerror}')
            return -1

    def _draw(self) -> None:
        if self._status is not None:
            self._status.draw(status_line(self.state, self.settings.manipulator_step))

    def _read(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd], [], [], 0.1)
            if not ready:
                continue
            try:
                data = os.read(self._fd, 32)
            except OSError:  # EIO: the terminal went away
                data = b''
            if not data:  # the terminal closed: stop sending, the failsafe takes over
                self.get_logger().warn('keyboard closed: no more commands')
                self._stop.set()
                return
            for key in data.decode(errors='ignore'):
                self.on_key(key)

    def on_key(self, key: str) -> None:
        """Apply one key press and send the new goal at once."""
        s = self.settings
        self.state, io = apply_key(self.state, key.lower(), s.linear_step, s.angular_step,
                                   s.max_linear, s.max_angular)
        if io is not None:
            role, value = io
            executor = s.lights_executor if role == 'lights' else s.manipulator_executor
            value = value * s.manipulator_step if role == 'manipulator' else value
            self._io_pub.publish(Parameter(
                name=executor, value=convert.python_to_parameter_value(value)))
        self._send()

    def _send(self) -> None:
        if self._stop.is_set():
            return
        msg = TwistStamped()
        convert.ns_to_stamp(self.now_ns(), msg.header.stamp)
        msg.header.frame_id = topics.BODY_FRAME
        convert.set_twist(msg.twist, self.state.nu)
        self._twist_pub.publish(msg)
        self._draw()  # at the send rate: a resized or cleared terminal gets it back

    def destroy_node(self) -> None:
        """Stop reading, restore the terminal, then destroy the node."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        if self._status is not None:
            self._status.close()
            os.close(self._status.fd)
            self._status = None
        if self._fd >= 0:
            try:
                termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
                os.close(self._fd)
            except (OSError, termios.error):
                pass
        super().destroy_node()
