"""Thrust feedback (pure): expected speed of a quadratic propeller, blocked and tangled rotors
found after the hold time, never a healthy one spinning up, a failure latched until cleared.
"""

from __future__ import annotations

import math

import pytest

from enbarr_core.control.thruster_health import (
    expected_speed, HealthSettings, short_of, ThrusterHealth)

pytestmark = pytest.mark.unit

FULL = 300.0   # rad/s at full throttle
SETTINGS = HealthSettings(full_speed=FULL, min_command=0.2, ratio=0.5, hold_time=0.5)
MS = 1_000_000


def test_expected_speed_is_the_square_root_law():
    # T = K_T rho D^4 n|n| with T proportional to the command: n = sign(c) sqrt(|c|) n_full
    assert expected_speed(0.25, FULL) == pytest.approx(150.0)
    assert expected_speed(-1.0, FULL) == pytest.approx(-300.0)
    assert expected_speed(0.0, FULL) == 0.0


@pytest.mark.parametrize('command, speed, short', [
    (0.25, 150.0, False),     # as expected
    (0.25, 76.0, False),      # just above half the expected speed
    (0.25, 74.0, True),       # just below
    (0.25, -150.0, True),     # turning the other way
    (-1.0, -300.0, False),
    (-1.0, 0.0, True),        # blocked in reverse
    (0.1, 0.0, False),        # below min_command: not judged
])
def test_short_of(command, speed, short):
    assert short_of(command, speed, SETTINGS) is short


def spin(health, name, command, speeds, t0_ns=0, period_ms=20):
    """Command once, then feed ``speeds`` every ``period_ms``; return the first failure."""
    health.commanded(name, command)
    for k, speed in enumerate(speeds):
        why = health.measured(name, speed, t0_ns + k * period_ms * MS)
        if why is not None:
            return k, why
    return None


def test_a_blocked_rotor_fails_after_the_hold_time_and_stays_failed():
    h = ThrusterHealth(['a', 'b'], SETTINGS)
    found = spin(h, 'a', 0.8, [0.0] * 60)
    assert found is not None
    k, why = found
    assert k == 25                       # 25 x 20 ms = the 0.5 s hold, not before
    assert 'blocked or tangled' in why and '+0.80' in why
    assert set(h.failed) == {'a'}
    # reported once: still blocked, it is not found again
    assert spin(h, 'a', 0.8, [0.0] * 60, t0_ns=1_000 * MS) is None
    # latched: turning again by itself does not bring it back
    assert spin(h, 'a', 0.8, [expected_speed(0.8, FULL)] * 10, t0_ns=2_000 * MS) is None
    assert set(h.failed) == {'a'}
    h.clear('a')
    assert h.failed == {}


def test_a_healthy_rotor_spinning_up_never_fails():
    # a first-order motor, time constant 0.15 s: below half speed for the first ~0.1 s only
    h = ThrusterHealth(['a'], SETTINGS)
    want = expected_speed(1.0, FULL)
    speeds = [want * (1.0 - math.exp(-k * 0.02 / 0.15)) for k in range(100)]
    assert spin(h, 'a', 1.0, speeds) is None


def test_a_break_in_the_shortfall_restarts_the_hold():
    h = ThrusterHealth(['a'], SETTINGS)
    speeds = [0.0] * 20 + [300.0] + [0.0] * 20    # never 0.5 s in a row
    assert spin(h, 'a', 1.0, speeds) is None


def test_a_tangled_rotor_at_a_third_of_its_speed_fails():
    h = ThrusterHealth(['a'], SETTINGS)
    assert spin(h, 'a', -0.6, [expected_speed(-0.6, FULL) / 3.0] * 40) is not None


def test_unknown_names_and_non_finite_speeds_are_not_judged():
    h = ThrusterHealth(['a'], SETTINGS)
    h.commanded('x', 1.0)
    assert h.measured('x', 0.0, 10**10) is None
    assert spin(h, 'a', 1.0, [math.nan] * 60) is None
    assert h.failed == {}


def test_clear_all():
    h = ThrusterHealth(['a', 'b'], SETTINGS)
    spin(h, 'a', 1.0, [0.0] * 30)
    spin(h, 'b', 1.0, [0.0] * 30)
    assert set(h.failed) == {'a', 'b'}
    h.clear()
    assert h.failed == {}


@pytest.mark.parametrize('field, value, match', [
    ('full_speed', 0.0, '^full_speed'), ('min_command', 0.0, '^min_command'),
    ('ratio', 1.0, '^ratio'), ('hold_time', math.inf, '^hold_time')])
def test_settings_name_the_bad_field(field, value, match):
    values = {'full_speed': FULL, 'min_command': 0.2, 'ratio': 0.5, 'hold_time': 0.5,
              field: value}
    with pytest.raises(ValueError, match=match):
        HealthSettings(**values).validate()
