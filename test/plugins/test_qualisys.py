"""Qualisys (QTM RT) driver against its loopback emulator: framing, poses, faults, resume.

Unit tests read the emulator's bytes by hand (the QTM RT protocol document's layout) and
through qtm-rt's own parser; node tests run the driver on the emulator.
"""

from __future__ import annotations

import math
import socket
import struct
import threading

import numpy as np
import pytest
from qtm_rt.packet import QRTPacket
from rclpy.parameter import Parameter
from support.cli import enbarr, refused
from support.devices import (
    FAST_RECONNECT, free_tcp_port, record_delays, record_faults, statuses, values)
from support.nodes import add, probe, TIMEOUT
from support.saucer import odometry_msg

from enbarr_core.commands.main import main
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_core.framework.kinematics import quat_from_euler, quat_to_rotmat
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.mocap.check import check_device
from enbarr_plugins.mocap.qtm_emulator import QtmEmulator, QtmEmulatorNode
from enbarr_plugins.mocap.qtm_frame import QtmFrame
from enbarr_plugins.mocap.qtm_protocol import body_names
from enbarr_plugins.mocap.qualisys import body_index, QualisysNode, rotmat_to_quat

# -- unit ---------------------------------------------------------------------------------


def _recv_packet(sock):
    header = b''
    while len(header) < 8:
        header += sock.recv(8 - len(header))
    size, ptype = struct.unpack('<II', header)
    body = b''
    while len(body) < size - 8:
        body += sock.recv(size - 8 - len(body))
    return header, ptype, body


def _command(sock, text):
    data = text.encode() + b'\0'
    sock.sendall(struct.pack('<II', 8 + len(data), 1) + data)


def test_the_emulator_speaks_qtm_rt_bytes():
    emu = QtmEmulator(bodies=('saucer', 'buoy'))
    host, port = emu.start()
    emu.set_pose(1.0, 2.0, math.pi / 2)
    try:
        with socket.create_connection((host, port), timeout=TIMEOUT) as sock:
            header, ptype, body = _recv_packet(sock)  # the welcome: 8 + 26 + NUL = 35 bytes
            assert header == bytes.fromhex('23000000 01000000')
            assert body == b'QTM RT Interface connected\0'
            _command(sock, 'Version 1.25')
            assert _recv_packet(sock)[1:] == (1, b'Version set to 1.25\0')
            _command(sock, 'Version 1.99')
            assert _recv_packet(sock)[1] == 0  # an error packet
            _command(sock, 'GetParameters 6D')
            ptype, xml_text = _recv_packet(sock)[1:]
            assert ptype == 2 and body_names(xml_text) == ['saucer', 'buoy']
            _command(sock, 'GetState')
            assert _recv_packet(sock)[1:] == (6, b'\x01')  # event: connected
            _command(sock, 'GetCurrentFrame 6DEuler')
            euler = _recv_packet(sock)[2]
            _command(sock, 'GetCurrentFrame 6D')
            ptype, data = _recv_packet(sock)[1:]
        with socket.create_connection((host, port), timeout=TIMEOUT) as sock:
            _recv_packet(sock)
            _command(sock, 'StreamFrames Frequency:20 6D')
            assert [_recv_packet(sock)[1] for _ in range(3)] == [3, 3, 3]
            _command(sock, 'StreamFrames Stop')
        _, bodies = QRTPacket(euler).get_6d_euler()
        assert bodies[0][1].a3 == pytest.approx(90.0, abs=1e-4)  # yaw [deg]
        assert ptype == 3
        _, frame, count = struct.unpack_from('<qII', data)
        csize, ctype = struct.unpack_from('<II', data, 16)
        assert count == 1 and ctype == 5 and csize == 8 + 8 + 2 * 48
        assert struct.unpack_from('<ihh', data, 24) == (2, 0, 0)
        body = struct.unpack_from('<12f', data, 32)
        assert body[:3] == pytest.approx((1000.0, 2000.0, 0.0), abs=1e-3)
        # R = Rz(90 deg), column-major: first column (0, 1, 0), second (-1, 0, 0)
        assert body[3:] == pytest.approx((0, 1, 0, -1, 0, 0, 0, 0, 1), abs=1e-6)
        # and qtm-rt's own parser reads the same
        _, bodies = QRTPacket(data).get_6d()
        assert len(bodies) == 2 and bodies[0][0].x == pytest.approx(1000.0)
    finally:
        emu.stop()


def test_frames_rotations_and_body_names():
    rng = np.random.default_rng(9)
    for _ in range(20):
        r = quat_to_rotmat(quat_from_euler(*rng.uniform(-math.pi, math.pi, 3)))
        q = rotmat_to_quat(r)
        assert quat_to_rotmat(q) == pytest.approx(r, abs=1e-9)
        frame = QtmFrame(yaw=rng.uniform(-3, 3), x=1.5, y=-2.0, up=rng.choice(['z', 'y']))
        p, rr = frame.to_odom(*frame.from_odom([3.0, 4.0, 0.5], r))
        assert p == pytest.approx([3.0, 4.0, 0.5]) and rr == pytest.approx(r)
    # y up: QTM's +y is odom's +z, QTM's +z is odom's -y; a yaw of 90 deg turns x into y
    p, _ = QtmFrame(up='y').to_odom([0.0, 1000.0, 2000.0], np.eye(3))
    assert p == pytest.approx([0.0, -2.0, 1.0])
    p, _ = QtmFrame(yaw=math.pi / 2, x=10.0).to_odom([1000.0, 0.0, 0.0], np.eye(3))
    assert p == pytest.approx([10.0, 1.0, 0.0])
    with pytest.raises(ValueError, match='frame.up'):
        QtmFrame(up='x')
    with pytest.raises(DeviceError, match=r"'boat' is not in .*known: 'saucer', 'buoy'"):
        body_index(['saucer', 'buoy'], 'boat', 'tcp://qtm:22223')


def test_check_device_against_the_emulator_and_failures():
    lines = check_device(CheckTarget(host='emulated'))
    assert '6D bodies: saucer' in lines[0] and "'saucer' in frame" in lines[1]
    with pytest.raises(DeviceError, match="'boat' is not in the 6D parameters"):
        check_device(CheckTarget(host='emulated', name='boat'))
    with pytest.raises(DeviceError, match='127.0.0.1:1: cannot connect'):
        check_device(CheckTarget(host='127.0.0.1:1', timeout=1.0))


def test_check_device_command_line(capsys):
    assert main(['check-device', 'qualisys', '--host', 'emulated', '--name', 'saucer']) == 0
    assert '6D bodies: saucer' in capsys.readouterr().out
    assert main(['check-device', 'qualisys', '--host', '127.0.0.1:1']) == 2
    err = capsys.readouterr().err.strip()
    assert '127.0.0.1:1' in err and len(err.splitlines()) == 1


@pytest.mark.parametrize('command, refused', [('getcurrentframe', 'GetCurrentFrame 6D'),
                                               ('getparameters', 'GetParameters 6D')])
def test_check_device_when_qtm_answers_with_an_error(capsys, command, refused):
    """A QTM that answers a command with an error packet: one line naming the command and
    QTM's words, exit 2 (not a traceback)."""
    emu = QtmEmulator()
    host, port = emu.start()
    emu.refusals[command] = 'emulated refusal'
    try:
        with pytest.raises(DeviceError, match=rf'{refused} refused: emulated refusal$'):
            check_device(CheckTarget(host=f'{host}:{port}'))
        assert main(['check-device', 'qualisys', '--host', f'{host}:{port}']) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f'enbarr check-device: error: tcp://{host}:{port}: {refused} refused: '
                       'emulated refusal']
    finally:
        emu.stop()


@pytest.mark.e2e
def test_the_check_device_command_when_qtm_answers_with_an_error():
    """The real command, a process of its own, against a QTM that refuses GetCurrentFrame."""
    emu = QtmEmulator()
    host, port = emu.start()
    emu.refusals['getcurrentframe'] = 'emulated refusal'
    try:
        line = refused(enbarr('check-device', 'qualisys', '--host', f'{host}:{port}'),
                       'check-device')
    finally:
        emu.stop()
    assert line.endswith(f'tcp://{host}:{port}: GetCurrentFrame 6D refused: emulated refusal')
    assert emu.commands.get('getcurrentframe') == 1


# -- node tests -----------------------------------------------------------------------------
FAST = [*FAST_RECONNECT, Parameter('timeout', value=1.0)]


def mocap_pair(context, executor, name='default', body='saucer', **driver):
    emu = add(executor, QtmEmulatorNode(node_name=f'qtm_{name}', context=context,
                                        parameter_overrides=[Parameter('name', value=name)]))
    emu.start()
    mocap = add(executor, QualisysNode(context=context, parameter_overrides=[
        Parameter('host', value=f'emulated:{name}'), Parameter('body', value=body), *FAST,
        *[Parameter(k, value=v) for k, v in driver.items()]]))
    mocap.start()
    p = probe(context, executor, 'simulator')
    poses = []
    p.create_topic_subscription(topics.MOCAP_POSE, poses.append)
    truth = p.create_topic_publisher(topics.SIM_ODOMETRY)
    LinkBus.of(context).connect()
    return emu, mocap, poses, truth


def more(spin, executor, poses, n=5):
    target = len(poses) + n
    return spin(executor, lambda: len(poses) >= target, TIMEOUT)


def test_silent_between_stop_and_start(context, executor, spin):
    """The chain's source: after bringup stops the sources (before the safe state), no pose
    may drive observer -> controller -> thrusters again, though QTM keeps streaming."""
    emu, mocap, poses, truth = mocap_pair(context, executor)
    truth.publish(odometry_msg(1, [1.0, 0.0, 0.0]))
    assert more(spin, executor, poses, 5), mocap.last_fault
    mocap.stop()
    spin(executor, lambda: False, 0.3)          # frames in flight
    count, frames = len(poses), emu.emulator.frames_sent
    spin(executor, lambda: False, 0.5)
    assert len(poses) == count
    assert emu.emulator.frames_sent > frames    # QTM streamed on meanwhile
    mocap.start()
    assert more(spin, executor, poses, 5)


def test_poses_from_the_simulated_vessel(context, executor, spin):
    emu, mocap, poses, truth = mocap_pair(context, executor, **{'frame.yaw': 0.5,
                                                                'frame.x': 2.0})
    emu.set_parameters([Parameter('frame.yaw', value=0.5), Parameter('frame.x', value=2.0)])
    truth.publish(odometry_msg(1, [3.0, -1.0, 0.3]))  # the simulator's truth, via the emulator
    assert more(spin, executor, poses, 5), mocap.last_fault
    eta = convert.pose_to_eta(poses[-1].pose)
    assert eta == pytest.approx([3.0, -1.0, 0.3], abs=1e-4)
    assert poses[-1].header.frame_id == 'odom'
    stamps = [convert.stamp_to_ns(p.header.stamp) for p in poses]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    v = mocap.status_values()
    assert v['state'] == 'streaming' and v['bodies'] == 'saucer' and v['lost'] == 0
    assert emu.emulator.commands['version'] >= 1 and emu.emulator.commands['streamframes'] >= 1
    # the emulator reports what it received and sent
    seen = statuses(context, executor, 'qtm_default')
    assert spin(executor, lambda: seen, TIMEOUT)
    reported = values(seen[-1])
    assert 'getparameters=' in reported['commands'] and int(reported['frames_sent']) > 0
    assert int(reported['poses']) == 1 and int(reported['open']) == 1


def test_lost_body_out_of_order_dropped_stalled_refused(context, executor, spin):
    emu, mocap, poses, _ = mocap_pair(context, executor, stall_timeout=0.3)
    e = emu.emulator
    assert more(spin, executor, poses)
    # NaN: counted, not published, WARN; found again: published again
    e.nan(True)
    assert spin(executor, lambda: mocap.lost >= 5, TIMEOUT)
    n = len(poses)
    level, message = mocap.status()
    assert level == 1 and 'not tracked' in message and len(poses) <= n + 1
    e.nan(False)
    assert more(spin, executor, poses) and mocap.faults == 0
    # an older frame number: dropped and counted
    e.send_old_frame()
    assert spin(executor, lambda: mocap.out_of_order == 1, TIMEOUT)
    # dropped connection: a fault, reconnected, resumed
    seen = record_faults(mocap)
    e.drop()
    assert spin(executor, lambda: seen, TIMEOUT)
    assert 'connection lost' in seen[0] and 'emulated:default' in mocap.device
    assert more(spin, executor, poses) and e.connections >= 2
    # stalled stream: a fault, resumed after
    seen.clear()
    e.stall(True)
    assert spin(executor, lambda: seen, TIMEOUT)
    assert 'stalled' in seen[0]
    e.stall(False)
    assert more(spin, executor, poses), mocap.last_fault
    # refused connections: faults that say so, until QTM listens again
    e.refuse(True)
    e.drop()
    assert spin(executor, lambda: 'cannot connect' in mocap.last_fault, TIMEOUT)
    e.refuse(False)
    assert more(spin, executor, poses), mocap.last_fault


def test_wrong_version_and_unknown_body(context, executor, spin):
    emu, mocap, poses, _ = mocap_pair(context, executor, body='boat')
    assert spin(executor, lambda: mocap.faults >= 1, TIMEOUT)
    assert "'boat' is not in the 6D parameters" in mocap.last_fault
    assert "known: 'saucer'" in mocap.last_fault
    assert not poses
    emu.emulator.bodies = ('saucer', 'boat')  # the body defined in QTM: found on a retry
    assert more(spin, executor, poses, 3), mocap.last_fault
    emu.emulator.wrong_version = True
    emu.emulator.drop()
    assert spin(executor, lambda: 'Version NOT supported' in mocap.last_fault, TIMEOUT)
    assert 'version 1.25 refused' in mocap.last_fault
    emu.emulator.wrong_version = False
    assert more(spin, executor, poses, 3), mocap.last_fault


def test_absent_at_start_then_started(context, executor, spin):
    mocap = add(executor, QualisysNode(context=context, parameter_overrides=[
        Parameter('host', value='emulated:late'), Parameter('body', value='saucer'), *FAST]))
    mocap.start()
    assert spin(executor, lambda: mocap.faults >= 1, TIMEOUT)
    assert "no tcp emulator named 'late'" in mocap.last_fault
    add(executor, QtmEmulatorNode(node_name='qtm_late', context=context,
                                  parameter_overrides=[Parameter('name', value='late')])).start()
    assert spin(executor, lambda: mocap.samples >= 3, TIMEOUT), mocap.last_fault


def test_constructing_the_driver_and_the_emulator_opens_nothing(context, executor, spin,
                                                                monkeypatch):
    """``bringup --check`` builds every node: no connection to QTM, no server, until start."""
    import qtm_rt
    connects: list[tuple[str, int]] = []
    real_connect = qtm_rt.connect
    monkeypatch.setattr(qtm_rt, 'connect', lambda host, port, **kw: connects.append(
        (host, port)) or real_connect(host, port, **kw))
    emu = add(executor, QtmEmulatorNode(node_name='qtm_quiet', context=context,
                                        parameter_overrides=[Parameter('name', value='q')]))
    mocap = add(executor, QualisysNode(context=context, parameter_overrides=[
        Parameter('host', value='emulated:q'), Parameter('body', value='saucer'), *FAST]))
    assert emu.emulator.address is None and connects == [] and mocap.state == 'closed'
    with pytest.raises(DeviceError, match="no tcp emulator named 'q'"):
        emulation.lookup('tcp', 'emulated:q')             # QTM is not up
    assert not any(t.name in ('mocap_qtm', 'qtm_emulator') for t in threading.enumerate())
    emu.start()
    mocap.start()
    assert spin(executor, lambda: mocap.samples >= 1, TIMEOUT), mocap.last_fault
    assert connects == [emu.emulator.address] and emu.emulator.connections == 1
    assert mocap.confirmed and mocap._backoff.delay == 0.05
    executor.remove_node(emu)
    emu.destroy_node()                     # QTM goes: its address is withdrawn
    with pytest.raises(DeviceError, match="no tcp emulator named 'q'"):
        emulation.lookup('tcp', 'emulated:q')


def test_a_dead_server_backs_off_until_qtm_answers(context, executor, spin):
    """Nothing listens: every open starts a session thread that fails. The server was never
    back, so the retry delay doubles to its maximum and /diagnostics never says OK; once QTM
    listens on that port, its first frame confirms it and the delay starts over."""
    port = free_tcp_port()
    mocap = add(executor, QualisysNode(context=context, parameter_overrides=[
        Parameter('host', value=f'127.0.0.1:{port}'), Parameter('body', value='saucer'),
        *FAST]))
    delays = record_delays(mocap)
    seen = statuses(context, executor, 'mocap')
    mocap.start()
    assert spin(executor, lambda: len(delays) >= 4, 3 * TIMEOUT), mocap.last_fault
    assert delays[:4] == [0.05, 0.1, 0.2, 0.2]
    assert f'127.0.0.1:{port}: cannot connect' in mocap.last_fault
    assert not mocap.confirmed and seen
    assert all(s.level != b'\x00' and values(s)['confirmed'] == 'False' for s in seen)
    emu = QtmEmulator()
    emu.start(port)
    try:
        assert spin(executor, lambda: mocap.samples >= 3, TIMEOUT), mocap.last_fault
        assert mocap.confirmed and mocap._backoff.delay == 0.05
        assert mocap._backoff.next_ns is None
    finally:
        emu.stop()


def test_bad_parameters_are_named(context):
    with pytest.raises(ConfigurationError, match='body'):
        QualisysNode(context=context, parameter_overrides=[Parameter('host', value='qtm')])
    with pytest.raises(ConfigurationError, match='frame.up'):
        QualisysNode(context=context, parameter_overrides=[
            Parameter('host', value='qtm'), Parameter('body', value='saucer'),
            Parameter('frame.up', value='x')])
    with pytest.raises(ConfigurationError, match='protocol_version'):
        QualisysNode(context=context, parameter_overrides=[
            Parameter('host', value='qtm'), Parameter('body', value='saucer'),
            Parameter('protocol_version', value='1.2')])
