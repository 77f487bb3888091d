"""End-to-end tier: whole profiles run as users run them (a real process tree), checked
through the bag they record.
"""

from __future__ import annotations

import math
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from support.bags import read_bag, stamp
from support.cli import ENBARR

DRIVE_SCRIPT = "surface.script=['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.2']"


def _wait_for(cond: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.1)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')


def _flushed(bag: Path) -> bool:
    return (bag / 'metadata.yaml').exists()


def _neutral(msg: Any) -> bool:
    return len(msg.effort) == 8 and all(e == 0.0 for e in msg.effort)


# -- the default vessel ----------------------------------------------------------------------
@pytest.fixture(scope='module')
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    bag = tmp_path_factory.mktemp('e2e') / 'bag'
    proc = subprocess.run(
        [*ENBARR, 'bringup', '--profile', 'enbarr_sim', '--duration', '19', '--record',
         str(bag)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    msgs = read_bag(bag)
    t0 = stamp(msgs['/surface_command/twist'][0][1])  # the script's t = 0
    return {'bag': bag, 'msgs': msgs, 't0': t0, 'log': proc.stderr + proc.stdout}


def _window(run: dict[str, Any], topic: str, start: float, end: float) -> list[Any]:
    return [m for _, m in run['msgs'][topic] if start <= stamp(m) - run['t0'] < end]


# The script (params/enbarr_sim.yaml): dive 0.2 m/s from 0 s, 0.4 m/s surge from 4 s, surge
# 0.3 m/s + yaw 0.3 rad/s from 8 s, stop at 13 s. Windows start ~1.5 s after each change
# (the reference model's time constants and acceleration limits need about 1 s).
# Tolerance: 0.03 m/s and 0.03 rad/s on the truth (sim/odometry), the design accuracy of
# feed-forward velocity control without a velocity sensor when the model is right.
VELOCITY_TOL = 0.03


@pytest.mark.parametrize('window,index,goal', [
    ((1.5, 4.0), 2, -0.2),   # heave (FLU: negative = diving)
    ((5.5, 8.0), 0, 0.4),    # surge
    ((9.5, 13.0), 5, 0.3),   # yaw rate
    ((14.5, 16.0), 0, 0.0),  # stopped
])
def test_rov_reaches_commanded_velocity(sim_run: dict[str, Any], window: tuple[float, float],
                                        index: int, goal: float) -> None:
    odom = _window(sim_run, '/sim/odometry', *window)
    assert len(odom) > 50
    for m in odom:
        t = m.twist.twist
        nu = (t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z)
        assert abs(nu[index] - goal) < VELOCITY_TOL, (stamp(m) - sim_run['t0'], nu)


def test_rov_stays_upright(sim_run: dict[str, Any]) -> None:
    for _, m in sim_run['msgs']['/sim/odometry']:
        q = m.pose.pose.orientation
        # Tilt of body z from world z: cos(tilt) = 1 - 2 (x^2 + y^2).
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, 1 - 2 * (q.x ** 2 + q.y ** 2)))))
        assert tilt < 5.0


def test_rov_dives(sim_run: dict[str, Any]) -> None:
    odom = [m for _, m in sim_run['msgs']['/sim/odometry']]
    assert odom[-1].pose.pose.position.z < odom[0].pose.pose.position.z - 0.5


def test_filter_tracks_truth(sim_run: dict[str, Any]) -> None:
    truth = {stamp(m): m for _, m in sim_run['msgs']['/sim/imu']}
    errors = []
    for _, m in sim_run['msgs']['/imu/data'][400:]:  # after the first second
        t = truth.get(stamp(m))
        if t is None:
            continue
        a, b = m.orientation, t.orientation
        dot = abs(a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w)
        errors.append(math.degrees(2 * math.acos(min(1.0, dot))))
    assert len(errors) > 1000
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert rms < 3.0, rms


def test_filter_reports_its_orientation_covariance(sim_run: dict[str, Any]) -> None:
    truth = {stamp(m) for _, m in sim_run['msgs']['/sim/imu']}
    for _, m in sim_run['msgs']['/imu/data'][400:]:  # after the first second
        if stamp(m) in truth:
            assert m.orientation_covariance[0] > 0.0


def _io_states(run: dict[str, Any], name: str | None = None) -> list[Any]:
    return [m for _, m in run['msgs']['/io_state'] if name is None or m.name == name]


def test_lights_follow_their_requests(sim_run: dict[str, Any]) -> None:
    lights = [m.value.bool_value for m in _io_states(sim_run, 'gpio_12')]
    assert lights == [True, False]  # on at 1 s, off at 15 s, nothing for gpio_13


def test_io_plugins_act_on_their_requests_only(sim_run: dict[str, Any]) -> None:
    assert not [m for m in _io_states(sim_run) if m.name not in ('gpio_12', 'manipulator')]


def test_manipulator_moves_once_toward_its_target(sim_run: dict[str, Any]) -> None:
    manip = [m.value.integer_value for m in _io_states(sim_run, 'manipulator')]
    assert manip and manip[-1] == 400 and all(0 < p <= 400 for p in manip)
    assert manip == sorted(manip)  # moved once, toward 400; 'manipulator true' refused


def test_manipulator_refuses_a_boolean_request(sim_run: dict[str, Any]) -> None:
    assert 'manipulator: refused True' in sim_run['log']


def test_failsafe_after_surface_goes_quiet(sim_run: dict[str, Any]) -> None:
    goals = _window(sim_run, '/trajectory_request', 16.8, 19.0)
    assert goals and all(g.twist.linear.x == 0.0 and g.twist.angular.z == 0.0 for g in goals)
    assert 'surface commands lost' in sim_run['log']


def test_bag_readable_by_mcap_reader(sim_run: dict[str, Any]) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    count = 0
    for f in sorted(sim_run['bag'].glob('*.mcap')):
        with f.open('rb') as fh:
            for _, channel, _, msg in make_reader(
                    fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                count += 1
    assert count == sum(len(v) for v in sim_run['msgs'].values())


def test_every_stage_is_recorded(sim_run: dict[str, Any]) -> None:
    for topic in ('/imu/data_raw', '/imu/mag', '/imu/data', '/trajectory_request',
                  '/force_command', '/thruster_commands', '/thruster_output',
                  '/sim/odometry', '/io_request', '/io_state', '/diagnostics'):
        assert sim_run['msgs'].get(topic), topic


# -- exit paths --------------------------------------------------------------------------------
def _last_outputs(bag: Path) -> list[Any]:
    return [m for _, m in read_bag(bag)['/thruster_output']]


def test_duration_end_leaves_thrusters_neutral(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    proc = subprocess.run(
        [*ENBARR, 'bringup', '--profile', 'enbarr_sim', '--duration', '4', '--record',
         str(bag), '--set', DRIVE_SCRIPT], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = _last_outputs(bag)
    assert not _neutral(out[-2])  # it was driving until the end ...
    assert _neutral(out[-1])      # ... and the last command is neutral


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_leaves_thrusters_neutral(tmp_path: Path, sig: signal.Signals) -> None:
    bag = tmp_path / 'bag'
    proc = subprocess.Popen(
        [*ENBARR, 'bringup', '--profile', 'enbarr_sim', '--record', str(bag), '--set',
         DRIVE_SCRIPT], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_for(lambda: _flushed(bag) and len(list(bag.glob('*.mcap'))) >= 3, 60,
                  'three flushed segments')
        proc.send_signal(sig)
        log, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, log[-2000:]
    assert f'{sig.name} received' in log
    out = _last_outputs(bag)
    assert not _neutral(out[-2]) and _neutral(out[-1])


def test_sigkill_leaves_a_readable_bag(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    proc = subprocess.Popen(
        [*ENBARR, 'bringup', '--profile', 'enbarr_sim', '--record', str(bag)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(lambda: _flushed(bag) and len(list(bag.glob('*.mcap'))) >= 2, 60,
                  'two flushed segments')
    finally:
        proc.kill()
        proc.wait()
    msgs = read_bag(bag)
    assert len(msgs['/imu/data']) > 100
