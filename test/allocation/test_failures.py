"""Allocation with failed thrusters (pure algorithm tier).

The layouts are read from the profiles (the ROV's ``enbarr_sim.yaml``, the Saucer's
``saucer_core.yaml``); the configuration matrices are built here again from positions and
directions, and the expected thrusts and lost DOFs are derived by hand in the comments or by an
independent ``numpy.linalg.lstsq`` on the columns left, never from the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.layouts import ROV, rov_thrusters, SAUCER, saucer_specs

from enbarr_core.allocation import azimuth as azimuth_module
from enbarr_core.allocation import fixed as fixed_module
from enbarr_core.allocation.azimuth import AzimuthAllocator
from enbarr_core.allocation.failures import (
    DEAD, DIAGNOSTIC_KEY, Failure, FailureBook, parse_entries, parse_entry, STUCK)
from enbarr_core.allocation.fixed import ThrustAllocator

def rov_B(names: list[str]) -> np.ndarray:
    """Columns [d; r x d] of the named thrusters, written out from the profile."""
    cols = []
    for n in names:
        r = np.array(ROV['thrusters'][n]['position'], dtype=float)
        d = np.array(ROV['thrusters'][n]['direction'], dtype=float)
        d /= np.linalg.norm(d)
        cols.append(np.concatenate([d, np.cross(r, d)]))
    return np.array(cols).T


SAUCER_POS = {n: SAUCER['azimuths'][n]['position'] for n in SAUCER['azimuth_names']}
ALL8 = list(ROV['thruster_names'])
C45 = math.sqrt(0.5)  # the horizontal thrusters point at 45 deg: |d_x| = |d_y| = cos 45


def tau_of_azimuths(names, thrust, angle) -> np.ndarray:
    """[X, Y, N] of azimuths ``names`` with thrust T and angle a (N = x T sin a - y T cos a)."""
    out = np.zeros(3)
    for n, T, a in zip(names, thrust, angle):
        x, y = SAUCER_POS[n]
        out += [T * math.cos(a), T * math.sin(a), x * T * math.sin(a) - y * T * math.cos(a)]
    return out


# -- the ROV's eight fixed thrusters --------------------------------------------------------

def test_the_profile_is_the_layout_these_answers_were_derived_for():
    # Four horizontal at z = 0, 45 deg, at (+-0.156, +-0.111); four vertical at (+-0.12, +-0.218).
    assert ALL8[:4] == ['front_right', 'front_left', 'rear_right', 'rear_left']
    assert ROV['thrusters']['front_right']['position'] == [0.156, -0.111, 0.0]
    assert ROV['thrusters']['vert_front_right']['position'] == [0.12, -0.218, 0.0]


def test_one_horizontal_dead_still_gives_surge_sway_yaw_exactly():
    a = ThrustAllocator(rov_thrusters())
    a.fail('front_right')
    assert a.lost_dofs == () and a.rank == 6
    assert a.failed == {'front_right': Failure(DEAD)}
    # Surge alone, by hand (columns in units of cos 45: FL (1,-1,-k), RR (1,-1,k),
    # RL (1,1,-k)): Y = 0 and N = 0 give FL = 0, RR = RL, so RR = RL = X / (2 cos 45).
    r = a.allocate([5.0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(r.thrust[:4], [0.0, 0.0, 5.0 / (2 * C45), 5.0 / (2 * C45)],
                               atol=1e-12)
    # Within rounding: the BLAS kernel a CPU picks leaves ~1e-16 (AVX-512: -6.7e-17).
    np.testing.assert_allclose(r.thrust[4:], 0.0, atol=1e-12)
    # A small general demand: three columns left for X, Y, N, so one exact solution.
    tau = np.array([3.0, -2.0, 1.5, 0.2, -0.1, 0.4])
    r = a.allocate(tau)
    assert r.thrust[0] == 0.0 and r.command[0] == 0.0 and not r.saturated
    h = np.linalg.solve(rov_B(ALL8[1:4])[[0, 1, 5], :], tau[[0, 1, 5]])
    np.testing.assert_allclose(r.thrust[1:4], h, atol=1e-12)
    np.testing.assert_allclose(rov_B(ALL8) @ r.thrust, tau, atol=1e-12)


def test_one_vertical_dead_keeps_heave_roll_pitch():
    a = ThrustAllocator(rov_thrusters())
    a.fail('vert_front_right')
    assert a.lost_dofs == () and a.rank == 6
    # Heave alone, by hand (columns (1, y, -x)): K = 0 and M = 0 with FL, RR, RL give RL = 0 and
    # FL = RR = Z / 2: the diagonal pair left carries it.
    r = a.allocate([0, 0, 4.0, 0, 0, 0])
    np.testing.assert_allclose(r.thrust[4:], [0.0, 2.0, 2.0, 0.0], atol=1e-12)
    tau = np.array([1.0, 0.5, 6.0, 0.3, -0.4, 0.2])
    r = a.allocate(tau)
    np.testing.assert_allclose(rov_B(ALL8) @ r.thrust, tau, atol=1e-12)


@pytest.mark.parametrize('dead, lost', [
    # FR (1,1,k) and FL (1,-1,-k) gone: RR (1,-1,k), RL (1,1,-k) give e_X = (RR + RL) / 2,
    # but RL - RR = (0, 2, -2k): sway only with yaw, so both are lost.
    (['front_right', 'front_left'], ('sway', 'yaw')),
    # FR and RL (the pair pushing along (1, 1)) gone: FL - RR = (0, 0, -2k) is pure yaw;
    # FL + RR = (2, -2, 0) couples surge and sway.
    (['front_right', 'rear_left'], ('surge', 'sway')),
    (['vert_front_right', 'vert_front_left', 'vert_rear_right', 'vert_rear_left'],
     ('heave', 'roll', 'pitch')),
])
def test_what_the_thrusters_left_cannot_produce_is_reported_and_dropped(dead, lost):
    a = ThrustAllocator(rov_thrusters())
    for n in dead:
        a.fail(n)
    assert a.lost_dofs == lost
    tau = np.array([2.0, -1.5, 3.0, 0.2, -0.3, 0.5])
    r = a.allocate(tau)
    kept = [j for j, d in enumerate(fixed_module.DOF_NAMES) if d not in lost]
    gone = [j for j, d in enumerate(fixed_module.DOF_NAMES) if d in lost]
    delivered = rov_B(ALL8) @ r.thrust
    np.testing.assert_allclose(delivered[kept], tau[kept], atol=1e-12)  # the rest exactly
    np.testing.assert_allclose(delivered[gone], 0.0, atol=1e-12)        # nothing leaks
    assert all(r.thrust[ALL8.index(n)] == 0.0 for n in dead)
    # The same thrusts as the minimum-norm least squares on the columns left, for the
    # demand with the lost DOFs set to zero (an independent solver).
    alive = [n for n in ALL8 if n not in dead]
    want = tau.copy()
    want[gone] = 0.0
    f, *_ = np.linalg.lstsq(rov_B(alive), want, rcond=None)
    np.testing.assert_allclose(r.thrust[[ALL8.index(n) for n in alive]], f, atol=1e-12)


def test_restore_gives_back_the_nominal_solution_bit_for_bit():
    a = ThrustAllocator(rov_thrusters())
    rng = np.random.default_rng(7)
    taus = rng.normal(size=(20, 6)) * [20, 20, 20, 2, 2, 2]
    nominal = [a.allocate(t) for t in taus]
    B_pinv = a.B_pinv.copy()
    a.fail('rear_left')
    a.fail('vert_rear_left')
    assert not np.array_equal(a.B_pinv, B_pinv)
    a.restore('vert_rear_left')
    a.restore('rear_left')
    assert a.failed == {} and a.lost_dofs == ()
    assert np.array_equal(a.B_pinv, B_pinv)
    for t, r0 in zip(taus, nominal):
        r = a.allocate(t)
        for field in ('thrust', 'command', 'tau_delivered'):
            assert np.array_equal(getattr(r, field), getattr(r0, field))
        assert r.scale == r0.scale


def test_saturation_with_a_dead_thruster_keeps_the_direction():
    a = ThrustAllocator(rov_thrusters())
    a.fail('front_left')
    big = np.array([300.0, 100.0, 200.0, 5.0, -5.0, 20.0])
    r = a.allocate(big)
    assert r.saturated and 0.0 < r.scale < 1.0
    assert np.max(np.abs(r.command)) == pytest.approx(1.0)
    np.testing.assert_allclose(rov_B(ALL8) @ r.thrust, r.scale * big, rtol=1e-9, atol=1e-9)


def test_the_pseudo_inverse_is_recomputed_once_per_change_not_per_call(monkeypatch):
    a = ThrustAllocator(rov_thrusters())
    calls = []
    real = fixed_module.reachable_pinv
    monkeypatch.setattr(fixed_module, 'reachable_pinv', lambda *x: calls.append(1) or real(*x))
    a.fail('front_right')
    for _ in range(50):
        a.allocate([1.0, 2.0, 3.0, 0.0, 0.0, 0.1])
    a.fail('front_right')  # no change: no new solve
    assert len(calls) == 1


def test_fixed_failures_are_checked():
    a = ThrustAllocator(rov_thrusters())
    with pytest.raises(ValueError, match="unknown thruster 'nope'"):
        a.fail('nope')
    with pytest.raises(ValueError, match='can only be'):
        a.set_failures({'front_right': Failure(STUCK, 0.3)})
    assert a.failed == {}


# -- the CS Saucer's three azimuths ---------------------------------------------------------

SAUCER_NAMES = list(SAUCER['azimuth_names'])  # az_bow, az_port_aft, az_stbd_aft


def ext_columns(names) -> np.ndarray:
    """B_ext of ``names``: per azimuth [1, 0, -y] (f_x) and [0, 1, x] (f_y)."""
    cols = []
    for n in names:
        x, y = SAUCER_POS[n]
        cols += [[1.0, 0.0, -y], [0.0, 1.0, x]]
    return np.array(cols).T


@pytest.mark.parametrize('dead', SAUCER_NAMES)
def test_one_azimuth_dead_the_two_left_give_surge_sway_yaw(dead):
    a = AzimuthAllocator(saucer_specs())
    a.fail(dead)
    assert a.lost_dofs == () and a.rank == 3
    left = [n for n in SAUCER_NAMES if n != dead]
    assert np.linalg.matrix_rank(ext_columns(left)) == 3  # 4 columns, rank 3
    for tau in ([0.5, -0.3, 0.05], [0.0, 0.8, 0.0], [-0.4, 0.0, -0.06]):
        r = a.allocate(tau)
        assert r.feasible
        i = SAUCER_NAMES.index(dead)
        assert r.thrust[i] == 0.0
        keep = [SAUCER_NAMES.index(n) for n in left]
        np.testing.assert_allclose(tau_of_azimuths(left, r.thrust[keep], r.angle[keep]), tau,
                                   atol=1e-12)
        # Equal weights: the least-norm pair is numpy's minimum-norm lstsq on the 4 columns.
        f, *_ = np.linalg.lstsq(ext_columns(left), np.array(tau), rcond=None)
        np.testing.assert_allclose(np.abs(r.thrust[keep]), np.hypot(f[0::2], f[1::2]),
                                   atol=1e-12)


@pytest.mark.parametrize('name, deg', [('az_bow', 30.0), ('az_port_aft', -60.0)])
def test_a_stuck_azimuth_pushes_only_along_its_angle(name, deg):
    a = AzimuthAllocator(saucer_specs())
    stuck = math.radians(deg)
    a.fail(name, STUCK, stuck)
    assert a.lost_dofs == () and a.failed[name] == Failure(STUCK, stuck)
    i = SAUCER_NAMES.index(name)
    others = [n for n in SAUCER_NAMES if n != name]
    x, y = SAUCER_POS[name]
    col = [math.cos(stuck), math.sin(stuck), x * math.sin(stuck) - y * math.cos(stuck)]
    B = np.column_stack([col, ext_columns(others)])
    for tau in ([0.5, -0.3, 0.05], [-0.6, 0.2, 0.0], [0.0, 0.0, 0.08]):
        r = a.allocate(tau, previous_angle=[0.0, 0.0, 0.0])
        assert r.angle[i] == pytest.approx(stuck, abs=0.0)
        np.testing.assert_allclose(tau_of_azimuths(SAUCER_NAMES, r.thrust, r.angle), tau,
                                   atol=1e-12)
        f, *_ = np.linalg.lstsq(B, np.array(tau), rcond=None)  # 5 columns, equal weights
        assert r.thrust[i] == pytest.approx(f[0], abs=1e-12)   # signed: reverse allowed
        rest = [SAUCER_NAMES.index(n) for n in others]
        np.testing.assert_allclose(np.abs(r.thrust[rest]), np.hypot(f[1::2], f[2::2]),
                                   atol=1e-12)


def test_two_dead_report_what_one_azimuth_cannot_give():
    a = AzimuthAllocator(saucer_specs())
    a.fail('az_port_aft')
    a.fail('az_stbd_aft')
    # The bow one at (x, 0): [1, 0, 0] is pure surge; [0, 1, x] couples sway with yaw, and
    # no combination gives pure yaw.
    assert a.lost_dofs == ('sway', 'yaw') and a.rank == 2
    r = a.allocate([0.5, 0.3, 0.05])
    np.testing.assert_allclose(r.tau_delivered, [0.5, 0.0, 0.0], atol=1e-12)
    assert r.thrust[1] == 0.0 and r.thrust[2] == 0.0
    # An aft one alone at (x, y), y != 0: f_x brings -y f_x of yaw, f_y brings x f_y: no DOF
    # is free of another, all three are lost and it is commanded nothing.
    a.restore('az_port_aft')
    a.fail('az_bow')
    assert a.lost_dofs == ('surge', 'sway', 'yaw')
    r = a.allocate([0.5, 0.3, 0.05])
    assert np.all(r.thrust == 0.0)
    a.fail('az_port_aft')  # all three dead
    assert a.lost_dofs == ('surge', 'sway', 'yaw') and a.rank == 0
    assert np.all(a.allocate([0.5, 0.3, 0.05]).thrust == 0.0)


def test_saucer_saturation_with_one_dead_keeps_the_direction():
    a = AzimuthAllocator(saucer_specs())
    a.fail('az_bow')
    big = np.array([4.0, -2.0, 0.2])
    r = a.allocate(big)
    assert not r.feasible and 0.0 < r.scale < 1.0
    np.testing.assert_allclose(r.tau_delivered, r.scale * big, rtol=1e-9, atol=1e-12)
    limits = [SAUCER['azimuths'][n] for n in SAUCER_NAMES[1:]]
    assert any(math.isclose(T, lim['max_forward']) or math.isclose(-T, lim['max_reverse'])
               for T, lim in zip(r.thrust[1:], limits))


def test_saucer_restore_gives_back_the_nominal_solution_bit_for_bit(monkeypatch):
    a = AzimuthAllocator(saucer_specs())
    rng = np.random.default_rng(11)
    taus = rng.normal(size=(20, 3)) * [0.5, 0.5, 0.05]
    prev = np.zeros(3)
    nominal = [a.allocate(t, previous_angle=prev) for t in taus]
    calls = []
    real = azimuth_module.reachable_pinv
    monkeypatch.setattr(azimuth_module, 'reachable_pinv', lambda *x: calls.append(1) or real(*x))
    a.fail('az_stbd_aft', STUCK, 0.4)
    for t in taus:
        a.allocate(t, previous_angle=prev)
    a.restore('az_stbd_aft')
    assert len(calls) == 2  # once per change, none per call
    for t, r0 in zip(taus, nominal):
        r = a.allocate(t, previous_angle=prev)
        for field in ('thrust', 'angle', 'tau_delivered'):
            assert np.array_equal(getattr(r, field), getattr(r0, field))


# -- the entries and where they come from ---------------------------------------------------

def test_entries_parse_and_name_the_bad_one():
    known = SAUCER_NAMES
    assert parse_entries(['', 'az_bow', 'az_port_aft:stuck:-45'], known, True) == {
        'az_bow': Failure(DEAD), 'az_port_aft': Failure(STUCK, math.radians(-45.0))}
    assert parse_entry('az_bow:dead', known, True) == ('az_bow', Failure(DEAD))
    for bad, match in (('az_mid', "'az_mid': unknown thruster 'az_mid'"),
                       ('az_bow:stuck', "'az_bow:stuck': expected"),
                       ('az_bow:stuck:abc', "'az_bow:stuck:abc': the stuck angle"),
                       ('az_bow:stuck:nan', 'the stuck angle'),
                       ('az_bow:melted', "'az_bow:melted': expected")):
        with pytest.raises(ValueError, match=match):
            parse_entries([bad], known, True)
    with pytest.raises(ValueError, match='listed twice'):
        parse_entries(['az_bow', 'az_bow:stuck:3'], known, True)
    with pytest.raises(ValueError, match=r"'front_right:stuck:10': expected front_right, "
                                         r'front_right:dead$'):
        parse_entries(['front_right:stuck:10'], ALL8, False)
    assert Failure(STUCK, math.radians(30.0)).entry('az_bow') == 'az_bow:stuck:30'


def test_failure_book_merges_operator_and_sources_and_clears_per_source():
    book = FailureBook(SAUCER_NAMES, allow_stuck=True)
    assert book.report('detector', 2, [('rpm', '0'), (DIAGNOSTIC_KEY, 'az_stbd_aft')]) == []
    assert book.report('other', 1, [(DIAGNOSTIC_KEY, 'az_bow')]) == []  # WARN: no failure
    book.set_operator({'az_port_aft': Failure(STUCK, 0.1)})
    assert list(book.merged()) == ['az_port_aft', 'az_stbd_aft']   # layout order
    problems = book.report('detector', 2, [(DIAGNOSTIC_KEY, 'az_mid'),
                                           (DIAGNOSTIC_KEY, 'az_bow:dead')])
    assert len(problems) == 1 and 'az_mid' in problems[0] and 'detector' in problems[0]
    assert list(book.merged()) == ['az_bow', 'az_port_aft']        # the source's latest
    book.report('detector', 0, [])                                  # OK again: cleared
    assert list(book.merged()) == ['az_port_aft']
    # The operator's word wins where both name the same thruster.
    book.report('detector', 2, [(DIAGNOSTIC_KEY, 'az_port_aft')])
    assert book.merged() == {'az_port_aft': Failure(STUCK, 0.1)}
