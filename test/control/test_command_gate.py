"""The command gate's rules (pure tier): failsafe latency, freshness, limits and counts.

Times are integer nanoseconds, so every boundary is exact: the gate's documented choice is
that every limit is inclusive (a command exactly at a limit, a stamp exactly ``max_age`` old
or ``max_future`` ahead is accepted; the goal is held through ``timeout`` and is zero from
``timeout`` + 1 ns on). The numbers below are chosen by hand, never read back from the gate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.control.command_gate import CommandGate, GateSettings, Verdict

S = 1_000_000_000   # ns per second
T0 = 1_000 * S      # an arbitrary clock reading [ns]
SETTINGS = GateSettings(max_linear=0.8, max_angular=0.6, timeout=0.3, max_age=0.2,
                        max_future=0.05)
TIMEOUT_NS = 300_000_000
MAX_AGE_NS = 200_000_000
MAX_FUTURE_NS = 50_000_000
WANTED = np.array([0.3, -0.2, 0.1, 0.0, 0.05, -0.4])


@pytest.fixture
def gate() -> CommandGate:
    return CommandGate(SETTINGS)


# -- failsafe latency ------------------------------------------------------------------------

def test_no_goal_before_the_first_command(gate):
    # The goal is public: before any command it is already six zeros, not a placeholder.
    np.testing.assert_array_equal(gate.goal, np.zeros(6))
    assert gate.failsafe(T0)
    np.testing.assert_array_equal(gate.current_goal(T0), np.zeros(6))


@pytest.mark.parametrize('eps_ns', [1, 1_000_000])
def test_goal_held_until_timeout_and_zero_just_after(gate, eps_ns):
    assert gate.offer(WANTED, T0, T0) is Verdict.ACCEPTED
    for now in (T0, T0 + TIMEOUT_NS // 2, T0 + TIMEOUT_NS - eps_ns, T0 + TIMEOUT_NS):
        assert not gate.failsafe(now), now - T0
        np.testing.assert_array_equal(gate.current_goal(now), WANTED)
    assert gate.failsafe(T0 + TIMEOUT_NS + eps_ns)
    np.testing.assert_array_equal(gate.current_goal(T0 + TIMEOUT_NS + eps_ns), np.zeros(6))


def test_timeout_counts_from_the_last_accepted_command_not_the_last_offered(gate):
    gate.offer(WANTED, T0, T0)
    late = T0 + 250_000_000
    assert gate.offer(WANTED * 2.0, late, late) is Verdict.OUT_OF_RANGE  # refused: no renewal
    assert gate.failsafe(T0 + TIMEOUT_NS + 1)
    gate.offer(WANTED, late, late)                                    # accepted: renewed
    assert not gate.failsafe(late + TIMEOUT_NS)
    assert gate.failsafe(late + TIMEOUT_NS + 1)


def test_the_failsafe_latches_until_a_new_command(gate):
    gate.offer(WANTED, T0, T0)
    assert not np.any(gate.current_goal(T0 + TIMEOUT_NS + 1))
    # Asking again later, or with an earlier time, never brings the old command back.
    assert not np.any(gate.current_goal(T0 + TIMEOUT_NS + 2))
    assert not np.any(gate.current_goal(T0 + 1))
    later = T0 + 10 * S
    gate.offer(-WANTED, later, later)
    np.testing.assert_array_equal(gate.current_goal(later + TIMEOUT_NS), -WANTED)


def test_a_clock_that_goes_back_fails_safe(gate):
    gate.offer(WANTED, T0, T0)
    assert gate.failsafe(T0 - 1)  # the command's age is unknown: zero, not an hour of driving
    assert not np.any(gate.current_goal(T0 - S))


def test_a_new_timeout_acts_on_the_command_in_hand(gate):
    gate.offer(WANTED, T0, T0)
    gate.settings = GateSettings(timeout=0.1)
    assert not gate.failsafe(T0 + 100_000_000)
    assert gate.failsafe(T0 + 100_000_001)


def test_the_boundaries_are_whole_nanoseconds():
    # 1.001 s * 1e9 is 1000999999.9999999 in floating point (1.003 and 1.005 likewise fall
    # below their whole nanosecond): the gate holds exactly 1 001 000 000 ns etc., so a
    # command is held, or accepted, exactly at its limit as documented.
    gate = CommandGate(GateSettings(timeout=1.001, max_age=1.003, max_future=1.005))
    assert gate.check(WANTED, T0 - 1_003_000_000, T0) is Verdict.ACCEPTED
    gate.offer(WANTED, T0 - 1_003_000_000, T0)
    assert not gate.failsafe(T0 + 1_001_000_000)
    assert gate.failsafe(T0 + 1_001_000_001)
    assert gate.check(WANTED, T0 - 1_003_000_001, T0) is Verdict.STALE
    assert gate.check(WANTED, T0 + 1_005_000_000, T0) is Verdict.ACCEPTED
    assert gate.check(WANTED, T0 + 1_005_000_001, T0) is Verdict.FUTURE


# -- freshness ------------------------------------------------------------------------------

@pytest.mark.parametrize('age_ns,verdict', [
    (0, Verdict.ACCEPTED),
    (MAX_AGE_NS - 1, Verdict.ACCEPTED),
    (MAX_AGE_NS, Verdict.ACCEPTED),         # exactly max_age old: still fresh
    (MAX_AGE_NS + 1, Verdict.STALE),
    (60 * S, Verdict.STALE),
    (-MAX_FUTURE_NS, Verdict.ACCEPTED),     # exactly max_future ahead: accepted
    (-MAX_FUTURE_NS - 1, Verdict.FUTURE),
    (-60 * S, Verdict.FUTURE),
])
def test_stamps_are_judged_by_their_age(gate, age_ns, verdict):
    assert gate.check(WANTED, T0 - age_ns, T0) is verdict
    assert gate.offer(WANTED, T0 - age_ns, T0) is verdict
    assert (gate.last_accept_ns == T0) is (verdict is Verdict.ACCEPTED)


def test_the_timeout_runs_from_reception_not_from_the_stamp(gate):
    # A command stamped max_age ago, received now, holds for the whole timeout from now.
    gate.offer(WANTED, T0 - MAX_AGE_NS, T0)
    assert not gate.failsafe(T0 + TIMEOUT_NS)


# -- limits and non-finite values -----------------------------------------------------------

def _one(index: int, value: float) -> np.ndarray:
    nu = np.zeros(6)
    nu[index] = value
    return nu


@pytest.mark.parametrize('index', range(6))
def test_limits_are_inclusive_in_every_component(gate, index):
    limit = 0.8 if index < 3 else 0.6
    for value in (limit, -limit):
        assert gate.check(_one(index, value), T0, T0) is Verdict.ACCEPTED
    for value in (np.nextafter(limit, 1.0), -np.nextafter(limit, 1.0)):
        assert gate.check(_one(index, value), T0, T0) is Verdict.OUT_OF_RANGE


def test_linear_and_angular_limits_are_apart(gate):
    # 0.7 is inside the linear limit (0.8) but outside the angular one (0.6).
    assert gate.check(_one(0, 0.7), T0, T0) is Verdict.ACCEPTED
    assert gate.check(_one(5, 0.7), T0, T0) is Verdict.OUT_OF_RANGE


@pytest.mark.parametrize('index', range(6))
def test_each_component_has_its_own_kinds_limit_either_way_round(index):
    # With the angular limit above the linear one (0.5 m/s, 1.0 rad/s), 0.8 is a valid rate
    # and an invalid speed: u, v, w go by max_linear only and p, q, r by max_angular only
    # (with SETTINGS the angular limit is the smaller one, so a rate judged by both passed).
    gate = CommandGate(GateSettings(max_linear=0.5, max_angular=1.0))
    verdict = Verdict.OUT_OF_RANGE if index < 3 else Verdict.ACCEPTED
    assert gate.check(_one(index, 0.8), T0, T0) is verdict
    assert gate.check(_one(index, -0.8), T0, T0) is verdict


@pytest.mark.parametrize('index', range(6))
@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_components_are_refused(gate, index, bad):
    assert gate.offer(_one(index, bad), T0, T0) is Verdict.NON_FINITE
    assert gate.last_accept_ns is None and not np.any(gate.goal)


def test_a_refused_command_never_changes_the_goal(gate):
    gate.offer(WANTED, T0, T0)
    for nu, stamp in ((_one(0, math.nan), T0), (_one(0, 0.9), T0),
                      (_one(0, 0.5), T0 - S), (_one(0, 0.5), T0 + S)):
        gate.offer(nu, stamp, T0 + 1)
        np.testing.assert_array_equal(gate.current_goal(T0 + 1), WANTED)


def test_the_verdict_order_is_non_finite_range_stale_future(gate):
    # A command wrong in several ways gets the first verdict of that order.
    assert gate.check(np.array([math.nan, 5.0, 0, 0, 0, 0]), T0 - S, T0) is Verdict.NON_FINITE
    assert gate.check(_one(0, 5.0), T0 - S, T0) is Verdict.OUT_OF_RANGE
    assert gate.check(_one(0, 0.5), T0 - S, T0) is Verdict.STALE


def test_the_goal_is_float_whatever_the_caller_passes():
    # A caller may build its command from integers (a button mapping): the goal is still the
    # float64 array its type promises, so a later fractional update cannot be truncated.
    gate = CommandGate(GateSettings(max_linear=1.0))
    assert gate.offer([0, 1, 0, 0, 0, 0], T0, T0) is Verdict.ACCEPTED
    assert gate.goal.dtype == np.float64
    np.testing.assert_array_equal(gate.goal, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0])


def test_the_goal_is_a_copy_of_the_command(gate):
    nu = WANTED.copy()
    gate.offer(nu, T0, T0)
    nu[0] = 0.0  # the caller reuses its array
    assert gate.goal[0] == WANTED[0]


# -- counts -----------------------------------------------------------------------------------

def test_every_offer_is_counted_once_under_its_verdict(gate):
    offers = [(WANTED, 1), (WANTED, 0), (WANTED, 0), (_one(1, math.nan), 0), (_one(2, 1.0), 0),
              (_one(3, -0.7), 0), (WANTED, 2 * MAX_AGE_NS), (WANTED, -2 * MAX_FUTURE_NS)]
    for nu, age in offers:
        gate.offer(nu, T0 - age, T0)
    assert gate.counts == {Verdict.ACCEPTED: 2, Verdict.NON_FINITE: 1, Verdict.NOT_NEWER: 1,
                           Verdict.OUT_OF_RANGE: 2, Verdict.STALE: 1, Verdict.FUTURE: 1,
                           Verdict.WRONG_FRAME: 0, Verdict.CONTESTED: 0}
    gate.check(_one(0, math.nan), T0, T0)  # check alone counts nothing
    assert sum(gate.counts.values()) == len(offers)


# -- settings ---------------------------------------------------------------------------------

@pytest.mark.parametrize('field', ['max_linear', 'max_angular', 'timeout', 'max_age',
                                   'max_future'])
@pytest.mark.parametrize('bad', [-0.1, math.nan, math.inf])
def test_bad_settings_are_refused_naming_the_field(field, bad):
    with pytest.raises(ValueError, match=field):
        CommandGate(GateSettings(**{field: bad}))


def test_a_zero_timeout_is_refused():
    with pytest.raises(ValueError, match='timeout'):
        GateSettings(timeout=0.0).validate()


def test_zero_limits_and_windows_are_allowed():
    gate = CommandGate(GateSettings(max_linear=0.0, max_angular=0.0, max_age=0.0,
                                    max_future=0.0))
    assert gate.check(np.zeros(6), T0, T0) is Verdict.ACCEPTED
    assert gate.check(np.zeros(6), T0 - 1, T0) is Verdict.STALE
    assert gate.check(np.zeros(6), T0 + 1, T0) is Verdict.FUTURE
    assert gate.check(_one(0, 1e-9), T0, T0) is Verdict.OUT_OF_RANGE


def test_bad_new_settings_are_refused_and_the_old_kept(gate):
    with pytest.raises(ValueError, match='timeout'):
        gate.settings = GateSettings(timeout=-1.0)
    assert gate.settings == SETTINGS


# -- ordering, frame, contested -------------------------------------------------------------

def test_a_command_not_newer_than_the_last_accepted_is_refused(gate):
    assert gate.offer(WANTED, T0, T0) is Verdict.ACCEPTED
    assert gate.offer(WANTED * 0.5, T0, T0 + 1) is Verdict.NOT_NEWER
    assert gate.offer(WANTED * 0.5, T0 - 1, T0 + 1) is Verdict.NOT_NEWER
    np.testing.assert_array_equal(gate.goal, WANTED)
    assert gate.offer(WANTED * 0.5, T0 + 1, T0 + 1) is Verdict.ACCEPTED
    assert gate.counts[Verdict.NOT_NEWER] == 2


def test_a_refused_command_does_not_move_the_order(gate):
    gate.offer(WANTED, T0, T0)
    assert gate.offer(WANTED * 9.0, T0 + 5, T0 + 5) is Verdict.OUT_OF_RANGE
    assert gate.offer(WANTED, T0 + 2, T0 + 5) is Verdict.ACCEPTED


@pytest.mark.parametrize('frame_id, verdict', [
    ('base_link', Verdict.ACCEPTED), ('', Verdict.ACCEPTED), ('odom', Verdict.WRONG_FRAME),
    ('base_link ', Verdict.WRONG_FRAME)])
def test_frames_other_than_base_link_are_refused(gate, frame_id, verdict):
    assert gate.offer(WANTED, T0, T0, frame_id) is verdict


def test_withdraw_counts_and_engages_the_failsafe(gate):
    gate.offer(WANTED, T0, T0)
    gate.withdraw(Verdict.CONTESTED)
    assert gate.failsafe(T0 + 1)
    np.testing.assert_array_equal(gate.current_goal(T0 + 1), np.zeros(6))
    assert gate.counts[Verdict.CONTESTED] == 1
    with pytest.raises(ValueError):
        gate.withdraw(Verdict.ACCEPTED)
