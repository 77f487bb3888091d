"""RPLidar A1 driver against its pty emulator: the bytes, the scans, every fault, resume.

Unit tests check the protocol against bytes written by hand from the Slamtec protocol
document (not from the code under test); node tests run the driver on the emulator's pty.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
import serial
from sensor_msgs.msg import LaserScan
from support.nodes import add, probe, TIMEOUT

from enbarr_core.bringup.cli import main
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_interfaces import topics
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.lidar import rplidar
from enbarr_plugins.lidar.rplidar import (
    bin_revolution, check_device, decode_descriptor, Descriptor, encode_descriptor, Mount,
    request, RevolutionAssembler, RplidarNode, ScanDecoder)
from enbarr_plugins.lidar.rplidar_emulator import Basin, RplidarEmulator, RplidarEmulatorNode

# -- unit: the protocol, from the document's bytes --------------------------------------------


def test_requests_and_descriptors_are_the_documented_bytes():
    assert request(0x50) == bytes.fromhex('a5 50')  # GET_INFO: no payload, no checksum
    assert request(0x25) == bytes.fromhex('a5 25')
    # EXPRESS_SCAN with 5 zero bytes: checksum = A5 ^ 82 ^ 05 ^ 0 ... = 0x22
    assert request(0x82, bytes(5)) == bytes.fromhex('a5 82 05 00 00 00 00 00 22')
    assert encode_descriptor(5, 1, 0x81) == bytes.fromhex('a5 5a 05 00 00 40 81')
    assert encode_descriptor(20, 0, 0x04) == bytes.fromhex('a5 5a 14 00 00 00 04')
    assert decode_descriptor(bytes.fromhex('a5 5a 03 00 00 00 06')) == Descriptor(3, 0, 6)
    with pytest.raises(ValueError, match='not a response descriptor'):
        decode_descriptor(bytes.fromhex('a5 a5 03 00 00 00 06'))


def test_a_scan_sample_decodes_as_the_document_says():
    # start, quality 47, 90 deg (q6 5760), 1000 mm (q2 4000): BD 01 2D A0 0F
    sample = bytes.fromhex('bd 01 2d a0 0f')
    assert rplidar.encode_sample(True, 47, 90.0, 1000.0) == sample
    start, quality, angle, dist = ScanDecoder().feed(sample)
    assert start.tolist() == [True] and quality.tolist() == [47]
    assert angle.tolist() == [90.0] and dist.tolist() == [1000.0]


def test_the_decoder_resynchronises_after_garbage_corruption_and_truncation():
    good = [rplidar.encode_sample(k == 0, 30, 10.0 * k, 500.0 + k) for k in range(20)]
    broken = bytes((good[5][0] & 0xFC,)) + good[5][1:]   # S == !S
    stream = (b'\x00\x00' + b''.join(good[:5]) + broken + b''.join(good[6:10])
              + good[10][:3] + b''.join(good[11:]))        # a truncated sample
    dec = ScanDecoder()
    out = [dec.feed(stream[i:i + 7]) for i in range(0, len(stream), 7)]  # any split
    dist = np.concatenate([o[3] for o in out])
    assert dec.sync_losses >= 3 and dec.skipped >= 2
    # every good sample is found again after each loss; the truncated sample's header is
    # intact, so it takes two bytes of the next one (the protocol has no checksum): one
    # bogus distance, one sample lost, then in step again
    d = dist.tolist()
    assert d[:9] == [500.0 + k for k in (*range(5), *range(6, 10))]
    assert d[10:] == [500.0 + k for k in range(12, 20)]


def test_mount_and_flip_put_returns_in_base_link():
    # one return at the lidar's 0 deg, 1 m; lidar 0.5 m ahead: 1.5 m straight ahead
    r = bin_revolution(np.array([0.0]), np.array([1000.0]), Mount(0.5, 0.0, 0.0), 360)
    assert r[180] == pytest.approx(1.5) and np.isinf(np.delete(r, 180)).all()
    # 90 deg clockwise is the right side (-y) upright, the left side (+y) upside down
    up = bin_revolution(np.array([90.0]), np.array([2000.0]), Mount(), 360)
    flipped = bin_revolution(np.array([90.0]), np.array([2000.0]), Mount(flip=True), 360)
    assert up[90] == pytest.approx(2.0) and flipped[270] == pytest.approx(2.0)
    # yaw: the 0 deg mark pointing left
    left = bin_revolution(np.array([0.0]), np.array([1000.0]), Mount(yaw=math.pi / 2), 360)
    assert left[270] == pytest.approx(1.0)
    # no return (0) stays inf; the nearest of two returns in one ray wins
    r = bin_revolution(np.array([0.0, 0.2, 0.1]), np.array([0.0, 3000.0, 2000.0]), Mount(), 360)
    assert r[180] == pytest.approx(2.0)


def test_revolutions_start_at_a_start_flag():
    asm = RevolutionAssembler(min_samples=3)
    a = np.arange(6) * 60.0
    assert asm.add(np.array([0, 0, 1, 0, 0, 0], bool), a, a + 1, 100) == []  # before: dropped
    revs = asm.add(np.array([0, 1, 0], bool), a[:3], a[:3] + 1, 200)
    assert len(revs) == 1 and revs[0].stamp_ns == 100
    assert revs[0].angle_deg.tolist() == [120.0, 180.0, 240.0, 300.0, 0.0]
    assert revs[0].duration == pytest.approx(1e-7)
    # a start flag too soon after the last (a stream out of step) and an angle >= 360 deg:
    # ignored and counted
    revs = asm.add(np.array([0, 1, 0, 0, 1], bool), np.array([10.0, 20.0, 400.0, 30.0, 40.0]),
                   np.ones(5), 300)
    assert len(revs) == 1 and revs[0].angle_deg.tolist() == [60.0, 120.0, 10.0]
    assert asm.false_starts == 1 and asm.invalid == 1
    # a start read with 3 samples after it was taken 3 sample periods before the read
    revs = asm.add(np.array([0, 0, 0, 1, 0, 0, 0], bool), np.zeros(7), np.ones(7), 10_000, 1000)
    assert revs[0].stamp_ns == 300 and revs[0].duration == pytest.approx((7000 - 300) * 1e-9)
    revs = asm.add(np.array([1, 0], bool), np.zeros(2), np.ones(2), 20_000, 1000)
    assert revs[0].stamp_ns == 7000 and revs[0].duration == pytest.approx(12_000e-9)


def test_the_emulator_answers_with_the_documented_bytes():
    emu = RplidarEmulator()
    emu.start()
    try:
        ser = serial.Serial(emu.path, 115200, timeout=2.0)
        ser.write(bytes.fromhex('a5 50'))
        answer = ser.read(27)
        assert answer[:7] == bytes.fromhex('a5 5a 14 00 00 00 04')
        assert answer[7:11] == bytes.fromhex('18 1d 01 07')  # A1M8, firmware 1.29, hw 7
        ser.write(bytes.fromhex('a5 52'))
        assert ser.read(10) == bytes.fromhex('a5 5a 03 00 00 00 06 00 00 00')
        ser.write(bytes.fromhex('a5 20'))
        assert ser.read(7) == bytes.fromhex('a5 5a 05 00 00 40 81')
        data = ser.read(5 * 400)
        start, _, angle, dist = ScanDecoder().feed(data)
        assert start.sum() >= 1 and (dist > 0).any()
        ser.write(bytes.fromhex('a5 25'))
        deadline = time.monotonic() + TIMEOUT
        while 'STOP' not in emu.commands and time.monotonic() < deadline:
            time.sleep(0.01)
        ser.close()
        assert emu.commands == {'GET_INFO': 1, 'GET_HEALTH': 1, 'SCAN': 1, 'STOP': 1}
    finally:
        emu.stop()


def test_the_emulator_ray_casts_walls_and_circles():
    emu = RplidarEmulator(basin=Basin((-5.0, -2.0, 5.0, 2.0), ((3.0, 0.0, 0.5),)))
    emu.set_pose(1.0, 0.0, 0.0)
    # ahead: the circle at 1.5 m (3 - 0.5 - 1); 90 deg clockwise (right): wall at 2 m
    assert emu.ranges_mm(np.array([0.0, 90.0, 270.0])) == pytest.approx([1500.0, 2000.0, 2000.0])
    emu.set_pose(0.0, 1.0, math.pi)  # facing -x: the circle is behind, the wall at -5 ahead
    assert emu.ranges_mm(np.array([0.0, 90.0])) == pytest.approx([5000.0, 1000.0])


def test_check_device_against_the_emulator_and_an_absent_port():
    lines = check_device(CheckTarget(port='emulated'))
    assert 'RPLidar A1M8 (model 0x18)' in lines[0] and 'health good' in lines[1]
    assert 'one revolution' in lines[2] and 'returns' in lines[2]
    with pytest.raises(DeviceError, match='/dev/ttyNOPE'):
        check_device(CheckTarget(port='/dev/ttyNOPE'))


def test_check_device_command_line(capsys):
    assert main(['check-device', 'rplidar', '--port', 'emulated']) == 0
    assert 'RPLidar A1M8' in capsys.readouterr().out
    assert main(['check-device', 'rplidar', '--port', '/dev/ttyNOPE']) == 2
    err = capsys.readouterr().err.strip()
    assert '/dev/ttyNOPE' in err and len(err.splitlines()) == 1


# -- node tests: the driver on the emulator's pty ---------------------------------------------
FAST = [Parameter('reconnect.initial_delay', value=0.05),
        Parameter('reconnect.max_delay', value=0.2)]


def lidar_pair(context, executor, name='default', **driver):
    emu = add(executor, RplidarEmulatorNode(node_name=f'emu_{name}', context=context,
                                            parameter_overrides=[Parameter('name', value=name)]))
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value=f'emulated:{name}'), *FAST,
        *[Parameter(k, value=v) for k, v in driver.items()]]))
    lidar.start()
    scans: list[LaserScan] = []
    probe(context, executor).create_subscription(LaserScan, topics.SCAN.name, scans.append,
                                                 topics.SCAN.qos)
    return emu, lidar, scans


def ray(scan, bearing_deg):
    """The range near ``bearing_deg`` (the nearest of 3 rays: ~364 samples fill 360 rays)."""
    k = round((math.radians(bearing_deg) - scan.angle_min) / scan.angle_increment)
    return min(scan.ranges[(k + d) % len(scan.ranges)] for d in (-1, 0, 1))


def record_faults(driver):
    """Every fault message of ``driver`` from now on, in order (retries included)."""
    seen: list[str] = []
    fail = driver._fail

    def recording(err):
        seen.append(str(err))
        fail(err)
    driver._fail = recording
    return seen


def more_scans(spin, executor, scans, n=2):
    target = len(scans) + n
    return spin(executor, lambda: len(scans) >= target, TIMEOUT)


def test_scans_in_the_vessel_frame(context, executor, spin):
    emu, lidar, scans = lidar_pair(context, executor)
    emu.emulator.set_pose(0.0, 1.0, 0.0)
    assert more_scans(spin, executor, scans, 3), lidar.last_fault
    s = scans[-1]
    assert s.header.frame_id == 'laser' and len(s.ranges) == 360  # the contract's frame
    assert s.angle_min == pytest.approx(-math.pi) and s.range_max == pytest.approx(12.0)
    # 5.5 Hz on average (one scan may stretch when the machine is loaded)
    assert all(x.scan_time > 0.0 for x in scans)
    assert 0.1 < np.mean([x.scan_time for x in scans]) < 0.5
    assert ray(s, 90.0) == pytest.approx(2.225, abs=0.02)  # left wall (+y 3.225), y = 1
    assert ray(s, -90.0) == pytest.approx(4.225, abs=0.02)  # right wall
    assert np.isinf(ray(s, 0.0))                           # ahead: 19 m, beyond 12 m
    v = lidar.status_values()
    assert v['model'] == 'A1M8' and v['state'] == 'scanning' and v['sync_losses'] == 0
    assert emu.emulator.commands['GET_INFO'] >= 1 and emu.emulator.commands['SCAN'] >= 1
    # the emulator reports what it received and sent
    statuses = []
    probe(context, executor, 'listener').create_subscription(
        topics.DIAGNOSTICS.msg_type, topics.DIAGNOSTICS.name,
        lambda m: statuses.extend(x for x in m.status if x.hardware_id == 'emu_default'),
        topics.DIAGNOSTICS.qos)
    assert spin(executor, lambda: statuses, TIMEOUT)
    values = {kv.key: kv.value for kv in statuses[-1].values}
    assert 'GET_INFO=' in values['commands'] and int(values['samples_sent']) > 700


def test_the_motor_runs_through_dtr(context, executor, spin, monkeypatch):
    calls: list[bool] = []

    class DtrRecorder:  # a pty has no modem lines: record what the driver sets
        def __init__(self, ser):
            object.__setattr__(self, '_ser', ser)

        def __getattr__(self, name):
            return getattr(self._ser, name)

        def __setattr__(self, name, value):
            if name == 'dtr':
                calls.append(value)
            else:
                setattr(self._ser, name, value)

    real_open = rplidar.open_serial
    monkeypatch.setattr(rplidar, 'open_serial', lambda *a, **k: DtrRecorder(real_open(*a, **k)))
    emu, lidar, scans = lidar_pair(context, executor)
    assert more_scans(spin, executor, scans, 1)
    assert calls == [False]  # DTR cleared: the A1 motor runs
    lidar.close_device()
    assert calls == [False, True]  # DTR asserted: motor off


def test_absent_at_start_then_plugged_in(context, executor, spin):
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value='emulated:late'), *FAST]))
    lidar.start()
    statuses = []
    probe(context, executor).create_subscription(
        topics.DIAGNOSTICS.msg_type, topics.DIAGNOSTICS.name,
        lambda m: statuses.extend(s for s in m.status if s.hardware_id == 'rplidar'),
        topics.DIAGNOSTICS.qos)
    assert spin(executor, lambda: any(s.level == b'\x02' for s in statuses), TIMEOUT)
    assert not lidar.connected and 'emulated:late' in lidar.last_fault
    error = next(s for s in statuses if s.level == b'\x02')
    assert 'no serial emulator named' in error.message
    emu = add(executor, RplidarEmulatorNode(node_name='emu_late', context=context,
                                            parameter_overrides=[Parameter('name', value='late')]))
    assert spin(executor, lambda: lidar.revolutions >= 2, TIMEOUT), lidar.last_fault
    assert lidar.connected and emu.emulator.commands['SCAN'] >= 1


def test_unplug_replug_stall_and_corruption(context, executor, spin):
    emu, lidar, scans = lidar_pair(context, executor, stall_timeout=0.3)
    e = emu.emulator
    assert more_scans(spin, executor, scans)
    # corrupted and truncated samples: counted, resynchronised, no fault
    e.corrupt(20)
    e.truncate(20)
    assert spin(executor, lambda: lidar.decoder.sync_losses >= 2, TIMEOUT)
    assert more_scans(spin, executor, scans, 3) and lidar.faults == 0
    assert ray(scans[-1], -90.0) == pytest.approx(3.225, abs=0.02)
    # unplugged: a fault naming the port; plugged again under a new pty: found and resumed
    seen = record_faults(lidar)
    e.unplug()
    assert spin(executor, lambda: seen, TIMEOUT) and not lidar.connected
    assert 'emulated:default' in seen[0] and 'read failed (unplugged?)' in seen[0]
    e.replug()  # a new pty (the kernel may give it the old number)
    assert spin(executor, lambda: lidar.connected and lidar.state == 'scanning', TIMEOUT)
    assert more_scans(spin, executor, scans, 2)
    assert lidar.status_values()['sync_losses'] >= 2  # totals since start survive reconnects
    # stalled: a fault, reconnect with STOP / SCAN again, resume when it speaks again
    scans_before = e.commands['SCAN']
    seen.clear()
    e.stall(True)
    assert spin(executor, lambda: seen, TIMEOUT)
    assert 'stalled' in seen[0]
    e.stall(False)
    assert more_scans(spin, executor, scans, 2), lidar.last_fault
    assert e.commands['SCAN'] > scans_before and e.commands['STOP'] >= 2


def test_wrong_identity_and_health_error(context, executor, spin):
    emu, lidar, scans = lidar_pair(context, executor)
    e = emu.emulator
    assert more_scans(spin, executor, scans, 1)
    e.model = 0x61  # an S-series answers on this port
    e.unplug()
    e.replug()
    assert spin(executor, lambda: '0x61' in lidar.last_fault, TIMEOUT), lidar.last_fault
    assert 'not an RPLidar A1' in lidar.last_fault and 'emulated:default' in lidar.last_fault
    # health error: cleared by one RESET
    e.model = 0x18
    e.health = (2, 0x1234)
    assert spin(executor, lambda: lidar.resets == 1 and lidar.state == 'scanning', TIMEOUT)
    assert e.commands['RESET'] == 1 and more_scans(spin, executor, scans, 1)
    # an error that a RESET does not clear: a fault saying so
    e.health, e.health_sticky = (2, 0x1234), True
    e.unplug()
    e.replug()
    assert spin(executor, lambda: 'persists after RESET' in lidar.last_fault, TIMEOUT)


def test_bad_parameters_are_named(context):
    with pytest.raises(ConfigurationError, match='bins'):
        RplidarNode(context=context, parameter_overrides=[Parameter('bins', value=5)])
    with pytest.raises(ConfigurationError, match='port'):
        RplidarNode(context=context, parameter_overrides=[Parameter('port', value=' ')])
