"""Keyboard teleoperation: the key rules (pure) and the node reading a real pseudo-terminal."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
import fcntl
import os
import struct
import termios
from typing import Any

import pytest
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_plugins.operator.keyboard import KeyboardTeleopNode, KeyState, StatusLine, \
    apply_key, status_line
from support.cli import enbarr, refused
from support.nodes import add, probe
from support.waiting import poll_until

STEPS = (0.05, 0.1, 0.5, 0.5)  # linear_step, angular_step, max_linear, max_angular


def press(state: KeyState, keys: str) -> tuple[KeyState, Any]:
    """The state after ``keys`` and the io request of the last one."""
    io = None
    for key in keys:
        state, io = apply_key(state, key, *STEPS)
    return state, io


# -- the key rules (pure) ----------------------------------------------------------------------
def test_keys_step_and_saturate():
    s = KeyState()
    for _ in range(20):
        s, io = apply_key(s, 'w', *STEPS)
        assert io is None
    assert s.nu[0] == 0.5  # saturated at max_linear


def test_heave_and_yaw_keys_step_their_axes():
    s, _ = press(KeyState(), 'wwwwwwwwwwef')
    assert s.nu == (0.5, 0.0, -0.05, 0.0, 0.0, -0.1)


def test_unknown_key_changes_nothing():
    s, _ = press(KeyState(), 'wwwwwwwwwwef')
    after, io = apply_key(s, 'x', *STEPS)
    assert after.nu == (0.5, 0.0, -0.05, 0.0, 0.0, -0.1) and io is None


def test_space_stops():
    s, _ = press(KeyState(), 'wwef ')
    assert s.nu == (0.0,) * 6


def test_lights_key_toggles_and_requests():
    s, io = press(KeyState(), 'l')
    assert s.lights and io == ('lights', True)
    s, io = press(s, 'l')
    assert not s.lights and io == ('lights', False)


def test_manipulator_keys_request_steps():
    assert press(KeyState(), 'n')[1] == ('manipulator', -1)


# -- what the operator sees (pure) -------------------------------------------------------------
def test_the_status_line_shows_the_goal_the_lights_the_manipulator_and_how_to_quit():
    s, _ = press(KeyState(), 'wwrqqlmmmn')
    assert status_line(s, 50) == ('goal u +0.10 v +0.00 w +0.05 m/s r +0.20 rad/s | '
                                  'lights on | manipulator +100 steps | Ctrl-C quits')


def test_the_status_line_after_all_stop_and_astern():
    s, _ = press(KeyState(), 'wwl ssdenn')
    assert status_line(s, 10) == ('goal u -0.10 v -0.05 w +0.00 m/s r -0.10 rad/s | '
                                  'lights on | manipulator -20 steps | Ctrl-C quits')


def test_the_status_line_is_cut_to_the_terminal_width():
    assert status_line(KeyState(), 50, width=20) == 'goal u +0.00 v +0.00'


# -- the node on a pseudo-terminal -------------------------------------------------------------
@dataclass
class Terminal:
    """The keyboard node reading a pseudo-terminal, and what a probe heard from it."""

    node: KeyboardTeleopNode
    master: int
    twists: list[list[float]] = field(default_factory=list)
    ios: list[tuple[str, object]] = field(default_factory=list)

    def type(self, keys: bytes) -> None:
        os.write(self.master, keys)


    def screen(self) -> str:
        """What the node wrote to the terminal since the last call."""
        out = b''
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except BlockingIOError:
                return out.decode(errors='replace')
            out += chunk


@pytest.fixture
def terminal(context, executor) -> Iterator[Terminal]:
    master, slave = os.openpty()
    # A 24 x 100 terminal (struct winsize: rows, columns, x and y pixels)
    fcntl.ioctl(master, termios.TIOCSWINSZ, struct.pack('HHHH', 24, 100, 0, 0))
    os.set_blocking(master, False)
    t: Terminal | None = None
    try:
        node = add(executor, KeyboardTeleopNode(
            node_name='keyboard', context=context,
            parameter_overrides=[Parameter('device', value=os.ttyname(slave))]))
        t = Terminal(node, master)
        listener = probe(context, executor)
        listener.create_subscription(
            TwistStamped, topics.SURFACE_TWIST.name,
            lambda m: t.twists.append(list(convert.twist_to_nu(m.twist))),
            topics.SURFACE_TWIST.qos)
        listener.create_subscription(ParameterMsg, topics.SURFACE_IO.name, lambda m: t.ios.append(
            (m.name, convert.parameter_value_to_python(m.value))), topics.SURFACE_IO.qos)
        node.start()
        yield t
    finally:
        if t is None or t.master >= 0:
            os.close(master)
        os.close(slave)


def test_node_sends_the_twist_of_the_keys(terminal, executor, spin):
    terminal.type(b'ww')
    assert spin(executor, lambda: terminal.twists
                and terminal.twists[-1][0] == pytest.approx(0.1), 10.0)


def test_node_sends_io_requests(terminal, executor, spin):
    terminal.type(b'lm')
    assert spin(executor, lambda: ('gpio_12', True) in terminal.ios
                and ('manipulator', 50) in terminal.ios, 10.0)


def test_node_space_stops(terminal, executor, spin):
    terminal.type(b'ww')
    assert spin(executor, lambda: terminal.twists and terminal.twists[-1][0] > 0.0, 10.0)
    terminal.type(b' ')
    assert spin(executor, lambda: terminal.twists[-1] == [0.0] * 6, 10.0)


def test_node_shows_what_it_commands_on_the_last_row_below_a_scrolling_region(
        terminal, executor, spin):
    seen: list[str] = []
    # The status row, drawn at CUP (CSI 24;1 H) after the cursor is saved (ESC 7) and then
    # restored (ESC 8)
    status = ('\x1b7\x1b[24;1H\x1b[2Kgoal u +0.10 v +0.00 w +0.00 m/s r +0.00 rad/s | '
              'lights on | manipulator +0 steps | Ctrl-C quits\x1b8')
    terminal.type(b'wwl')
    assert spin(executor, lambda: seen.append(terminal.screen()) or status in ''.join(seen),
                10.0), ''.join(seen)
    # DECSTBM (CSI 1;23 r): rows 1-23 scroll, so log lines pass above row 24
    assert '\x1b[1;23r' in ''.join(seen)
    executor.remove_node(terminal.node)
    terminal.node.destroy_node()
    # the whole screen scrolls again (DECSTBM without arguments), the status row cleared; the
    # pty hands the writes over asynchronously: read until the last one is there
    after: list[str] = []
    closed = '\x1b7\x1b[r\x1b8\x1b7\x1b[24;1H\x1b[2K\x1b8'
    assert poll_until(lambda: after.append(terminal.screen()) or ''.join(after).endswith(closed),
                      10.0), ''.join(after)


def test_the_status_line_gives_the_screen_back_when_closed():
    master, slave = os.openpty()
    try:
        fcntl.ioctl(master, termios.TIOCSWINSZ, struct.pack('HHHH', 30, 80, 0, 0))
        status = StatusLine(slave)
        status.draw('x' * 200)
        status.close()
        os.set_blocking(master, False)
        chunks: list[bytes] = []

        def read_all() -> bool:  # the pty hands the writes over asynchronously
            try:
                chunks.append(os.read(master, 4096))
            except BlockingIOError:
                pass
            return b''.join(chunks).endswith(b'\x1b[2K\x1b8')
        poll_until(read_all, 10.0)
        shown = b''.join(chunks).decode()
        assert '\x1b[1;29r' in shown and 'x' * 79 + '\x1b8' in shown  # cut to 79 columns
        # DECSTBM with no arguments: the whole screen scrolls again; the status row cleared
        assert shown.endswith('\x1b7\x1b[r\x1b8\x1b7\x1b[30;1H\x1b[2K\x1b8')
    finally:
        os.close(master)
        os.close(slave)


def test_node_stops_when_the_terminal_goes_away(terminal, executor, spin):
    os.close(terminal.master)  # the terminal goes away: the node stops sending
    terminal.master = -1
    assert spin(executor, lambda: terminal.node._stop.is_set(), 10.0)


def test_not_a_terminal_is_a_clear_error_at_start_and_constructing_opens_nothing(context):
    node = KeyboardTeleopNode(node_name='keyboard', context=context, parameter_overrides=[
        Parameter('device', value='/dev/null')])
    try:
        assert node._fd == -1  # a check builds the node: the terminal is not touched
        with pytest.raises(ConfigurationError, match='/dev/null is not a terminal'):
            node.start()
        assert node._fd == -1 and not node.started
    finally:
        node.destroy_node()


@pytest.mark.e2e  # the command line, in a process
def test_teleop_profile_without_a_terminal_is_refused():
    line = refused(enbarr('bringup', '--profile', 'enbarr_teleop', '--check', timeout=120))
    assert 'nodes.keyboard' in line and 'is not a terminal' in line
