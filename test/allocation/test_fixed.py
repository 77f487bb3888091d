"""Thrust allocation (pure algorithm tier): checked against numpy / scipy least squares."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog, lsq_linear

from enbarr_core.allocation.fixed import (
    DOF_NAMES,
    AllocationResult,
    ThrustAllocator,
    Thruster,
    allocation_matrix,
)
from enbarr_core.framework.errors import AllocationError, ConfigurationError

F_FWD, F_REV = 40.0, 30.0


def vectored_8() -> list[Thruster]:
    """Vectored 8-thruster ROV: 4 horizontal at 45 deg in the corners, 4 vertical (+z)."""
    horizontal = [
        ('h_fl', (0.2, 0.15, 0.0), (1.0, -1.0, 0.0)),
        ('h_fr', (0.2, -0.15, 0.0), (1.0, 1.0, 0.0)),
        ('h_rl', (-0.2, 0.15, 0.0), (1.0, 1.0, 0.0)),
        ('h_rr', (-0.2, -0.15, 0.0), (1.0, -1.0, 0.0)),
    ]
    vertical = [
        (f'v_{i}', (x, y, 0.0), (0.0, 0.0, 1.0))
        for i, (x, y) in enumerate([(0.12, 0.22), (0.12, -0.22), (-0.12, 0.22), (-0.12, -0.22)])
    ]
    return [Thruster(n, p, d, F_FWD, F_REV) for n, p, d in horizontal + vertical]


def limits_for(f: np.ndarray) -> np.ndarray:
    return np.where(f >= 0.0, F_FWD, F_REV)


def random_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    v = rng.normal(size=(count, 6))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# --- geometry -----------------------------------------------------------------------------


def test_thruster_normalizes_direction_and_rejects_bad_values():
    t = Thruster('t', (1, 2, 3), (0.0, 3.0, 4.0), 10, 5)
    assert t.direction == pytest.approx((0.0, 0.6, 0.8))
    assert isinstance(t.position[0], float)
    with pytest.raises(ConfigurationError, match='direction'):
        Thruster('t', (0, 0, 0), (0, 0, 0), 10, 5)
    with pytest.raises(ConfigurationError, match='max_reverse'):
        Thruster('t', (0, 0, 0), (1, 0, 0), 10, 0)
    with pytest.raises(ConfigurationError, match='position'):
        Thruster('t', (0, math.nan, 0), (1, 0, 0), 10, 5)


def test_allocation_matrix_columns_are_force_and_moment():
    t = Thruster('t', (0.5, -0.25, 0.1), (0.0, 1.0, 0.0), 10, 10)
    B = allocation_matrix([t])
    # d = e_y; r x d = (x, y, z) x (0, 1, 0) = (-z, 0, x)
    np.testing.assert_allclose(B[:, 0], [0.0, 1.0, 0.0, -0.1, 0.0, 0.5])
    B8 = allocation_matrix(vectored_8())
    assert B8.shape == (6, 8)
    assert np.linalg.matrix_rank(B8) == 6
    # A vertical thruster at (x, y, 0) pushing +z rolls by +y and pitches by -x (FLU).
    np.testing.assert_allclose(B8[:, 4], [0, 0, 1, 0.22, -0.12, 0])


# --- unsaturated: equals the minimum-norm least-squares solution ----------------------------


def test_unsaturated_equals_lstsq_minimum_norm():
    alloc = ThrustAllocator(vectored_8())
    B = allocation_matrix(vectored_8())
    rng = np.random.default_rng(20240611)
    for direction in random_directions(rng, 200):
        f_ref = np.linalg.lstsq(B, direction, rcond=None)[0]
        # Scale into the attainable set: largest ratio |f|/limit in (0.05, 0.95).
        tau = direction * rng.uniform(0.05, 0.95) / np.max(np.abs(f_ref) / limits_for(f_ref))
        f_ref = np.linalg.lstsq(B, tau, rcond=None)[0]
        res = alloc.allocate(tau)
        assert isinstance(res, AllocationResult)
        assert not res.saturated and res.scale == 1.0
        np.testing.assert_allclose(res.thrust, f_ref, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(B @ res.thrust, tau, atol=1e-9)
        np.testing.assert_allclose(res.tau_delivered, tau, atol=1e-9)
        assert np.all(np.abs(res.command) < 1.0)


def test_weighted_solution_matches_kkt_system():
    """Min f^T W f s.t. B f = tau, solved independently from its KKT equations."""
    weights = [1.0, 2.0, 0.5, 1.0, 3.0, 1.0, 1.0, 0.25]
    alloc = ThrustAllocator(vectored_8(), weights=weights)
    B = allocation_matrix(vectored_8())
    W = np.diag(weights)
    kkt = np.block([[W, B.T], [B, np.zeros((6, 6))]])
    rng = np.random.default_rng(7)
    for tau in rng.normal(scale=5.0, size=(20, 6)):
        f_ref = np.linalg.solve(kkt, np.concatenate([np.zeros(8), tau]))[:8]
        res = alloc.allocate(tau * 1e-2)  # small: unsaturated
        np.testing.assert_allclose(res.thrust, f_ref * 1e-2, rtol=1e-9, atol=1e-12)
    # Heave with 4 verticals has one free direction (+v_0 -v_1 -v_2 +v_3): penalizing the
    # diagonal pair v_0, v_3 moves load onto v_1, v_2 (uniform weights share it equally).
    tau = np.array([0.0, 0.0, 10.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(ThrustAllocator(vectored_8()).allocate(tau).thrust[4:], 2.5)
    f = ThrustAllocator(vectored_8(), weights=[1, 1, 1, 1, 4, 1, 1, 4]).allocate(tau).thrust
    assert f[4] == pytest.approx(f[7]) and f[5] == pytest.approx(f[6]) and f[5] > 2.5 > f[4]
    with pytest.raises(ConfigurationError, match='weights'):
        ThrustAllocator(vectored_8(), weights=[1.0] * 7)
    with pytest.raises(ConfigurationError, match='weights'):
        ThrustAllocator(vectored_8(), weights=[1.0] * 7 + [0.0])


# --- saturated: direction preserving (contrasted with bounded least squares) -----------------


def test_saturated_is_direction_preserving_vs_bounded_lsq():
    alloc = ThrustAllocator(vectored_8())
    B = allocation_matrix(vectored_8())
    lb = -F_REV * np.ones(8)
    ub = F_FWD * np.ones(8)
    rng = np.random.default_rng(42)
    worst_lsq_angle = 0.0
    for direction in random_directions(rng, 25):
        f_ref = np.linalg.lstsq(B, direction, rcond=None)[0]
        tau = direction * 10.0 / np.max(np.abs(f_ref) / limits_for(f_ref))  # 10x too large
        res = alloc.allocate(tau)
        assert res.saturated and 0.0 < res.scale < 1.0
        assert res.scale == pytest.approx(0.1, rel=1e-9)
        # Parallel and same sense: tau_delivered = scale * tau.
        np.testing.assert_allclose(res.tau_delivered, res.scale * tau, rtol=1e-9, atol=1e-9)
        cos = res.tau_delivered @ tau / (np.linalg.norm(res.tau_delivered) * np.linalg.norm(tau))
        assert cos == pytest.approx(1.0, abs=1e-12)
        # Within limits, at least one thruster exactly at its limit.
        assert np.all(np.abs(res.command) <= 1.0)
        assert np.all(res.thrust <= ub * (1 + 1e-12)) and np.all(res.thrust >= lb * (1 + 1e-12))
        assert np.isclose(np.max(np.abs(res.command)), 1.0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(res.command, res.thrust / limits_for(res.thrust))

        # Bounded least squares minimizes |B f - tau| in the box: smaller residual than ours,
        # but its delivered force is in general not parallel to the request.
        f_box = lsq_linear(B, tau, bounds=(lb, ub), method='bvls').x
        tau_box = B @ f_box
        assert np.linalg.norm(tau_box - tau) <= np.linalg.norm(res.tau_delivered - tau) + 1e-6
        cos_box = tau_box @ tau / (np.linalg.norm(tau_box) * np.linalg.norm(tau))
        worst_lsq_angle = max(worst_lsq_angle, math.acos(min(1.0, cos_box)))

        # Our tau is attainable along tau: scale <= the largest alpha with B f = alpha tau in the
        # box (a linear program).
        lp = linprog(c=np.r_[np.zeros(8), -1.0],
                     A_eq=np.c_[B, -tau], b_eq=np.zeros(6),
                     bounds=[(lo, hi) for lo, hi in zip(lb, ub)] + [(0, None)])
        assert lp.status == 0
        assert res.scale <= lp.x[-1] + 1e-9
    assert worst_lsq_angle > math.radians(5.0)  # the contrast is real for this seed


def test_command_normalization_uses_max_reverse_for_negative_thrust():
    t = Thruster('x', (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), max_forward=40.0, max_reverse=30.0)
    alloc = ThrustAllocator([t], controlled_dofs=(0,))
    fwd = alloc.allocate([20.0, 0, 0, 0, 0, 0])
    rev = alloc.allocate([-15.0, 0, 0, 0, 0, 0])
    assert fwd.thrust[0] == pytest.approx(20.0) and fwd.command[0] == pytest.approx(0.5)
    assert rev.thrust[0] == pytest.approx(-15.0) and rev.command[0] == pytest.approx(-0.5)
    sat = alloc.allocate([-60.0, 0, 0, 0, 0, 0])  # 2x the reverse limit, within forward's 40
    assert sat.saturated and sat.scale == pytest.approx(0.5)
    assert sat.thrust[0] == pytest.approx(-30.0) and sat.command[0] == pytest.approx(-1.0)
    sat = alloc.allocate([60.0, 0, 0, 0, 0, 0])
    assert sat.scale == pytest.approx(40.0 / 60.0) and sat.command[0] == pytest.approx(1.0)


# --- reachability -------------------------------------------------------------------------


def test_layout_that_cannot_yaw_names_yaw():
    # Horizontal thrusters aimed radially: every line of action passes through the origin in
    # the horizontal plane, so no yaw moment; the verticals still roll and pitch.
    radial = [
        Thruster(t.name, t.position, t.position if t.name.startswith('h_') else t.direction,
                 F_FWD, F_REV)
        for t in vectored_8()
    ]
    with pytest.raises(AllocationError) as info:
        ThrustAllocator(radial)
    message = str(info.value)
    assert 'yaw' in message
    assert 'roll' not in message.split('cannot produce')[1].split('(')[0]
    assert 'h_fl' in message  # names the layout
    # Without yaw in the controlled set the same layout is fine.
    ThrustAllocator(radial, controlled_dofs=(0, 1, 2, 3, 4))


def test_all_thrusters_through_centre_cannot_rotate():
    directions = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1)]
    centre = [Thruster(f't{i}', (0, 0, 0), d, 10, 10) for i, d in enumerate(directions)]
    with pytest.raises(AllocationError) as info:
        ThrustAllocator(centre)
    missing = str(info.value).split('cannot produce')[1].split('(')[0]
    assert all(name in missing for name in ('roll', 'pitch', 'yaw'))
    assert not any(name in missing for name in ('surge', 'sway', 'heave'))
    assert isinstance(info.value, ConfigurationError)


def test_bad_controlled_dofs():
    for dofs in [(), (0, 0), (6,), (-1, 2)]:
        with pytest.raises(ConfigurationError, match='controlled_dofs'):
            ThrustAllocator(vectored_8(), controlled_dofs=dofs)


# --- per-call contract --------------------------------------------------------------------


def test_uncontrolled_dofs_are_ignored():
    # 4-DOF vehicle (surge, sway, heave, yaw): roll/pitch requests must not change the result.
    alloc = ThrustAllocator(vectored_8(), controlled_dofs=(0, 1, 2, 5))
    a = alloc.allocate([5.0, -3.0, 2.0, 0.0, 0.0, 1.0])
    b = alloc.allocate([5.0, -3.0, 2.0, 100.0, -100.0, 1.0])
    np.testing.assert_array_equal(a.thrust, b.thrust)
    np.testing.assert_allclose(a.tau_delivered[[0, 1, 2, 5]], [5.0, -3.0, 2.0, 1.0], atol=1e-12)
    # Minimum norm over the free DOFs: the symmetric verticals share heave, no roll/pitch.
    np.testing.assert_allclose(a.tau_delivered[[3, 4]], 0.0, atol=1e-12)


def test_non_finite_or_misshapen_tau_raises():
    alloc = ThrustAllocator(vectored_8())
    for bad in ([math.nan, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, math.inf]):
        with pytest.raises(ValueError, match='finite'):
            alloc.allocate(bad)
    with pytest.raises(ValueError, match='shape'):
        alloc.allocate([0.0] * 5)
    # Huge but finite values are not mistaken for non-finite.
    res = alloc.allocate([1e308, 1e308, 0, 0, 0, 0])
    assert res.saturated and np.all(np.isfinite(res.thrust))


def test_precomputed_matrices_are_read_only_and_results_fresh():
    alloc = ThrustAllocator(vectored_8())
    with pytest.raises(ValueError):
        alloc.B[0, 0] = 1.0
    with pytest.raises(ValueError):
        alloc.B_pinv[0, 0] = 1.0
    a = alloc.allocate([1.0, 0, 0, 0, 0, 0])
    b = alloc.allocate([2.0, 0, 0, 0, 0, 0])
    assert a.thrust is not b.thrust and a.thrust[0] != b.thrust[0]
    assert DOF_NAMES[5] == 'yaw'


# --- gaps found by the mutation run (docs/testing.md) -------------------------------------


def test_small_positive_thrust_is_normalized_by_the_forward_limit():
    """0 < f < 1 N is forward thrust too: 0.5 N of 40 N forward is command 0.0125, not the
    0.5/30 a reverse limit would give."""
    t = Thruster('x', (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), max_forward=40.0, max_reverse=30.0)
    alloc = ThrustAllocator([t], controlled_dofs=(0,))
    assert alloc.allocate([0.5, 0, 0, 0, 0, 0]).command[0] == pytest.approx(0.5 / 40.0,
                                                                            rel=1e-12)


def test_thrust_exactly_at_the_limit_is_not_saturated():
    """s = max |f_i| / limit_i = 1 exactly (40 N of 40 N): delivered in full, scale 1."""
    t = Thruster('x', (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), max_forward=40.0, max_reverse=30.0)
    res = ThrustAllocator([t], controlled_dofs=(0,)).allocate([40.0, 0, 0, 0, 0, 0])
    assert res.command[0] == 1.0 and res.scale == 1.0 and res.saturated is False


def test_layout_errors_say_what_is_wrong():
    with pytest.raises(AllocationError,
                       match='^thruster layout is empty: cannot produce any DOF$'):
        ThrustAllocator([])
    t = vectored_8()
    with pytest.raises(ConfigurationError, match=r"^thruster names must be unique, got \['h_fl',"):
        ThrustAllocator([t[0], t[0]])
    with pytest.raises(ConfigurationError,
                       match=r'^weights must be 8 positive finite numbers \(one per thruster\)'):
        ThrustAllocator(t, weights=[1.0] * 7)
    # Two thrusters along x make surge and yaw (differential); sway and heave are missing, both
    # named, and the way out is said.
    pair = [Thruster('a', (0, 0.1, 0), (1, 0, 0), 10, 10), Thruster('b', (0, -0.1, 0),
                                                                       (1, 0, 0), 10, 10)]
    with pytest.raises(AllocationError, match=(
            r"^thruster layout \[a, b\] cannot produce sway, heave \(rank 2 of 4 controlled "
            r"DOFs \['surge', 'sway', 'heave', 'yaw'\]\); add or re-aim thrusters, or remove "
            r'the DOF from controlled_dofs$')):
        ThrustAllocator(pair, controlled_dofs=(0, 1, 2, 5))


def test_weights_are_read_only():
    alloc = ThrustAllocator(vectored_8(), weights=[1.0] * 8)
    with pytest.raises(ValueError, match='read-only'):
        alloc.weights[0] = 2.0


def test_thrust_limits_below_one_newton_are_valid():
    """A limit must be > 0 N, not >= 1 N: a small thruster gives 0.5 N."""
    t = Thruster('small', (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), max_forward=0.8, max_reverse=0.5)
    assert (t.max_forward, t.max_reverse) == (0.8, 0.5)


def test_thruster_vector_errors_name_the_thruster_and_field():
    with pytest.raises(ConfigurationError, match=r"^thruster 't': position must be 3 numbers"):
        Thruster('t', (1.0, 2.0), (1.0, 0.0, 0.0), 10, 5)
    with pytest.raises(ConfigurationError, match=r"^thruster 't': direction must be 3 numbers"):
        Thruster('t', (0.0, 0.0, 0.0), (1.0, 0.0), 10, 5)
    with pytest.raises(ConfigurationError, match=r"^thruster 't': direction must be a non-zero"):
        Thruster('t', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 10, 5)
