"""The emulated CS Saucer end to end: ``saucer_emulated`` as a user runs it (a real process),
its real drivers against the device emulators, judged from the bag.

The DualShock 4 emulator plays the operator as Linux input events; the evdev driver, the
modes, the observer fed by the Qualisys driver (QTM RT protocol on loopback), guidance,
control, allocation and the PWM mapper lead to the Arduino driver, whose frames the
firmware's own C code (built with the host compiler) turns into duty cycles
(``emulator/arduino``). The lidar driver reads the emulated A1's scan bytes; the camera
driver reads the emulator's video. So the bag shows what the devices received.
"""

from __future__ import annotations

import bisect
import math
import subprocess
from typing import Any

import pytest
from support.bags import read_bag, stamp
from support.cli import ENBARR

from enbarr_core.bringup.profile import load_profile
from enbarr_core.world.model import Circle

# alone (setup.cfg): judged against real time, the emulators starve beside another worker
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

PROFILE = load_profile('saucer_emulated')
# The run ends in guidance: bringup stops while the chain drives the azimuths, and the board
# must still end neutral (the joystick's loss is judged in test/plugins/test_ds4_evdev.py).
SCRIPT = ['0.0  sticks 0.6 0.0 0.0',   # manual: ahead
          '3.0  sticks 0.0 0.0 0.0',
          '4.0  press triangle',       # automatic
          '8.0  press cross',          # manual
          '9.0  press square']         # guidance, to the end
DURATION = 18.0
NEUTRAL = 6.85      # [%] motors (no thrust) and servos (angle 0): saucer_core's pwm tables
DEAD_BAND = (6.7, 7.0)
TOPICS = ['/emulator/arduino', '/mode', '/scan', '/mocap/pose', '/sim/odometry', '/joy',
          '/diagnostics', '/camera/camera_info']  # not the images: 15 MB/s


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    bag = tmp_path_factory.mktemp('saucer_emulated') / 'bag'
    script = '[' + ', '.join(f"'{line}'" for line in SCRIPT) + ']'
    record = [a for t in TOPICS for a in ('--record-topic', t)]
    proc = subprocess.run(
        [*ENBARR, 'bringup', '--profile', 'saucer_emulated', '--duration', str(DURATION),
         '--output', str(bag), *record, '--set', f'ds4_emulator.script={script}'],
        capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {'msgs': read_bag(bag), 'log': proc.stderr + proc.stdout}


def _t0(run: dict[str, Any]) -> float:
    """The script's time zero: the first joystick sample."""
    return stamp(run['msgs']['/joy'][0][1])


def _duties(run: dict[str, Any], start: float, end: float) -> list[dict[str, float]]:
    t0 = _t0(run)
    return [dict(zip(m.name, m.position)) for _, m in run['msgs']['/emulator/arduino']
            if t0 + start <= stamp(m) <= t0 + end]


def _last_status(run: dict[str, Any]) -> dict[str, tuple[int, dict[str, str]]]:
    last: dict[str, tuple[int, dict[str, str]]] = {}
    for _, m in run['msgs']['/diagnostics']:
        for s in m.status:
            last[s.name.lstrip('/')] = (s.level, {v.key: v.value for v in s.values})
    return last


def test_the_run_is_clean(run: dict[str, Any]) -> None:
    assert 'Traceback' not in run['log']
    for line in run['log'].splitlines():  # emulators are built first: no device is absent
        if any(f'[{d}]:' in line for d in ('arduino', 'mocap', 'lidar', 'camera')):
            assert '(fault ' not in line, line


def test_every_driver_is_connected_at_the_end(run: dict[str, Any]) -> None:
    last = _last_status(run)
    for driver in ('arduino', 'mocap', 'lidar', 'camera', 'joystick'):
        level, values = last[driver]
        assert values['connected'] == 'True' and values['faults'] == '0', (driver, values)


def test_the_operator_goes_through_every_mode(run: dict[str, Any]) -> None:
    modes = [m.data for _, m in run['msgs']['/mode']]
    it = iter(modes)
    assert all(mode in it for mode in ('automatic', 'manual', 'guidance')), modes


def test_manual_stick_ahead_reaches_the_motors(run: dict[str, Any]) -> None:
    """0-3 s: left stick up: every motor's duty above the dead band, the servos near 0 rad."""
    window = _duties(run, 1.0, 2.8)
    assert window
    for d in window:
        motors = [v for k, v in d.items() if k.endswith('/motor')]
        servos = [v for k, v in d.items() if k.endswith('/servo')]
        assert len(motors) == 3 and all(v > DEAD_BAND[1] for v in motors), d
        assert all(abs(v - NEUTRAL) < 0.5 for v in servos), d


def test_the_bag_ends_with_the_board_neutral(run: dict[str, Any]) -> None:
    """The drivers' safe state reached the firmware, and no pose drove the chain after it
    (the run ended in guidance): every channel at its neutral duty."""
    guiding = _duties(run, 12.0, DURATION - 2.0)
    assert any(abs(v - NEUTRAL) > 0.05 for d in guiding for v in d.values())
    _, last = run['msgs']['/emulator/arduino'][-1]
    assert len(last.position) == 6
    assert all(abs(v - NEUTRAL) < 0.01 for v in last.position), list(last.position)


def test_motion_capture_measures_the_simulated_vessel(run: dict[str, Any]) -> None:
    truth = [(stamp(m), m.pose.pose.position) for _, m in run['msgs']['/sim/odometry']]
    times = [t for t, _ in truth]
    poses = run['msgs']['/mocap/pose']
    assert len(poses) > 0.5 * 50.0 * DURATION
    for _, m in poses[::20]:
        i = min(bisect.bisect_left(times, stamp(m)), len(truth) - 1)
        p = truth[i][1]
        # the truth of the nearest 10 ms step, the pose read at its arrival (vessel < 0.5 m/s)
        assert math.hypot(m.pose.position.x - p.x, m.pose.position.y - p.y) < 0.03


def _nearest_obstacle(x: float, y: float) -> float:
    """By hand, not by World.distance: the profile's world is the basin's rectangle of walls
    and circular buoys."""
    d = math.inf
    for o in PROFILE.world.obstacles:
        assert not o.moving
        if isinstance(o.shape, Circle):
            (cx, cy), r = o.shape.center, o.shape.radius
            d = min(d, math.hypot(x - cx, y - cy) - r)
        else:
            xs, ys = zip(*o.shape.points)
            d = min(d, x - min(xs), max(xs) - x, y - min(ys), max(ys) - y)
    return d


def test_the_lidar_sees_the_basin(run: dict[str, Any]) -> None:
    """Each scan's nearest return is the nearest wall or buoy from where the vessel was."""
    truth = [(stamp(m), m.pose.pose.position) for _, m in run['msgs']['/sim/odometry']]
    times = [t for t, _ in truth]
    scans = [m for _, m in run['msgs']['/scan']]
    assert len(scans) > 0.5 * 5.5 * DURATION
    for scan in scans[5::10]:
        assert scan.header.frame_id == 'laser' and len(scan.ranges) == 360
        finite = [r for r in scan.ranges if math.isfinite(r)]
        assert len(finite) > 150           # the A1 sees 12 m: the basin is 40 m long
        p = truth[min(bisect.bisect_left(times, stamp(scan)), len(truth) - 1)][1]
        assert min(finite) == pytest.approx(_nearest_obstacle(p.x, p.y), abs=0.1)


def test_the_camera_delivers_frames_with_their_calibration(run: dict[str, Any]) -> None:
    infos = [m for _, m in run['msgs']['/camera/camera_info']]
    assert len(infos) > 0.5 * 15.0 * DURATION
    assert (infos[-1].width, infos[-1].height) == (640, 480)
