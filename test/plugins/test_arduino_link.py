"""Node tests: the arduino_pwm driver against the board's own firmware (host build) on a pty.

Every fault of the board and its link in docs/hardware.md is injected by the emulator
(enbarr_plugins/arduino/emulator.py); the driver must report it, put the outputs neutral,
reconnect with backoff and resume.
"""

from __future__ import annotations

from dataclasses import dataclass
import itertools
import os
import struct
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from support.nodes import add, probe, TIMEOUT
from support.saucer import duty_msg, NAMES, overrides

from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins import emulation
from enbarr_plugins.arduino import link
from enbarr_plugins.arduino.emulator import (
    ArduinoEmulator, ArduinoEmulatorNode, EMULATOR_OUTPUT)
from enbarr_plugins.arduino.link import ArduinoPwmNode, LinkSettings
from enbarr_plugins.transport.serial_link import crc16_ccitt_false, FrameDecoder

# Message types of firmware/enbarr_arduino/link.h, typed from it (not read from the driver).
HELLO_REQ, SET_DUTY, HEARTBEAT, CONFIG = 0x01, 0x02, 0x03, 0x04
BOARD_ID = 0x4D45

GOOD = [8.2, 9.4] * len(NAMES)           # motor 0.6 N, servo 1.98968 rad on every azimuth
OTHER = [6.0, 5.0, 7.5, 8.0, 4.3, 6.85]
NEUTRAL = [6.85] * 6
_names = itertools.count()


@dataclass
class Emu:
    board: ArduinoEmulator
    name: str

    @property
    def port(self) -> str:
        return f'emulated:{self.name}'

    def unplug(self) -> None:
        emulation.unregister('serial', self.name)
        self.board.unplug()

    def replug(self) -> None:
        emulation.register('serial', self.name, self.board.replug())

    def applied(self, duties: list[float]) -> bool:
        return self.board.duties() == pytest.approx(duties, abs=1e-9)


@pytest.fixture
def emu():
    e = Emu(ArduinoEmulator(record=True), f'link{next(_names)}')
    emulation.register('serial', e.name, e.board.start())
    yield e
    emulation.unregister('serial', e.name)
    e.board.stop()


@dataclass
class Rig:
    node: ArduinoPwmNode
    pub: Any

    def send(self, duties: list[float]) -> None:
        self.pub.publish(duty_msg(duties))


def driver(context: Any, executor: Any, port: str, **extra: Any) -> Rig:
    params = {'port': port, 'command_timeout': 10.0, 'reconnect.initial_delay': 0.05,
              'reconnect.max_delay': 0.2, 'boot_wait': 0.3, 'hello_timeout': 2.0, **extra}
    node = add(executor, ArduinoPwmNode(node_name='arduino', context=context,
                                        parameter_overrides=overrides(params)))
    pub = probe(context, executor, 'pwm').create_topic_publisher(topics.PWM_DUTY)
    LinkBus.of(context).connect()
    node.start()  # opens the port: the board resets (DTR) and the session begins
    return Rig(node, pub)


def ready(node: ArduinoPwmNode) -> bool:
    session = node._session
    return node.connected and session is not None and session.ready.is_set()


def drive(spin: Any, executor: Any, rig: Rig, emu: Emu, duties: list[float]) -> None:
    """Send ``duties`` until the board outputs them (a reconnecting driver drops none)."""
    assert spin(executor, lambda: ready(rig.node), TIMEOUT), rig.node.last_fault
    rig.send(duties)
    assert spin(executor, lambda: emu.applied(duties), TIMEOUT), emu.board.duties()


def test_duties_reach_the_board_as_set_duty_frames(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    payloads = FrameDecoder().feed(bytes(emu.board.received))
    kinds = [p[0] for p in payloads]
    # The session: HELLO_REQ, CONFIG from the profile, neutral duties, then the command.
    assert kinds[:3] == [HELLO_REQ, CONFIG, SET_DUTY], kinds[:5]
    assert payloads[1][2:] == struct.pack('>9H', 430, 940, 250, *[685] * 6)
    assert payloads[2][2:] == struct.pack('>6H', *[685] * 6)
    duty = next(p for p in payloads if p[0] == SET_DUTY and p[2:] != payloads[2][2:])
    body = struct.pack('>6H', 820, 940, 820, 940, 820, 940)
    assert duty[2:] == body
    head = bytes([len(duty)]) + duty
    frame = bytes([0xA5]) + head + crc16_ccitt_false(head).to_bytes(2, 'big')
    assert frame in emu.board.received  # the exact bytes on the wire
    seqs = [p[1] for p in payloads]
    assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:]))  # one counter, no gaps
    assert emu.board.counters()['seq_errors'] == 0 and r.node.faults == 0


def test_heartbeats_keep_the_board_alive_without_commands(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    diag = statuses(context, executor)
    drive(spin, executor, r, emu, GOOD)
    sent = r.node._session.sent
    assert spin(executor, lambda: r.node._session.sent >= sent + 10, TIMEOUT)
    kinds = [p[0] for p in FrameDecoder().feed(bytes(emu.board.received))]
    assert kinds[-5:] == [HEARTBEAT] * 5
    assert emu.applied(GOOD) and emu.board.counters()['watchdog_trips'] == 0
    # /diagnostics carries the link counters of both ends.
    assert spin(executor, lambda: diag and diag[-1].level == DiagnosticStatus.OK
                and int({v.key: v.value for v in diag[-1].values}.get('acked', 0)) > 0,
                TIMEOUT)
    values = {v.key: v.value for v in diag[-1].values}
    for key in ('sent', 'crc_errors', 'out_of_order', 'board_watchdog_trips',
                'board_crc_errors', 'board_seq_errors', 'board_resets'):
        assert key in values, key
    assert values['device'] == f'{emu.port} ({emu.board.path})'


def test_the_board_goes_neutral_on_its_own_when_the_driver_dies(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    # The driver's I/O stops dead (a killed or paused process): no neutral frame is sent.
    session = r.node._session
    session.link.serial.close = lambda: None   # keep the port open, like a paused process
    r.node._session = None
    with session._cond:
        session._stop = True
        session.fault = DeviceError('paused')  # no last word
        session._cond.notify_all()
    assert spin(executor, lambda: emu.board.neutral, TIMEOUT)
    assert emu.board.counters()['watchdog_trips'] == 1
    type(session.link.serial).close(session.link.serial)


def test_host_watchdog_sends_neutral_when_duties_stop(context, executor, spin, emu):
    r = driver(context, executor, emu.port, command_timeout=0.2)
    drive(spin, executor, r, emu, GOOD)
    assert spin(executor, lambda: r.node.timeouts == 1, TIMEOUT)
    assert spin(executor, lambda: emu.applied(NEUTRAL), TIMEOUT)
    # The host said neutral; heartbeats go on, so the board's own watchdog never tripped.
    assert emu.board.counters()['watchdog_trips'] == 0 and r.node.is_neutral()


def test_safe_state_and_shutdown_send_neutral(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    r.node.safe_state()
    executor.remove_node(r.node)
    r.node.destroy_node()  # right after: the last word must still reach the board
    assert spin(executor, lambda: emu.applied(NEUTRAL), TIMEOUT)
    assert emu.board.counters()['watchdog_trips'] == 0


def test_refuses_duties_like_the_sim_twin(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    bad = Float64MultiArray(data=OTHER)
    bad.layout.dim = [MultiArrayDimension(label='effort', size=6, stride=6)]
    r.pub.publish(bad)
    for d in (4.2, 9.5, float('nan')):
        r.send([d] + GOOD[1:])
    assert r.node.refused == 4
    drive(spin, executor, r, emu, OTHER)  # the next good one goes through
    assert emu.board.counters()['refused'] == 0  # nothing bad reached the board


def test_absent_at_start_then_plugged_in(context, executor, spin):
    name = f'late{next(_names)}'
    r = driver(context, executor, f'emulated:{name}')
    assert not r.node.connected and 'no serial emulator' in r.node.last_fault
    level, message = r.node.status()
    assert level == 2 and f'emulated:{name}' in message
    board = ArduinoEmulator()
    try:
        emulation.register('serial', name, board.start())
        drive(spin, executor, r, Emu(board, name), GOOD)
        assert r.node.faults >= 1
    finally:
        emulation.unregister('serial', name)
        board.stop()


def statuses(context: Any, executor: Any) -> list[DiagnosticStatus]:
    out: list[DiagnosticStatus] = []
    probe(context, executor, 'diag').create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS.name, lambda m: out.extend(
            s for s in m.status if s.hardware_id == 'arduino'), topics.DIAGNOSTICS.qos)
    return out


def test_unplugged_and_replugged(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    diag = statuses(context, executor)
    drive(spin, executor, r, emu, GOOD)
    first_path = emu.board.path
    emu.unplug()
    assert spin(executor, lambda: not r.node.connected, TIMEOUT)
    assert r.node.is_neutral()  # safe state
    assert first_path in r.node.last_fault and 'failed' in r.node.last_fault, r.node.last_fault
    spin(executor, lambda: r.node.faults >= 3, TIMEOUT)  # retries meanwhile, backing off
    assert r.node.status()[0] == 2
    assert spin(executor, lambda: any(
        s.level == DiagnosticStatus.ERROR and emu.port in s.message for s in diag), TIMEOUT)
    values = {v.key: v.value for v in diag[-1].values}
    assert values['connected'] == 'False' and values['neutral'] == 'True'
    spare = os.openpty()  # holds the old pty number: the board comes back under another
    try:
        emu.replug()  # a new pty: the driver must look the path up again
        assert emu.board.path != first_path
        drive(spin, executor, r, emu, OTHER)
    finally:
        os.close(spare[0])
        os.close(spare[1])
    assert r.node.connected and r.node.status()[0] == 0


def test_occasional_corrupted_truncated_and_replayed_replies_are_counted(
        context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    s = r.node._session
    d = s.link.decoder
    emu.board.corrupt_replies(3)
    # (at least 3: a corrupted frame's bytes may hold a 0xA5 that starts a second bad one)
    assert spin(executor, lambda: d.crc_errors >= 3, TIMEOUT), s.counters()
    emu.board.truncate_replies(2)  # cut frames: the next frame completes them, CRC fails
    assert spin(executor, lambda: d.crc_errors + d.truncated >= 5, TIMEOUT), s.counters()
    emu.board.replay_replies(2)
    assert spin(executor, lambda: s.out_of_order == 2, TIMEOUT), s.counters()
    level, message = r.node.status()
    assert level == 1 and 'link errors' in message, message
    values = r.node.status_values()
    assert values['out_of_order'] == 2 and values['crc_errors'] >= 3
    drive(spin, executor, r, emu, OTHER)  # the link stays up
    assert r.node.faults == 0


def test_persistent_corruption_is_a_fault_and_it_resumes(context, executor, spin, emu):
    r = driver(context, executor, emu.port, reply_timeout=0.3)
    drive(spin, executor, r, emu, GOOD)
    emu.board.corrupt_replies(10 ** 9)
    assert spin(executor, lambda: not r.node.connected, TIMEOUT)
    assert 'stalled: no STATUS' in r.node.last_fault and r.node.is_neutral()
    assert spin(executor, lambda: emu.board.neutral, TIMEOUT)  # by the host or the board
    emu.board.clear_faults()
    drive(spin, executor, r, emu, OTHER)


def test_stalled_link_is_a_fault_and_it_resumes(context, executor, spin, emu):
    r = driver(context, executor, emu.port, reply_timeout=0.3)
    drive(spin, executor, r, emu, GOOD)
    emu.board.stall()
    assert spin(executor, lambda: not r.node.connected, TIMEOUT)
    assert 'stalled' in r.node.last_fault and emu.board.path in r.node.last_fault
    assert spin(executor, lambda: emu.board.neutral, TIMEOUT)  # nothing got through:
    assert emu.board.counters()['watchdog_trips'] == 1        # the board's own watchdog
    emu.board.resume()
    drive(spin, executor, r, emu, OTHER)


def test_wrong_identity_is_refused_naming_port_and_value(context, executor, spin, emu):
    emu.board.wrong_identity(board_id=0x1234)
    r = driver(context, executor, emu.port)
    assert spin(executor, lambda: r.node.faults >= 1, TIMEOUT)
    fault = r.node.last_fault
    assert emu.port in fault and emu.board.path in fault and 'board id 0x1234' in fault, fault
    assert not ready(r.node)
    emu.board.wrong_identity(board_id=BOARD_ID, version=9)
    assert spin(executor, lambda: 'protocol 9' in r.node.last_fault, TIMEOUT)
    # The port opens each time, the board does not fit: the retries still back off.
    assert spin(executor, lambda: r.node.faults >= 4, TIMEOUT)
    assert r.node._backoff.delay == pytest.approx(0.2)  # 0.05, 0.1, 0.2 (max_delay)
    emu.board.right_identity()
    drive(spin, executor, r, emu, GOOD)
    assert spin(executor, lambda: r.node._backoff.delay == pytest.approx(0.05), TIMEOUT)


def test_board_reset_is_detected_and_the_command_restored(context, executor, spin, emu):
    r = driver(context, executor, emu.port)
    drive(spin, executor, r, emu, GOOD)
    emu.board.reset()  # outputs neutral, sequence restarts, HELLO
    s = r.node._session
    assert spin(executor, lambda: s.board_resets == 1, TIMEOUT)
    assert spin(executor, lambda: emu.applied(GOOD), TIMEOUT)  # configured and sent again
    assert r.node.faults == 0 and r.node.status_values()['board_resets'] == 1


def test_waits_quietly_for_the_board_to_boot_after_opening(context, executor, spin):
    # A Mega resets when its port opens (DTR); bytes sent into the bootloader are lost and
    # would hold it there: the driver waits for the boot HELLO before it speaks.
    name = f'boot{next(_names)}'
    board = ArduinoEmulator(boot_delay=0.5)
    try:
        emulation.register('serial', name, board.start())
        r = driver(context, executor, f'emulated:{name}', boot_wait=1.5, hello_timeout=3.0)
        drive(spin, executor, r, Emu(board, name), GOOD)
        assert board.lost_bytes == 0 and board.resets == 1 and r.node.faults == 0
    finally:
        emulation.unregister('serial', name)
        board.stop()


def test_no_hello_is_a_fault_naming_the_port(context, executor, spin, emu):
    emu.board.stall()
    r = driver(context, executor, emu.port, boot_wait=0.1, hello_timeout=0.3)
    assert spin(executor, lambda: r.node.faults >= 1, TIMEOUT)
    assert 'no HELLO from the board within 0.3 s' in r.node.last_fault
    assert emu.port in r.node.last_fault
    emu.board.resume()
    drive(spin, executor, r, emu, GOOD)


@pytest.mark.parametrize('extra, name', [
    ({'board_timeout': 0.05, 'heartbeat_period': 0.05}, 'board_timeout'),
    ({'reply_timeout': 0.05, 'heartbeat_period': 0.05}, 'reply_timeout'),
    ({'boot_wait': 5.0, 'hello_timeout': 1.0}, 'hello_timeout'),
    ({'heartbeat_period': 5.0}, 'heartbeat_period'),
    ({'port': ''}, 'port'),
])
def test_bad_parameters_are_refused_naming_them(context, extra, name):
    with pytest.raises(ConfigurationError, match=name):
        ArduinoPwmNode(node_name='arduino', context=context,
                       parameter_overrides=overrides({'port': 'emulated:none', **extra}))


@pytest.mark.parametrize('extra, name', [
    ({'name': 'a:b'}, 'name'),
    ({'azimuth_names': ['az_bow', 'az_port_aft']}, 'azimuth_names'),
])
def test_emulator_node_bad_parameters_are_refused_naming_them(context, extra, name):
    with pytest.raises(ConfigurationError, match=name):
        ArduinoEmulatorNode(node_name='arduino_emulator', context=context,
                            parameter_overrides=overrides(extra))


def test_emulator_node_flies_the_simulator_and_reports_outputs(context, executor, spin):
    name = f'node{next(_names)}'
    emu_node = add(executor, ArduinoEmulatorNode(
        node_name='arduino_emulator', context=context,
        parameter_overrides=overrides({'name': name})))
    emu_node.start()  # bringup starts the emulators first
    r = driver(context, executor, f'emulated:{name}')
    p = probe(context, executor, 'sim')
    sim: list[JointState] = []
    out: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, sim.append)
    p.create_subscription(JointState, EMULATOR_OUTPUT.name, out.append, EMULATOR_OUTPUT.qos)
    reports: list[dict[str, str]] = []
    p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name, lambda m: reports.extend(
        {'level': s.level, 'message': s.message, **{v.key: v.value for v in s.values}}
        for s in m.status if s.hardware_id == 'arduino_emulator'), topics.DIAGNOSTICS.qos)
    LinkBus.of(context).connect()
    drive(spin, executor, r, Emu(emu_node.emulator, name), GOOD)
    n = len(sim)
    assert spin(executor, lambda: len(sim) > n + 3 and out
                and list(out[-1].position) == pytest.approx(GOOD), TIMEOUT)
    assert list(sim[-1].name) == NAMES
    assert list(sim[-1].effort) == pytest.approx([0.6] * 3, abs=1e-12)
    assert list(sim[-1].position) == pytest.approx([1.98968] * 3, abs=1e-12)
    assert list(out[-1].name) == [f'{a}/{k}' for a in NAMES for k in ('motor', 'servo')]
    assert out[-1].header.stamp.sec > 0 or out[-1].header.stamp.nanosec > 0
    # The emulator reports what it received on /diagnostics.
    assert spin(executor, lambda: reports and int(reports[-1]['frames']) > 3, TIMEOUT)
    assert reports[-1]['path'] == emu_node.emulator.path
    assert reports[-1]['duties'] == ' '.join(f'{d:.2f}' for d in GOOD)
    assert int(reports[-1]['bytes_in']) > 0 and reports[-1]['crc_errors'] == '0'
    emu_node.unplug()  # the board loses power: no pulses, the simulator's timeout acts
    assert spin(executor, lambda: not r.node.connected, TIMEOUT)
    emu_node.replug()
    drive(spin, executor, r, Emu(emu_node.emulator, name), OTHER)


@pytest.mark.parametrize('duty_min', [0.0, 0.004])
def test_a_minimum_duty_of_zero_is_refused_before_anything_is_sent(context, duty_min):
    # 0 in the board's 0.01 % units: its ticks(0) wraps to a constant-high output.
    with pytest.raises(ConfigurationError, match=r'pwm\.duty_min_percent: .*0\.01 %') as info:
        ArduinoPwmNode(node_name='arduino', context=context, parameter_overrides=overrides(
            {'port': 'emulated:none', 'pwm.duty_min_percent': duty_min}))
    assert info.value.parameter == 'pwm.duty_min_percent'


def test_link_settings_refuse_a_zero_minimum_or_neutral():
    with pytest.raises(ValueError, match='duty_min'):
        LinkSettings(duty_min=0)
    with pytest.raises(ValueError, match='neutral'):
        LinkSettings(neutral=(0,) * 6)


def test_constructing_the_driver_opens_nothing(context, executor, spin, emu, monkeypatch):
    # Opening the port resets a Mega through DTR: building the node (bringup --check) must not.
    opened: list[str] = []
    real = link.open_serial
    monkeypatch.setattr(link, 'open_serial', lambda path, *a, **k: opened.append(path)
                        or real(path, *a, **k))
    node = add(executor, ArduinoPwmNode(node_name='arduino', context=context,
                                        parameter_overrides=overrides({'port': emu.port})))
    assert opened == [] and node._session is None and node.sessions == 0
    assert not node.connected and node.faults == 0 and emu.board.resets == 0
    node.start()
    assert opened == [emu.board.path] and node.sessions == 1
    assert spin(executor, lambda: ready(node), TIMEOUT), node.last_fault
    assert emu.board.resets == 1  # the open reset it, once


def test_constructing_the_emulator_node_opens_no_pty(context, executor):
    name = f'quiet{next(_names)}'
    emu_node = add(executor, ArduinoEmulatorNode(
        node_name='arduino_emulator', context=context,
        parameter_overrides=overrides({'name': name})))
    assert emu_node.emulator.path is None and not emu_node.emulator.powered
    with pytest.raises(DeviceError, match=f'no serial emulator named {name!r}'):
        emulation.lookup('serial', f'emulated:{name}')
    emu_node.start()
    path = emulation.lookup('serial', f'emulated:{name}')
    assert path == emu_node.emulator.path and os.path.exists(path)
    emu_node.start()  # a second start opens no second pty
    assert emulation.lookup('serial', f'emulated:{name}') == path


def test_a_vanished_usb_port_is_a_fault_that_names_the_by_id_link(context, executor):
    # No /dev/ttyACM97 here: the open fails with ENOENT, as after a re-plug renumbered it.
    r = driver(context, executor, '/dev/ttyACM97')
    assert not r.node.connected
    assert ('/dev/ttyACM97 is gone' in r.node.last_fault
            and '/dev/serial/by-id/usb-<vendor>_<model>_<serial>-if00' in r.node.last_fault)
