"""The emulated ROV end to end: ``enbarr_rov_emulated`` as a user runs it (a real process),
its real drivers against the device emulators, judged from the bag.

The scripted surface station's commands go through the core to the PCA9685 driver, whose
register bytes the emulated chip decodes into pulse widths (``emulator/pca9685``); the ESC
models turn them into the simulator's thrust, and the simulated motion comes back through the
LSM9DS1 emulator's registers and the IMU driver. So the bag shows what the devices received.
"""

from __future__ import annotations

import subprocess
from typing import Any

import pytest
from support.bags import read_bag, stamp
from support.cli import ENBARR

from enbarr_core.bringup.profile import load_profile

# alone (setup.cfg): judged against real time, the emulators starve beside another worker
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

PROFILE = load_profile('enbarr_rov_emulated')
VERTICAL = ('vert_front_right', 'vert_front_left', 'vert_rear_right', 'vert_rear_left')
FRONT = ('front_right', 'front_left', 'rear_right', 'rear_left')
NEUTRAL = 1500.0   # [us], the ESC's stop pulse (pca9685_emulator esc.neutral)
DEAD_BAND = 25.0   # [us] half width
DURATION = 21.0    # [s]: the script ends at 16 s; the rest is margin for a slow start
#: [s] The driver opens the chip when bringup starts it and holds every thruster neutral for
#: this long (the ESCs arm on neutral); the script's dive starts at once.
ARMING = PROFILE.node('thruster_control').parameters['arming_time']


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    bag = tmp_path_factory.mktemp('rov_emulated') / 'bag'
    proc = subprocess.run(
        [*ENBARR, 'bringup', '--profile', 'enbarr_rov_emulated', '--duration', str(DURATION),
         '--output', str(bag)], capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {'msgs': read_bag(bag), 'log': proc.stderr + proc.stdout}


def _pulses(run: dict[str, Any]) -> list[tuple[float, dict[str, float]]]:
    return [(stamp(m), dict(zip(m.name, m.position)))
            for _, m in run['msgs']['/emulator/pca9685']]


def _window(run: dict[str, Any], start: float, end: float) -> list[dict[str, float]]:
    """Pulses between ``start`` and ``end`` seconds after the first surface command."""
    t0 = stamp(run['msgs']['/surface_command/twist'][0][1])
    return [p for t, p in _pulses(run) if t0 + start <= t <= t0 + end]


def _armed_at(run: dict[str, Any]) -> float:
    """When the ESCs are armed: ``arming_time`` after the driver's first pulses (its open).

    Bringup starts the thruster driver before the scripted surface, and how long the nodes
    between them take to start depends on the machine: the arming is timed from the chip.
    """
    first = next(t for t, p in _pulses(run) if any(v > 0.0 for v in p.values()))
    return first + ARMING


def test_the_run_is_clean(run: dict[str, Any]) -> None:
    assert 'Traceback' not in run['log']
    # emulators are built first: no driver ever finds its device absent
    assert 'device fault' not in run['log'], run['log'][-3000:]


def test_the_drivers_stayed_connected_and_the_escs_armed(run: dict[str, Any]) -> None:
    last: dict[str, dict[str, str]] = {}
    for _, m in run['msgs']['/diagnostics']:
        for s in m.status:
            last[s.name.lstrip('/')] = {v.key: v.value for v in s.values}
    for driver in ('imu', 'thruster_control', 'lights', 'manipulator'):
        assert last[driver]['connected'] == 'True' and last[driver]['faults'] == '0', driver
    assert last['pwm_emulator']['armed'] == '8'
    assert int(last['pwm_emulator']['transfers']) > 100


def test_every_esc_is_held_neutral_while_arming(run: dict[str, Any]) -> None:
    """The first ``arming_time`` after start: whatever the script commands (a dive), every
    channel outputs the ESC's stop pulse."""
    armed = _armed_at(run)
    window = [p for t, p in _pulses(run) if armed - ARMING + 0.2 <= t <= armed - 0.3]
    assert window
    for p in window:
        assert all(abs(v - NEUTRAL) <= DEAD_BAND for v in p.values()), p


def _changes(run: dict[str, Any]) -> list[float]:
    """When the script's velocity goal changed [s after the first surface command].

    The windows below are timed from these, not from the script's own seconds: the first
    command goes out when the surface node has started, which on a loaded start is late on
    its script, and the later steps then come early against it."""
    twists = run['msgs']['/surface_command/twist']
    t0 = stamp(twists[0][1])
    goals = [(stamp(m) - t0, (m.twist.linear.x, m.twist.linear.z)) for _, m in twists]
    return [t for (_, a), (t, b) in zip(goals, goals[1:]) if a != b]


def test_diving_drives_the_vertical_escs_down(run: dict[str, Any]) -> None:
    """Armed, until 4 s: dive at 0.2 m/s (FLU z up): the vertical thrusters push down, their
    pulses below the ESC dead band, the horizontal ones about neutral."""
    t0 = stamp(run['msgs']['/surface_command/twist'][0][1])
    ahead = _changes(run)[0]               # the script's 4 s: 0.4 m/s ahead
    window = _window(run, max(ARMING, _armed_at(run) - t0) + 0.5, ahead - 0.1)
    assert window
    for p in window:
        assert all(p[n] < NEUTRAL - DEAD_BAND for n in VERTICAL), p


def test_driving_forward_drives_the_horizontal_escs_ahead(run: dict[str, Any]) -> None:
    """4-8 s: 0.4 m/s ahead: the vectored thrusters' pulses above the dead band in the
    directions that add up to surge (front_right/front_left both push forward)."""
    ahead, slower = _changes(run)[:2]      # the script's 4 s and 8 s
    window = _window(run, ahead + 1.0, slower - 0.1)
    assert window
    for p in window:
        assert p['front_right'] > NEUTRAL + DEAD_BAND and p['front_left'] > NEUTRAL + DEAD_BAND


def test_the_vehicle_dove_and_drove(run: dict[str, Any]) -> None:
    """The dive has the 4 s of the script less the arming (at most 0.2 m/s x 2 s = 0.4 m)."""
    odom = [m.pose.pose.position for _, m in run['msgs']['/sim/odometry']]
    assert min(p.z for p in odom) < odom[0].z - 0.1   # down from where it started
    assert max(p.x for p in odom) > 1.0               # ahead


def test_the_imu_driver_read_the_emulated_chip(run: dict[str, Any]) -> None:
    raw = [m for _, m in run['msgs']['/imu/data_raw']]
    rate = PROFILE.node('imu').parameters['rate']
    # polled at its rate for most of the time it ran (the start of 22 nodes, before the first
    # sample, is not the driver's: it took 4-7 s of the 21 on this VM)
    span = stamp(raw[-1]) - stamp(raw[0])
    assert span > 0.5 * DURATION and len(raw) > 0.6 * rate * span
    assert all(m.header.frame_id == 'imu_link' for m in raw)
    g = sum(m.linear_acceleration.z for m in raw) / len(raw)
    assert 9.0 < g < 10.6                          # specific force, REP-145


def test_lights_and_manipulator_through_mock_pins(run: dict[str, Any]) -> None:
    states = [m for _, m in run['msgs']['/io_state']]
    assert [m.value.bool_value for m in states if m.name == 'gpio_12'] == [True, False]
    steps = [m.value.integer_value for m in states if m.name == 'manipulator']
    assert steps and steps[-1] == 400


def test_the_bag_ends_with_every_esc_at_neutral(run: dict[str, Any]) -> None:
    """After the run, the chip outputs the stop pulse on every thruster channel (one count
    of the 200 Hz PWM is 4.9 us)."""
    _, last = _pulses(run)[-1]
    assert set(last) == set(VERTICAL + FRONT)
    assert all(abs(v - NEUTRAL) < 5.0 for v in last.values()), last
