"""RPLidar A1 driver against its pty emulator: the scans, every fault, resume, the check.

The protocol itself is held to the documents in test_rplidar_protocol.py, the revolution and
its rays in test_lidar_scan.py; here the emulator's answers are checked against bytes
written by hand from the Slamtec protocol document, and the driver runs on its pty.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
import serial
from sensor_msgs.msg import LaserScan
from support.devices import (
    FAST_RECONNECT as FAST, NoisyPort, record_delays, record_faults, statuses, values)
from support.nodes import add, probe, TIMEOUT

from enbarr_core.commands.main import main
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.lidar import rplidar
from enbarr_plugins.lidar.check import check_device
from enbarr_plugins.lidar.rplidar import RplidarNode
from enbarr_plugins.lidar.rplidar_protocol import ScanDecoder
from enbarr_plugins.lidar.rplidar_emulator import RplidarEmulator, RplidarEmulatorNode
from enbarr_core.framework.node import install_world
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Walls, World

# alone (setup.cfg): the node tests judge the emulator's real-time stream; they starve
# beside another worker, so ./dev test runs them after the parallel pass
pytestmark = pytest.mark.alone

#: The NTNU MC-lab basin as the profiles declare it (40 x 6.45 m, centred on odom).
BASIN = Obstacle('basin', Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225),
                                 (-20.0, 3.225)), closed=True))

# -- unit: the emulator's bytes, from the document -------------------------------------------


def test_the_emulator_answers_with_the_documented_bytes():
    emu = RplidarEmulator(world=World([BASIN]))
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
    box = Walls(((-5.0, -2.0), (5.0, -2.0), (5.0, 2.0), (-5.0, 2.0)), closed=True)
    emu = RplidarEmulator(world=World([Obstacle('box', box),
                                       Obstacle('buoy', Circle((3.0, 0.0), 0.5))]))
    emu.set_pose(1.0, 0.0, 0.0)
    # ahead: the circle at 1.5 m (3 - 0.5 - 1); 90 deg clockwise (right): wall at 2 m
    assert emu.ranges_mm(np.array([0.0, 90.0, 270.0])) == pytest.approx([1500.0, 2000.0, 2000.0])
    emu.set_pose(0.0, 1.0, math.pi)  # facing -x: the circle is behind, the wall at -5 ahead
    assert emu.ranges_mm(np.array([0.0, 90.0])) == pytest.approx([5000.0, 1000.0])


def test_the_emulator_sees_a_moving_obstacle_at_its_world_time():
    now = [0.0]
    boat = Obstacle('boat', Circle((10.0, 0.0), 0.5), ConstantVelocity((-1.0, 0.0)))
    emu = RplidarEmulator(world=World([boat]), world_time=lambda: now[0])
    assert emu.ranges_mm(np.array([0.0])) == pytest.approx([9500.0])
    now[0] = 4.0  # the boat's centre at x = 6
    assert emu.ranges_mm(np.array([0.0])) == pytest.approx([5500.0])
    assert emu.ranges_mm(np.array([180.0])) == [0.0]  # nothing behind: no return


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

def lidar_pair(context, executor, name='default', **driver):
    install_world(context, World([BASIN]))
    emu = add(executor, RplidarEmulatorNode(node_name=f'emu_{name}', context=context,
                                            parameter_overrides=[Parameter('name', value=name)]))
    emu.start()
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value=f'emulated:{name}'), *FAST,
        *[Parameter(k, value=v) for k, v in driver.items()]]))
    lidar.start()
    scans: list[LaserScan] = []
    probe(context, executor).create_subscription(LaserScan, topics.SCAN.name, scans.append,
                                                 topics.SCAN.qos)
    return emu, lidar, scans


def ray(scan, bearing_deg):
    """The range near ``bearing_deg``: the nearest of 3 rays (~364 samples fill 360 rays;
    NaN, no sample, only where none of the 3 has one)."""
    k = round((math.radians(bearing_deg) - scan.angle_min) / scan.angle_increment)
    return float(np.fmin.reduce([scan.ranges[(k + d) % len(scan.ranges)] for d in (-1, 0, 1)]))


def more_scans(spin, executor, scans, n=2):
    target = len(scans) + n
    return spin(executor, lambda: len(scans) >= target, TIMEOUT)


def test_scans_in_the_lidars_own_frame(context, executor, spin):
    emu, lidar, scans = lidar_pair(context, executor)
    emu.emulator.set_pose(0.0, 1.0, 0.0)
    assert more_scans(spin, executor, scans, 3), lidar.last_fault
    s = scans[-1]
    assert s.header.frame_id == 'laser' and len(s.ranges) == 360
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
    seen = statuses(context, executor, 'emu_default')
    assert spin(executor, lambda: seen, TIMEOUT)
    reported = values(seen[-1])
    assert 'GET_INFO=' in reported['commands'] and int(reported['samples_sent']) > 700


def test_the_driver_leaves_the_mount_to_the_frame_tree(context, executor, spin):
    """The A1 sits 0.5 m ahead of base_link with its 0 deg mark to port (the laser frame's
    pose): the scan stays in the lidar's frame, named by frame_id, unrotated."""
    install_world(context, World([BASIN]))
    emu = add(executor, RplidarEmulatorNode(node_name='emu_turned', context=context,
                                            parameter_overrides=[
        Parameter('name', value='turned'), Parameter('mount.x', value=0.5),
        Parameter('mount.yaw', value=math.pi / 2)]))
    emu.start()
    emu.emulator.set_pose(0.0, 1.0, 0.0)
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value='emulated:turned'), Parameter('frame_id', value='lidar_top'),
        *FAST]))
    lidar.start()
    scans: list[LaserScan] = []
    probe(context, executor).create_subscription(LaserScan, topics.SCAN.name, scans.append,
                                                 topics.SCAN.qos)
    assert more_scans(spin, executor, scans, 2), lidar.last_fault
    s = scans[-1]
    assert s.header.frame_id == 'lidar_top'
    assert ray(s, 0.0) == pytest.approx(2.225, abs=0.02)    # the mark points at the port wall
    assert ray(s, 180.0) == pytest.approx(4.225, abs=0.02)  # behind the mark: starboard wall
    assert np.isinf(ray(s, 90.0)) and np.isinf(ray(s, -90.0))  # along the basin: > 12 m


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
    seen = statuses(context, executor, 'rplidar')
    assert spin(executor, lambda: any(s.level == b'\x02' for s in seen), TIMEOUT)
    assert not lidar.connected and 'emulated:late' in lidar.last_fault
    error = next(s for s in seen if s.level == b'\x02')
    assert 'no serial emulator named' in error.message
    emu = add(executor, RplidarEmulatorNode(node_name='emu_late', context=context,
                                            parameter_overrides=[Parameter('name', value='late')]))
    emu.start()
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


def test_constructing_the_driver_and_the_emulator_opens_nothing(context, executor, spin,
                                                                monkeypatch):
    """``bringup --check`` builds every node: no port opened, no pty made, until start."""
    opened: list[str] = []
    real_open = rplidar.open_serial
    monkeypatch.setattr(rplidar, 'open_serial',
                        lambda path, *a, **k: opened.append(path) or real_open(path, *a, **k))
    emu = add(executor, RplidarEmulatorNode(node_name='emu_quiet', context=context,
                                            parameter_overrides=[Parameter('name', value='q')]))
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value='emulated:q'), *FAST]))
    assert emu.emulator.path is None and opened == [] and lidar.state == 'closed'
    with pytest.raises(DeviceError, match="no serial emulator named 'q'"):
        emulation.lookup('serial', 'emulated:q')       # nothing plugged in
    assert not any(t.name == 'rplidar_reader' for t in threading.enumerate())
    emu.start()
    lidar.start()
    assert opened == [emu.emulator.path]
    assert spin(executor, lambda: lidar.revolutions >= 1, TIMEOUT), lidar.last_fault
    # the first revolution confirmed the device: the retry delay is back to its start
    assert lidar.confirmed and lidar._backoff.delay == 0.05
    executor.remove_node(emu)
    emu.destroy_node()                     # unplugged: its pty is withdrawn
    with pytest.raises(DeviceError, match="no serial emulator named 'q'"):
        emulation.lookup('serial', 'emulated:q')


def test_a_port_that_only_sends_noise_backs_off(context, executor, spin):
    """A device that opens but never answers (noise on the line) is not "back" on every
    open: the retry delay doubles up to its maximum, /diagnostics never says OK."""
    port = NoisyPort()
    try:
        lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
            Parameter('port', value=port.path), Parameter('response_timeout', value=0.1),
            *FAST]))
        delays = record_delays(lidar)
        seen = statuses(context, executor, 'rplidar')
        lidar.start()
        assert spin(executor, lambda: len(delays) >= 4, 3 * TIMEOUT), lidar.last_fault
        assert delays[:4] == [0.05, 0.1, 0.2, 0.2]
        assert 'no answer to GET_INFO' in lidar.last_fault and port.path in lidar.last_fault
        assert not lidar.confirmed and seen
        assert all(s.level != b'\x00' and values(s)['confirmed'] == 'False' for s in seen)
    finally:
        port.close()


def test_noise_after_the_handshake_is_a_stall_and_backs_off(context, executor, spin):
    """An A1 that answers GET_INFO and SCAN, then streams bytes that make no sample: a fault
    (bytes alone are no sign of life), and the retry delay grows."""
    emu, lidar, scans = lidar_pair(context, executor, stall_timeout=0.2)
    emu.emulator.noise(True)
    delays = record_delays(lidar)
    assert spin(executor, lambda: len(delays) >= 2, 3 * TIMEOUT), lidar.last_fault
    assert delays[:2] == [0.05, 0.1]
    assert 'no valid scan sample for 0.2 s' in lidar.last_fault and not scans
    emu.emulator.noise(False)
    assert more_scans(spin, executor, scans, 2), lidar.last_fault
    assert lidar.confirmed and lidar._backoff.delay == 0.05


def test_a_vanished_usb_port_points_to_its_stable_name(context, executor, spin, monkeypatch):
    """A re-plugged adapter may come back as another /dev/ttyUSBn: when the port is gone,
    the fault says to name it by /dev/serial/by-id/."""
    advice = 'give the port by its stable name, ls -l /dev/serial/by-id/'
    absent = add(executor, RplidarNode(node_name='absent', context=context,
                                       parameter_overrides=[
        Parameter('port', value='/dev/ttyUSB97'), *FAST]))
    absent.start()
    assert '/dev/ttyUSB97: cannot open' in absent.last_fault and advice in absent.last_fault
    assert 'another /dev/ttyUSBn' in absent.last_fault
    by_id = add(executor, RplidarNode(node_name='by_id', context=context, parameter_overrides=[
        Parameter('port', value='/dev/serial/by-id/usb-nothing-if00-port0'), *FAST]))
    by_id.start()
    assert 'cannot open' in by_id.last_fault and advice not in by_id.last_fault
    # unplugged while scanning: the emulator's pty stands for /dev/ttyUSB0
    emu = add(executor, RplidarEmulatorNode(node_name='emu_usb', context=context,
                                            parameter_overrides=[Parameter('name', value='usb')]))
    emu.start()
    real_open = rplidar.open_serial
    monkeypatch.setattr(rplidar, 'open_serial', lambda path, *a, **k: real_open(
        emulation.lookup('serial', 'emulated:usb'), *a, **k))
    lidar = add(executor, RplidarNode(context=context, parameter_overrides=[
        Parameter('port', value='/dev/ttyUSB0'), *FAST]))
    lidar.start()
    assert spin(executor, lambda: lidar.revolutions >= 1, TIMEOUT), lidar.last_fault
    seen = record_faults(lidar)
    emu.emulator.unplug()
    assert spin(executor, lambda: seen, TIMEOUT)
    assert 'read failed (unplugged?)' in seen[0] and advice in seen[0]
    assert main(['check-device', 'rplidar', '--port', '/dev/ttyUSB97']) == 2


def test_bad_parameters_are_named(context):
    with pytest.raises(ConfigurationError, match='bins'):
        RplidarNode(context=context, parameter_overrides=[Parameter('bins', value=5)])
    with pytest.raises(ConfigurationError, match='port'):
        RplidarNode(context=context, parameter_overrides=[Parameter('port', value=' ')])
    with pytest.raises(ConfigurationError, match="frame_id: .*got '/laser'"):
        RplidarNode(context=context, parameter_overrides=[Parameter('frame_id', value='/laser')])
