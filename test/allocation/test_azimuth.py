"""Azimuth thrust allocation and PWM calibration (pure algorithm tier: numpy/scipy only).

The allocator is checked against a general constrained least-squares solution (scipy SLSQP
over thrust and angle with the real bounds), which knows nothing of the extended-thrust trick.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from enbarr_core.allocation.azimuth import (
    AzimuthAllocator,
    AzimuthResult,
    PwmCalibration,
    extended_allocation_matrix,
)
from enbarr_core.framework.errors import AllocationError, ConfigurationError
from enbarr_core.models.vessel3dof import AzimuthSpec, azimuth_tau

RADIUS = 0.1375                 # [m] Saucer azimuth radius of the profile (not in the manual)
A_LIM = math.radians(114.0)     # servo travel +/-114 deg (CS Saucer manual Table 1.1)
F_FWD, F_REV = 1.5, 1.0         # [N] assumed: the manual gives no thrust figures
LAMBDA = 1e-6                   # thrust regularization of the SLSQP reference


def saucer_specs(**overrides) -> list[AzimuthSpec]:
    """Three azimuths at 90, 210, 330 deg around the centre. Time constant and slew rate are
    assumed values (not in the manual); they do not matter to the allocator.
    """
    kw = dict(max_forward=F_FWD, max_reverse=F_REV, angle_min=-A_LIM, angle_max=A_LIM,
              time_constant=0.1, max_angle_rate=3.0)
    kw.update(overrides)
    return [AzimuthSpec(f'az{k}', (RADIUS * math.cos(math.radians(deg)),
                                   RADIUS * math.sin(math.radians(deg))), **kw)
            for k, deg in enumerate((90.0, 210.0, 330.0))]


POS = np.array([s.position for s in saucer_specs()])


def limits_for(T: np.ndarray) -> np.ndarray:
    return np.where(T >= 0.0, F_FWD, F_REV)


# -- SLSQP references over the box: min |B(a) T - tau|^2 + LAMBDA |T|^2 (any tau, attainable
# or not), and min |T|^2 subject to B(a) T = tau (an attainable tau) --------------------------


def _tau_of(T: np.ndarray, a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([T @ c, T @ s, T @ (POS[:, 0] * s - POS[:, 1] * c)])


def slsqp_reference(tau: np.ndarray, rng: np.random.Generator, starts: int = 8):
    """Best of several SLSQP runs from random starts; returns (T, a)."""
    n = len(POS)

    def objective(z):
        T, a = z[:n], z[n:]
        c, s = np.cos(a), np.sin(a)
        r = _tau_of(T, a) - tau
        # Jacobian of the residual: d/dT_i and d/da_i of [T c, T s, T (x s - y c)]
        J_T = np.array([c, s, POS[:, 0] * s - POS[:, 1] * c])
        J_a = T * np.array([-s, c, POS[:, 0] * c + POS[:, 1] * s])
        grad = 2.0 * np.concatenate((J_T.T @ r + LAMBDA * T, J_a.T @ r))
        return float(r @ r + LAMBDA * T @ T), grad

    bounds = [(-F_REV, F_FWD)] * n + [(-A_LIM, A_LIM)] * n
    best = None
    for _ in range(starts):
        z0 = np.concatenate((rng.uniform(-F_REV, F_FWD, n), rng.uniform(-A_LIM, A_LIM, n)))
        res = minimize(objective, z0, jac=True, method='SLSQP', bounds=bounds,
                       options=dict(ftol=1e-16, maxiter=500))
        if best is None or res.fun < best.fun:
            best = res
    # SLSQP can stop short of the optimum's last digits (seen with scipy 1.17 on some CPUs):
    # restart it from the best point until the objective stops improving.
    for _ in range(5):
        res = minimize(objective, best.x, jac=True, method='SLSQP', bounds=bounds,
                       options=dict(ftol=1e-16, maxiter=500))
        if not res.fun < best.fun:
            break
        best = res
    return best.x[:n], best.x[n:]


def slsqp_least_thrust(tau: np.ndarray, rng: np.random.Generator, starts: int = 8):
    """Min |T|^2 subject to B(a) T = tau within the box: best of SLSQP runs from random starts
    that deliver tau (to 1e-10 N); returns (T, a). For an attainable tau: the constraint
    written as one, so SLSQP converges in tens of iterations where the penalty form above
    crawls to its iteration limit."""
    n = len(POS)

    def thrust_squared(z):
        T = z[:n]
        return float(T @ T), np.concatenate((2.0 * T, np.zeros(n)))

    def residual(z):
        return _tau_of(z[:n], z[n:]) - tau

    def jacobian(z):  # d/dT_i and d/da_i of [T c, T s, T (x s - y c)]
        T, a = z[:n], z[n:]
        c, s = np.cos(a), np.sin(a)
        return np.hstack((np.array([c, s, POS[:, 0] * s - POS[:, 1] * c]),
                          T * np.array([-s, c, POS[:, 0] * c + POS[:, 1] * s])))

    bounds = [(-F_REV, F_FWD)] * n + [(-A_LIM, A_LIM)] * n
    constraint = {'type': 'eq', 'fun': residual, 'jac': jacobian}
    best = None
    for _ in range(starts):
        z0 = np.concatenate((rng.uniform(-F_REV, F_FWD, n), rng.uniform(-A_LIM, A_LIM, n)))
        res = minimize(thrust_squared, z0, jac=True, method='SLSQP', bounds=bounds,
                       constraints=[constraint], options=dict(ftol=1e-15, maxiter=500))
        delivers = np.max(np.abs(residual(res.x))) < 1e-10
        if res.success and delivers and (best is None or res.fun < best.fun):
            best = res
    assert best is not None, f'no SLSQP start delivered tau = {tau}'
    return best.x[:n], best.x[n:]


def random_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    """Unit directions in [X, Y, N / RADIUS] so that yaw gets a fair share."""
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] *= RADIUS
    return v


def least_norm_forces(tau: np.ndarray) -> np.ndarray:
    """(3, 2) force pairs (f_x, f_y) of least sum |f_i|^2 delivering tau, derived by hand.

    Force pair i at (x_i, y_i) contributes [f_x, f_y, x_i f_y - y_i f_x], so
    B_ext = [[1, 0, ...], [0, 1, ...], [-y_i, x_i, ...]] and the least-norm solution is
    f = B_ext^T (B_ext B_ext^T)^-1 tau. Three azimuths evenly spaced on radius r have
    sum x_i = sum y_i = 0 and sum (x_i^2 + y_i^2) = 3 r^2: B_ext B_ext^T = diag(3, 3, 3 r^2),
    so f_i = (X / 3 - y_i N / (3 r^2), Y / 3 + x_i N / (3 r^2)). No package code involved.
    """
    X, Y, N = tau
    k = N / (3.0 * RADIUS ** 2)
    return np.column_stack([X / 3.0 - POS[:, 1] * k, Y / 3.0 + POS[:, 0] * k])


def unsaturated_ratio(tau: np.ndarray) -> float:
    """Max |T_i| / limit_i of the least-norm solution (before any scaling)."""
    f = least_norm_forces(tau)
    m = np.hypot(f[:, 0], f[:, 1])
    # The representation chosen without a previous angle is positive thrust when possible.
    phi = np.arctan2(f[:, 1], f[:, 0])
    return float(np.max(m / np.where(np.abs(phi) <= A_LIM, F_FWD, F_REV)))


def test_pure_yaw_and_pure_surge_by_hand():
    """Hand numbers. Yaw N = 0.1 N m: each azimuth pushes N / (3 r) = 0.2424 N tangentially,
    towards its position angle + 90 deg: 180 deg for the one at 90 deg (outside +-114 deg, so
    reversed: angle 0, thrust -0.2424), -60 deg and +60 deg for the others. Surge X = 0.9 N:
    0.3 N each at 0 deg."""
    alloc = AzimuthAllocator(saucer_specs())
    t = 0.1 / (3.0 * RADIUS)
    res = alloc.allocate([0.0, 0.0, 0.1])
    np.testing.assert_allclose(res.thrust, [-t, t, t], rtol=1e-12)
    np.testing.assert_allclose(res.angle, np.radians([0.0, -60.0, 60.0]), atol=1e-12)
    assert res.feasible and res.scale == 1.0
    res = alloc.allocate([0.9, 0.0, 0.0])
    np.testing.assert_allclose(res.thrust, [0.3, 0.3, 0.3], rtol=1e-12)
    np.testing.assert_allclose(res.angle, 0.0, atol=1e-12)
    # Yaw beyond the reverse limit of the first azimuth (1.0 N): N = 3 r 1.25 needs 1.25 N
    # reversed there, so everything is scaled by 1 / 1.25.
    res = alloc.allocate([0.0, 0.0, 3.0 * RADIUS * 1.25])
    assert not res.feasible and res.scale == pytest.approx(0.8, rel=1e-12)
    np.testing.assert_allclose(res.thrust, [-1.0, 1.0, 1.0], rtol=1e-12)


def test_least_norm_forces_match_the_allocator():
    """Per azimuth, |T| and the force direction are those of the hand-derived least-norm
    solution (attainable tau)."""
    alloc = AzimuthAllocator(saucer_specs())
    rng = np.random.default_rng(5)
    for direction in random_directions(rng, 30):
        tau = direction * 0.7 / unsaturated_ratio(direction)
        res = alloc.allocate(tau)
        f = least_norm_forces(tau)
        np.testing.assert_allclose(res.thrust * np.cos(res.angle), f[:, 0], atol=1e-12)
        np.testing.assert_allclose(res.thrust * np.sin(res.angle), f[:, 1], atol=1e-12)


def tau_by_hand(specs, thrust, angle) -> list[float]:
    """[X, Y, N]: thruster i at (x, y) pushes T (cos a, sin a), a moment x f_y - y f_x."""
    X = Y = N = 0.0
    for spec, T, a in zip(specs, thrust, angle):
        x, y = spec.position
        f_x, f_y = T * math.cos(a), T * math.sin(a)
        X, Y, N = X + f_x, Y + f_y, N + x * f_y - y * f_x
    return [X, Y, N]


def assert_angles_within(res: AzimuthResult) -> None:
    assert np.all(res.angle >= -A_LIM) and np.all(res.angle <= A_LIM)


# -- attainable: delivers tau with the least thrust -------------------------------------------


def test_attainable_tau_matches_slsqp_with_least_thrust():
    alloc = AzimuthAllocator(saucer_specs())
    rng = np.random.default_rng(20240612)
    gaps = []
    for direction in random_directions(rng, 20):
        tau = direction * rng.uniform(0.1, 0.8) / unsaturated_ratio(direction)
        res = alloc.allocate(tau)
        assert res.feasible and res.scale == 1.0
        np.testing.assert_allclose(res.tau_delivered, tau, atol=1e-12)
        np.testing.assert_allclose(azimuth_tau(POS, res.thrust, res.angle), tau, atol=1e-12)
        # Independently of the package: each azimuth's force summed by hand.
        np.testing.assert_allclose(tau_by_hand(alloc.specs, res.thrust, res.angle), tau,
                                   atol=1e-12)
        assert_angles_within(res)
        assert np.all(np.abs(res.thrust) <= limits_for(res.thrust))
        T_ref, a_ref = slsqp_least_thrust(tau, rng)
        np.testing.assert_allclose(_tau_of(T_ref, a_ref), tau, atol=1e-10)
        ours, theirs = float(res.thrust @ res.thrust), float(T_ref @ T_ref)
        assert ours <= theirs + 1e-9  # no start found less thrust
        gaps.append(abs(ours - theirs) / theirs)
    # The comparison is tight: SLSQP's best is mostly the same optimum, not a poor local one.
    assert np.median(gaps) < 1e-9


def test_weighted_least_norm_matches_kkt():
    """Min sum w_i (f_xi^2 + f_yi^2) s.t. B_ext f = tau, from its KKT equations."""
    weights = [1.0, 4.0, 0.5]
    alloc = AzimuthAllocator(saucer_specs(), weights=weights)
    # B_ext written out here: columns [1, 0, -y_i] and [0, 1, x_i] per azimuth.
    B = np.zeros((3, 6))
    B[0, 0::2], B[1, 1::2] = 1.0, 1.0
    B[2, 0::2], B[2, 1::2] = -POS[:, 1], POS[:, 0]
    np.testing.assert_array_equal(extended_allocation_matrix(POS), B)
    W = np.diag(np.repeat(weights, 2))
    kkt = np.block([[W, B.T], [B, np.zeros((3, 3))]])
    rng = np.random.default_rng(9)
    for tau in rng.normal(scale=[0.3, 0.3, 0.02], size=(20, 3)):
        f = np.linalg.solve(kkt, np.r_[np.zeros(6), tau])[:6].reshape(3, 2)
        res = alloc.allocate(tau)
        np.testing.assert_allclose(np.abs(res.thrust), np.hypot(f[:, 0], f[:, 1]), atol=1e-12)
        np.testing.assert_allclose(res.tau_delivered, tau, atol=1e-12)
    with pytest.raises(ConfigurationError, match='weights'):
        AzimuthAllocator(saucer_specs(), weights=[1.0, 1.0])
    with pytest.raises(ConfigurationError, match='weights'):
        AzimuthAllocator(saucer_specs(), weights=[1.0, 0.0, 1.0])


def test_reversed_thrust_when_direction_is_outside_travel():
    """A force pointing backwards (180 deg) is outside +/-114 deg: angle 0, thrust < 0."""
    alloc = AzimuthAllocator(saucer_specs())
    res = alloc.allocate([-0.9, 0.0, 0.0])
    np.testing.assert_allclose(res.thrust, -0.3, rtol=1e-12)
    np.testing.assert_allclose(res.angle, 0.0, atol=1e-12)
    fwd = alloc.allocate([0.9, 0.0, 0.0])
    np.testing.assert_allclose(fwd.thrust, 0.3, rtol=1e-12)


# -- unattainable: scaled along tau -----------------------------------------------------------


def test_unattainable_tau_is_scaled_along_its_direction():
    alloc = AzimuthAllocator(saucer_specs())
    rng = np.random.default_rng(77)
    for direction in random_directions(rng, 25):
        excess = rng.uniform(1.5, 10.0)
        tau = direction * excess / unsaturated_ratio(direction)
        res = alloc.allocate(tau)
        assert not res.feasible and 0.0 < res.scale < 1.0
        assert res.scale == pytest.approx(1.0 / excess, rel=1e-9)
        np.testing.assert_allclose(res.tau_delivered, res.scale * tau, rtol=1e-9, atol=1e-12)
        cos = res.tau_delivered @ tau / (np.linalg.norm(res.tau_delivered) * np.linalg.norm(tau))
        assert cos == pytest.approx(1.0, abs=1e-12)
        ratios = np.abs(res.thrust) / limits_for(res.thrust)
        assert np.all(ratios <= 1.0 + 1e-12)
        assert np.max(ratios) == pytest.approx(1.0, abs=1e-12)  # one azimuth at its limit
        assert_angles_within(res)
        # SLSQP (box-bounded least squares) gets at least as close to tau, in general not along
        # it; ours gives up magnitude to keep the direction.
        T_ref, a_ref = slsqp_reference(tau, rng, starts=4)
        assert np.all(T_ref <= F_FWD + 1e-9) and np.all(T_ref >= -F_REV - 1e-9)
        assert (np.linalg.norm(_tau_of(T_ref, a_ref) - tau)
                <= np.linalg.norm(res.tau_delivered - tau) + 1e-6)


# -- angle continuity -------------------------------------------------------------------------


def _other_representation(a: np.ndarray) -> np.ndarray:
    return np.where(a > 0.0, a - math.pi, a + math.pi)


def test_rotating_tau_keeps_angles_continuous_when_a_choice_exists():
    alloc = AzimuthAllocator(saucer_specs())
    prev = None
    jumps = 0
    for theta in np.linspace(0.0, 4.0 * math.pi, 2001):  # 0.36 deg per step
        tau = np.array([0.8 * math.cos(theta), 0.8 * math.sin(theta), 0.02])
        res = alloc.allocate(tau, previous_angle=prev)
        np.testing.assert_allclose(res.tau_delivered, tau, atol=1e-12)
        assert res.feasible
        assert_angles_within(res)
        if prev is not None:
            step = np.abs(res.angle - prev)
            for i in np.flatnonzero(step > 0.1):
                # A flip only when the continuation (the other representation, near prev) has
                # left the servo travel: there was no choice.
                jumps += 1
                assert abs(step[i] - math.pi) < 0.05
                alt = _other_representation(res.angle[i:i + 1])[0]
                assert abs(alt) > A_LIM - 1e-9
        prev = res.angle
    # Two forced flips per azimuth and revolution, two revolutions.
    assert jumps == 3 * 2 * 2


def test_hysteresis_near_the_travel_limit():
    """A force direction wobbling across +114 deg: no flip-flopping with previous_angle."""
    alloc = AzimuthAllocator(saucer_specs())
    thetas = A_LIM + math.radians(5.0) * np.sin(0.2 * np.arange(300))
    flips = {True: 0, False: 0}
    for hysteresis in (True, False):
        prev = None
        last = None
        for theta in thetas:
            tau = np.array([0.6 * math.cos(theta), 0.6 * math.sin(theta), 0.0])
            res = alloc.allocate(tau, previous_angle=prev if hysteresis else None)
            np.testing.assert_allclose(res.tau_delivered, tau, atol=1e-12)
            if last is not None:
                flips[hysteresis] += int(np.count_nonzero(np.abs(res.angle - last) > 1.0))
            last = res.angle
            prev = res.angle
    assert flips[True] <= 3       # at most once per azimuth
    assert flips[False] > 30      # without it: every crossing


def test_zero_tau_keeps_previous_angles():
    alloc = AzimuthAllocator(saucer_specs())
    res = alloc.allocate([0.0, 0.0, 0.0], previous_angle=[0.3, -1.0, 2.5])
    np.testing.assert_array_equal(res.thrust, 0.0)
    np.testing.assert_allclose(res.angle, [0.3, -1.0, A_LIM])  # clipped to the travel
    assert res.feasible and res.scale == 1.0
    np.testing.assert_array_equal(res.tau_delivered, 0.0)
    res = alloc.allocate([1e-15, 0.0, 0.0])
    np.testing.assert_array_equal(res.thrust, 0.0)
    np.testing.assert_array_equal(res.angle, 0.0)


# -- layout checks ----------------------------------------------------------------------------


def test_layout_at_the_centre_cannot_yaw():
    centre = [AzimuthSpec(f'c{k}', (0.0, 0.0), F_FWD, F_REV) for k in range(3)]
    with pytest.raises(AllocationError) as info:
        AzimuthAllocator(centre)
    missing = str(info.value).split('cannot produce')[1].split('(')[0]
    assert 'yaw' in missing and 'surge' not in missing and 'sway' not in missing
    assert 'c0' in str(info.value)
    assert isinstance(info.value, ConfigurationError)


def test_too_little_travel_or_bad_layout_is_rejected():
    with pytest.raises(ConfigurationError, match='angle_min'):
        AzimuthAllocator(saucer_specs(angle_min=-1.0, angle_max=1.0))
    with pytest.raises(AllocationError):
        AzimuthAllocator([])
    with pytest.raises(ConfigurationError, match='unique'):
        AzimuthAllocator([AzimuthSpec('a', (0, 0.1), 1, 1), AzimuthSpec('a', (0, -0.1), 1, 1)])
    alloc = AzimuthAllocator(saucer_specs())
    with pytest.raises(ValueError, match='tau'):
        alloc.allocate([1.0, math.nan, 0.0])
    with pytest.raises(ValueError, match='previous_angle'):
        alloc.allocate([1.0, 0.0, 0.0], previous_angle=[0.0, 0.0])


# -- PWM calibration --------------------------------------------------------------------------

# Illustrative calibration (the manual only gives the 4.3-9.4 % range): a 0 N dead band over
# 6.75-6.95 % and a servo mapping -114..114 deg over the full range.
THRUST_DUTY = [4.3, 5.0, 5.8, 6.5, 6.75, 6.85, 6.95, 7.2, 7.9, 8.6, 9.4]
THRUST_N = [-1.0, -0.75, -0.4, -0.1, 0.0, 0.0, 0.0, 0.1, 0.6, 1.2, 1.5]
ANGLE_DUTY = [4.3, 5.6, 6.85, 8.1, 9.4]
ANGLE_RAD = [math.radians(d) for d in (-114.0, -55.0, 0.0, 57.0, 114.0)]


DUTY_MIN, DUTY_MAX = 4.3, 9.4  # [%] the CS Saucer's Arduino PWM range (manual Table 1.1)


def calibration(**overrides) -> PwmCalibration:
    kw = dict(thrust_duty_percent=THRUST_DUTY, thrust_newton=THRUST_N,
              angle_duty_percent=ANGLE_DUTY, angle_rad=ANGLE_RAD,
              duty_min_percent=DUTY_MIN, duty_max_percent=DUTY_MAX)
    kw.update(overrides)
    return PwmCalibration(**kw)


def test_pwm_round_trips_and_neutral():
    cal = calibration()
    assert cal.duty_min_percent == 4.3 and cal.duty_max_percent == 9.4
    assert cal.neutral_thrust_duty == pytest.approx(6.85, abs=1e-15)
    assert cal.thrust_to_duty(0.0) == cal.neutral_thrust_duty  # exactly
    assert cal.thrust_to_duty(-0.0) == cal.neutral_thrust_duty
    assert cal.neutral_angle_duty == 6.85
    for T in np.linspace(-1.0, 1.5, 251):
        d = cal.thrust_to_duty(T)
        assert 4.3 <= d <= 9.4
        assert cal.duty_to_thrust(d) == pytest.approx(T, abs=1e-12)
        if T > 0.0:
            assert d > 6.95   # positive thrust never lands in the dead band
        elif T < 0.0:
            assert d < 6.75
    for a in np.linspace(-A_LIM, A_LIM, 101):
        d = cal.angle_to_duty(a)
        assert 4.3 <= d <= 9.4
        assert cal.duty_to_angle(d) == pytest.approx(a, abs=1e-12)
    # Outside the dead band, duty -> thrust -> duty is the identity too.
    for d in np.r_[np.linspace(4.3, 6.7, 50), np.linspace(7.0, 9.4, 50)]:
        assert cal.thrust_to_duty(cal.duty_to_thrust(d)) == pytest.approx(d, abs=1e-12)
    # Beyond the tables: clipped to their ends.
    assert cal.thrust_to_duty(5.0) == 9.4 and cal.thrust_to_duty(-5.0) == 4.3
    assert cal.duty_to_thrust(20.0) == 1.5 and cal.duty_to_thrust(0.0) == -1.0
    assert cal.angle_to_duty(4.0) == 9.4 and cal.duty_to_angle(0.0) == ANGLE_RAD[0]
    cal.check_covers(-A_LIM, A_LIM)
    with pytest.raises(ValueError, match='angle_rad'):
        cal.check_covers(-math.radians(120.0), A_LIM)
    # A saturating table (flat top): the smallest duty reaching the thrust is used.
    flat = calibration(thrust_newton=THRUST_N[:-1] + [1.2])
    assert flat.thrust_to_duty(1.2) == 8.6 and flat.thrust_to_duty(3.0) == 8.6
    # A single zero entry is its own neutral.
    single = calibration(thrust_duty_percent=[4.3, 6.9, 9.4], thrust_newton=[-1.0, 0.0, 1.5])
    assert single.thrust_to_duty(0.0) == 6.9


def test_pwm_bad_tables_name_the_table():
    with pytest.raises(ValueError, match=r'^thrust_duty_percent\[0\]: 3.0 %'):
        calibration(thrust_duty_percent=[3.0] + THRUST_DUTY[1:])
    with pytest.raises(ValueError, match=r'^angle_duty_percent\[4\]'):
        calibration(angle_duty_percent=ANGLE_DUTY[:-1] + [9.5])
    with pytest.raises(ValueError, match=r'^thrust_duty_percent\[3\]: must be strictly'):
        calibration(thrust_duty_percent=THRUST_DUTY[:3] + [5.7] + THRUST_DUTY[4:])
    with pytest.raises(ValueError, match=r'^thrust_newton\[2\]: must be non-decreasing'):
        calibration(thrust_newton=[-1.0, -0.75, -0.8] + THRUST_N[3:])
    with pytest.raises(ValueError, match=r'^thrust_newton: must contain 0'):
        calibration(thrust_newton=[t if t else 0.01 for t in THRUST_N])
    with pytest.raises(ValueError, match=r'^angle_rad\[2\]: must be strictly'):
        calibration(angle_rad=ANGLE_RAD[:2] + [ANGLE_RAD[1]] + ANGLE_RAD[3:])
    with pytest.raises(ValueError, match=r'^thrust_newton: 10 entries'):
        calibration(thrust_newton=THRUST_N[:-1])
    with pytest.raises(ValueError, match=r'^angle_duty_percent: needs at least 2'):
        calibration(angle_duty_percent=[6.85], angle_rad=[0.0])
    with pytest.raises(ValueError, match=r'^angle_rad: must span angle 0'):
        calibration(angle_rad=[a + 3.0 for a in ANGLE_RAD])


def test_pwm_duty_limits_come_from_the_calibration():
    # Another board with a wider range: the same tables fit, and more.
    wide = calibration(duty_min_percent=2.5, duty_max_percent=12.5,
                       thrust_duty_percent=[2.5] + THRUST_DUTY[1:])
    assert wide.thrust_to_duty(-5.0) == 2.5
    assert wide.accepts(2.5) and wide.accepts(12.5) and not wide.accepts(12.6)
    cal = calibration()
    assert cal.accepts(4.3) and cal.accepts(9.4) and cal.accepts(6.85)
    for bad in (4.2, 9.5, math.nan, math.inf, -math.inf):
        assert not cal.accepts(bad), bad
    # Tables beyond the limits, and limits that make no sense, are refused by name.
    with pytest.raises(ValueError, match=r'^thrust_duty_percent\[0\]: 4.3 % is outside'):
        calibration(duty_min_percent=5.0)
    with pytest.raises(ValueError, match=r'^duty_max_percent: must be above'):
        calibration(duty_min_percent=9.4, duty_max_percent=4.3)
    with pytest.raises(ValueError, match=r'^duty_min_percent: expected a duty cycle'):
        calibration(duty_min_percent=-1.0)
    with pytest.raises(ValueError, match=r'^duty_max_percent: expected a number'):
        calibration(duty_max_percent='high')


def test_pwm_from_mapping():
    d = dict(thrust_duty_percent=THRUST_DUTY, thrust_newton=THRUST_N,
             angle_duty_percent=ANGLE_DUTY, angle_rad=ANGLE_RAD,
             duty_min_percent=DUTY_MIN, duty_max_percent=DUTY_MAX)
    cal = PwmCalibration.from_mapping(d)
    assert cal == calibration()
    assert isinstance(cal.thrust_newton, tuple)
    with pytest.raises(ValueError, match='^angle_rad: missing'):
        PwmCalibration.from_mapping({k: v for k, v in d.items() if k != 'angle_rad'})
    with pytest.raises(ValueError, match='^duty_max_percent: missing'):
        PwmCalibration.from_mapping({k: v for k, v in d.items() if k != 'duty_max_percent'})
    with pytest.raises(ValueError, match='^neutral: unknown'):
        PwmCalibration.from_mapping({**d, 'neutral': 6.85})


# -- survivors of mutation testing (docs/testing.md): the travel limits and the sign choice ---


HALF = math.pi / 2


def half_turn_specs() -> list[AzimuthSpec]:
    """The Saucer layout with exactly a half turn of travel, [-pi/2, pi/2] (the least allowed)."""
    return saucer_specs(angle_min=-HALF, angle_max=HALF)


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_force_exactly_at_a_travel_limit_is_positive_thrust_there(sign):
    # Pure sway Y = 0.3 N: each azimuth pushes (0, +-0.1) N, phi = +-pi/2 = a travel limit (to
    # the last bit or two). Both representations are inside the travel then; without a previous
    # angle positive thrust is preferred: T = +0.1 N at +-pi/2, not -0.1 N at -+pi/2.
    res = AzimuthAllocator(half_turn_specs()).allocate([0.0, sign * 0.3, 0.0])
    np.testing.assert_allclose(res.thrust, 0.1, rtol=1e-12)
    np.testing.assert_array_equal(res.angle, sign * HALF)  # clipped onto the limit exactly


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_reversed_thrust_exactly_at_a_travel_limit_is_kept_near_the_previous_angle(sign):
    # The same +-Y force with the servos resting near -+pi/2: reversed thrust at -+pi/2
    # (0.07 rad away) is used, not a half turn to +-pi/2.
    res = AzimuthAllocator(half_turn_specs()).allocate([0.0, sign * 0.3, 0.0],
                                                       previous_angle=[-sign * 1.5] * 3)
    np.testing.assert_allclose(res.thrust, -0.1, rtol=1e-12)
    np.testing.assert_array_equal(res.angle, -sign * HALF)


def test_reversed_thrust_is_scaled_by_the_reverse_limit():
    # Pure yaw with max_reverse = 0.5 N: the azimuth at 90 deg pushes 0.8 N reversed (ratio
    # 0.8 / 0.5 = 1.6), the others 0.8 N forward (0.8 / 1.5): all scaled by 1 / 1.6 = 0.625.
    # (With max_reverse = 1 N, m / limit and m * limit agree.)
    alloc = AzimuthAllocator(saucer_specs(max_reverse=0.5))
    res = alloc.allocate([0.0, 0.0, 0.8 * 3.0 * RADIUS])
    assert not res.feasible and res.scale == pytest.approx(0.625, rel=1e-12)
    np.testing.assert_allclose(res.thrust, [-0.5, 0.5, 0.5], rtol=1e-12)


@pytest.mark.parametrize('phi', [0.5, 0.99, -0.5, 2.0])
def test_the_reversed_angle_is_the_force_direction_minus_a_half_turn(phi):
    # Full travel [-pi, pi]: force pairs (0.2 cos phi, 0.2 sin phi) for a pure X, Y push. With
    # the servos 0.1 rad from the reversed direction phi -+ pi (whichever lies in (-pi, pi]),
    # that is kept: T = -0.2 N at phi -+ pi.
    specs = saucer_specs(angle_min=-math.pi, angle_max=math.pi)
    phi_r = phi - math.pi if phi > 0.0 else phi + math.pi
    res = AzimuthAllocator(specs).allocate([0.6 * math.cos(phi), 0.6 * math.sin(phi), 0.0],
                                           previous_angle=[phi_r + 0.1] * 3)
    np.testing.assert_allclose(res.thrust, -0.2, rtol=1e-12)
    np.testing.assert_allclose(res.angle, phi_r, atol=1e-12)


def test_allocate_errors_start_with_the_argument_name():
    alloc = AzimuthAllocator(saucer_specs())
    with pytest.raises(ValueError, match=r'^tau'):
        alloc.allocate([0.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r'^tau'):
        alloc.allocate([0.0, math.nan, 0.0])
    with pytest.raises(ValueError, match=r'^previous_angle'):
        alloc.allocate([0.0, 0.0, 0.0], previous_angle=[0.0, 0.0])


def test_pwm_duty_limits_of_a_whole_board_and_no_empty_range():
    # 0 % and 100 % are valid limits (a board that takes any duty); 100.5 % and -0.5 % are
    # not, and equal limits leave no range (every command would be refused).
    n = len(THRUST_DUTY)
    full = calibration(duty_min_percent=0.0, duty_max_percent=100.0)
    assert full.accepts(0.0) and full.accepts(100.0) and not full.accepts(100.5)
    for field, bad in (('duty_max_percent', 100.5), ('duty_min_percent', -0.5)):
        with pytest.raises(ValueError, match=rf'^{field}: expected a duty cycle in \[0, 100\]'):
            calibration(**{field: bad})
    one = dict(thrust_duty_percent=[5.0] * n, angle_duty_percent=[5.0] * len(ANGLE_DUTY))
    with pytest.raises(ValueError, match=r'^duty_max_percent: must be above'):
        calibration(duty_min_percent=5.0, duty_max_percent=5.0, **one)


def test_pwm_saturating_tables_clip_to_the_duty_nearest_neutral():
    # Flat ends (the propeller gives no more thrust): beyond or at the flat value the duty
    # closest to neutral that reaches it is used, at both ends: reverse -1.0 N is reached at
    # 5.0 % already (THRUST_DUTY[1]), forward 1.2 N at 8.6 % (THRUST_DUTY[-2]).
    cal = calibration(thrust_newton=[-1.0, -1.0] + THRUST_N[2:-1] + [1.2])
    for T in (-1.0, -3.0):
        assert cal.thrust_to_duty(T) == THRUST_DUTY[1]
    for T in (1.2, 3.0):
        assert cal.thrust_to_duty(T) == THRUST_DUTY[-2]


def test_allocator_layout_errors_name_what_and_where():
    with pytest.raises(AllocationError, match=r'^azimuth layout is empty: cannot produce surge, '
                                              r'sway, yaw$'):
        AzimuthAllocator([])
    # A half turn of travel is the least allowed (accepted above); 1 mrad less is refused,
    # naming the azimuth, the parameter and the travel it has.
    short = saucer_specs(angle_min=-HALF + 1e-3, angle_max=HALF)
    with pytest.raises(ConfigurationError, match=r"^azimuth 'az0': angle_max - angle_min must "
                                                 r'be >= pi rad \(180 deg\) for the allocator, '
                                                 r'got 3\.1406 rad$') as info:
        AzimuthAllocator(short)
    assert info.value.parameter == 'angle_min'
    with pytest.raises(ConfigurationError, match=r'per azimuth') as info:
        AzimuthAllocator(saucer_specs(), weights=[1.0, 1.0])
    assert info.value.parameter == 'weights'


def test_allocator_exposes_its_matrices_read_only():
    # B_ext by hand (columns [1, 0, -y_i] and [0, 1, x_i] per azimuth), B_pinv its right
    # inverse, unit weights; none of them can be changed behind the allocator's back.
    alloc = AzimuthAllocator(saucer_specs())
    np.testing.assert_array_equal(alloc.positions, POS)
    B = np.zeros((3, 6))
    for i, (x, y) in enumerate(POS):
        B[:, 2 * i] = (1.0, 0.0, -y)
        B[:, 2 * i + 1] = (0.0, 1.0, x)
    np.testing.assert_allclose(alloc.B_ext, B, atol=1e-15)
    np.testing.assert_allclose(alloc.B_ext @ alloc.B_pinv, np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(alloc.weights, np.ones(3))
    for a in (alloc.positions, alloc.B_ext, alloc.B_pinv, alloc.weights):
        with pytest.raises(ValueError, match='read-only'):
            a[0] = 1.0
