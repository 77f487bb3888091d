"""3-DOF surface-vessel model and azimuth actuators (pure algorithm tier: numpy/scipy only)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from support.saucer_plant import vessel_params

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.models.vessel3dof import (
    AzimuthActuators,
    AzimuthSpec,
    Vessel3Dof,
    Vessel3DofParams,
    azimuth_tau,
    current_at,
    disturbance_at_rest,
)

# The manual's numbers typed again here (CS Saucer manual eqs. 1.2-1.5), not taken from the
# profile, so that a typo in saucer_core.yaml fails the tests.
M_MAN = np.diag([9.51, 9.51, 0.116])
D_MAN = np.diag([1.96, 1.96, 0.168])
DN_MAN = 7.095

SERVO_LIMIT = math.radians(114.0)  # +/-114 deg (manual Table 1.1)
CS_SAUCER = vessel_params()  # from params/saucer_core.yaml
RADIUS = 0.1375  # [m] Saucer azimuth radius of the Enbarr profile (not in the manual)


def saucer_specs(**overrides) -> list[AzimuthSpec]:
    """Three azimuths at 90, 210, 330 deg; +/-114 deg travel (manual Table 1.1). Thrust limits,
    time constant and slew rate are assumed (the manual does not give them).
    """
    kw = dict(max_forward=1.5, max_reverse=1.0, angle_min=-math.radians(114.0),
              angle_max=math.radians(114.0), time_constant=0.1, max_angle_rate=3.0)
    kw.update(overrides)
    return [AzimuthSpec(f'az{k}', (RADIUS * math.cos(math.radians(deg)),
                                   RADIUS * math.sin(math.radians(deg))), **kw)
            for k, deg in enumerate((90.0, 210.0, 330.0))]


# -- independent reference: the manual's matrices, np.linalg.solve, scipy ----------------------


def _R(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # manual eq. 1.6


def _dRT_dpsi(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[-s, c, 0.0], [-c, -s, 0.0], [0.0, 0.0, 0.0]])


def reference_rhs(tau_of_t, current=(0.0, 0.0), bias=(0.0, 0.0, 0.0)):
    """dy/dt, y = [eta, nu], in matrix form: nu_r = nu - R^T v_c,
    M nu_r_dot = tau + R^T b - (C(nu_r) + D + D_n(nu_r)) nu_r, nu_dot = nu_r_dot + d(R^T)/dt v_c.
    """
    v_c = np.array([current[0], current[1], 0.0])
    b = np.asarray(bias, dtype=float)

    def rhs(t, y):
        psi, nu = y[2], y[3:]
        RT = _R(psi).T
        nu_r = nu - RT @ v_c
        r = nu_r[2]
        C = np.array([[0.0, -9.51 * r, 0.0], [9.51 * r, 0.0, 0.0], [0.0, 0.0, 0.0]])
        Dn = DN_MAN * np.diag(np.abs(nu_r))
        nu_r_dot = np.linalg.solve(M_MAN, tau_of_t(t) + RT @ b - (C + D_MAN + Dn) @ nu_r)
        nu_dot = nu_r_dot + (_dRT_dpsi(psi) * nu[2]) @ v_c
        return np.concatenate([_R(psi) @ nu, nu_dot])

    return rhs


HOLD = 0.1  # [s] tau changes every 100 ms (a multiple of both test steps), held in between


def tau_profile(t: float) -> np.ndarray:
    """Piecewise-constant, sign-changing tau [N, N, N m] sampled at the HOLD grid."""
    k = math.floor(t / HOLD + 1e-9) * HOLD
    return np.array([0.9 * math.sin(0.4 * k) + 0.3, 0.6 * math.cos(0.27 * k),
                     0.04 * math.sin(0.9 * k) + 0.01 * math.cos(2.1 * k)])


def reference_run(y0, t_end, current, bias):
    """Integrate the reference segment by segment (tau constant on each), rtol 1e-10.

    RK45 rather than DOP853: at rtol 1e-10 DOP853 mis-steps over the kinks of |nu_r| by ~1e-8
    (measured against DOP853 at rtol 1e-12), RK45 agrees with it to ~1e-10.
    """
    rhs = reference_rhs(tau_profile, current, bias)
    y = np.asarray(y0, dtype=float)
    n = int(round(t_end / HOLD))
    for k in range(n):
        t0 = k * HOLD
        sol = solve_ivp(lambda t, yy: rhs(t0 + 0.5 * HOLD, yy), (t0, t0 + HOLD), y,
                        method='RK45', rtol=1e-10, atol=1e-12)
        assert sol.success
        y = sol.y[:, -1]
    return y


@pytest.mark.sim
@pytest.mark.parametrize('with_env', [False, True], ids=['calm', 'current+bias'])
def test_rk4_matches_reference_integration(with_env):
    current = (0.12, -0.07) if with_env else (0.0, 0.0)
    bias = (0.15, 0.25, -0.01) if with_env else (0.0, 0.0, 0.0)
    y0 = np.array([1.0, -2.0, 2.8, 0.1, -0.05, 0.2])  # psi near pi: crosses the wrap
    t_end = 20.0
    ref = reference_run(y0, t_end, current, bias)
    model = Vessel3Dof(CS_SAUCER)
    # Measured max errors: ~1.7e-6 at dt 0.02 (50 Hz, the lab rate) and ~2.5e-10 at 0.0025
    # (400 Hz); tolerances leave ~6x margin. (At dt 0.04 the error grows to ~3e-3: the yaw mode,
    # (0.168 + 2 * 7.095 |r|) / 0.116 ~ 26 1/s at r = 0.2 rad/s, is then poorly resolved.)
    errors = {}
    for dt, tol in ((0.02, 1e-5), (0.0025, 2e-9)):
        eta, nu = y0[:3], y0[3:]
        for k in range(int(round(t_end / dt))):
            eta, nu = model.step(eta, nu, tau_profile((k + 0.5) * dt), dt, current, bias)
        assert -math.pi <= eta[2] < math.pi
        err = np.abs(np.r_[eta[:2] - ref[:2], math.remainder(eta[2] - ref[2], 2 * math.pi),
                           nu - ref[3:]])
        assert err.max() < tol, f'dt={dt}: errors {err}'
        errors[dt] = err.max()
    # Fourth order: 8x smaller steps, ~8^4 = 4096x smaller error.
    assert errors[0.02] / errors[0.0025] > 1000.0


def test_derivatives_match_reference_rhs():
    rng = np.random.default_rng(3)
    model = Vessel3Dof(CS_SAUCER)
    for _ in range(50):
        eta = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
        nu = rng.normal(scale=[0.3, 0.3, 0.5])
        tau = rng.normal(scale=[1.0, 1.0, 0.05])
        current = rng.normal(scale=0.1, size=2)
        bias = rng.normal(scale=[0.2, 0.2, 0.01])
        eta_dot, nu_dot = model.derivatives(eta, nu, tau, current, bias)
        ref = reference_rhs(lambda t: tau, current, bias)(0.0, np.r_[eta, nu])
        np.testing.assert_allclose(np.r_[eta_dot, nu_dot], ref, rtol=1e-12, atol=1e-12)


def test_zero_current_is_the_manual_model_exactly():
    """eta_dot = R nu, M nu_dot + (C + D + D(nu)) nu = tau (CS Saucer manual 1.4)."""
    rng = np.random.default_rng(11)
    model = Vessel3Dof(CS_SAUCER)
    for _ in range(50):
        eta = rng.uniform([-5, -5, -math.pi], [5, 5, math.pi])
        nu = rng.normal(scale=[0.3, 0.3, 0.5])
        tau = rng.normal(scale=[1.0, 1.0, 0.05])
        u, v, r = nu
        C = np.array([[0, -9.51 * r, 0], [9.51 * r, 0, 0], [0, 0, 0]])
        Dnu = np.diag([7.095 * abs(u), 7.095 * abs(v), 7.095 * abs(r)])
        nu_dot_man = np.linalg.inv(M_MAN) @ (tau - (C + D_MAN + Dnu) @ nu)
        eta_dot, nu_dot = model.derivatives(eta, nu, tau)
        np.testing.assert_allclose(eta_dot, _R(eta[2]) @ nu, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(nu_dot, nu_dot_man, rtol=1e-12, atol=1e-14)
        # Explicit defaults are the same as none.
        _, n2 = model.derivatives(eta, nu, tau, (0.0, 0.0), (0.0, 0.0, 0.0))
        np.testing.assert_array_equal(n2, nu_dot)


def test_coriolis_is_eq_1_3_and_skew():
    model = Vessel3Dof(CS_SAUCER)
    nu = np.array([0.3, -0.2, 0.7])
    np.testing.assert_array_equal(
        model.coriolis(nu), [[0.0, -9.51 * 0.7, 0.0], [9.51 * 0.7, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(model.M, M_MAN)
    np.testing.assert_allclose(model.damping(nu), D_MAN + 7.095 * np.diag(np.abs(nu)))
    rng = np.random.default_rng(5)
    for nu in rng.normal(size=(100, 3)):
        C = model.coriolis(nu)
        np.testing.assert_array_equal(C, -C.T)
        assert abs(nu @ C @ nu) < 1e-14
    # General m11: C uses M[0], not the number 9.51.
    other = Vessel3Dof(Vessel3DofParams(M=(20.0, 25.0, 1.0), D=(1, 1, 1), Dn=(0, 0, 0)))
    assert other.coriolis([0, 0, 2.0])[1, 0] == 40.0


@pytest.mark.parametrize('X', [1.0, -0.6, 3.0])
def test_steady_surge_speed_closed_form(X):
    model = Vessel3Dof(CS_SAUCER)
    u_ss = model.steady_surge_speed(X)
    # The root of 1.96 u + 7.095 u |u| = X, by the quadratic formula on the sign of X.
    s = math.copysign(1.0, X)
    u_ref = s * (-1.96 + math.sqrt(1.96 ** 2 + 4 * 7.095 * abs(X))) / (2 * 7.095)
    assert u_ss == pytest.approx(u_ref, rel=1e-14)
    assert 1.96 * u_ss + 7.095 * u_ss * abs(u_ss) == pytest.approx(X, rel=1e-14)
    eta, nu = np.array([0.0, 0.0, 0.4]), np.array([0.0, 0.05, -0.1])
    for _ in range(int(120.0 / 0.02)):  # 120 s at 50 Hz; the slowest time constant is < 5 s
        eta, nu = model.step(eta, nu, (X, 0.0, 0.0), 0.02)
    assert nu[0] == pytest.approx(u_ss, rel=1e-9)
    assert abs(nu[1]) < 1e-9 and abs(nu[2]) < 1e-9
    assert model.steady_surge_speed(0.0) == 0.0
    pure_linear = Vessel3Dof(Vessel3DofParams(M=(1, 1, 1), D=(2, 2, 2), Dn=(0, 0, 0)))
    assert pure_linear.steady_surge_speed(X) == pytest.approx(X / 2.0, rel=1e-15)


def test_current_carries_the_vessel_along():
    """Tau = 0: the relative velocity decays, the world velocity tends to the current."""
    model = Vessel3Dof(CS_SAUCER)
    current = (0.1, -0.05)
    eta, nu = np.array([0.0, 0.0, 0.3]), np.zeros(3)
    for _ in range(int(120.0 / 0.02)):
        eta, nu = model.step(eta, nu, (0.0, 0.0, 0.0), 0.02, current=current)
    np.testing.assert_allclose(_R(eta[2]) @ nu, [*current, 0.0], atol=1e-6)
    nu_c = _R(eta[2]).T @ np.array([*current, 0.0])
    np.testing.assert_allclose(nu - nu_c, 0.0, atol=1e-6)
    assert eta[2] == pytest.approx(0.3, abs=1e-12)  # an irrotational current does not turn it


def test_world_bias_gives_steady_speed():
    """A constant world force F: heading stays, body speeds are the per-axis closed forms."""
    model = Vessel3Dof(CS_SAUCER)
    psi0 = 0.7
    F = np.array([0.4, -0.3, 0.0])
    eta, nu = np.array([0.0, 0.0, psi0]), np.zeros(3)
    for _ in range(int(120.0 / 0.02)):
        eta, nu = model.step(eta, nu, (0.0, 0.0, 0.0), 0.02, bias=F)
    Fb = _R(psi0).T @ F
    assert eta[2] == pytest.approx(psi0, abs=1e-12)
    np.testing.assert_allclose(
        nu, [model.steady_surge_speed(Fb[0]), model.steady_surge_speed(Fb[1]), 0.0], atol=1e-8)
    v_world = _R(psi0) @ nu
    assert v_world[:2] @ F[:2] > 0.0  # pushed along the force


def test_disturbance_at_rest_by_hand():
    """Heading north (psi = 90 deg ENU), 0.1 m/s current east, a sway damping unlike surge's:
    the current comes from port, nu_c = R^T V = (0, -0.1) (body, + to port), so the hull takes
    Y = (d22 + dn22 |v_c|) v_c = (3 + 20 x 0.1) x -0.1 = -0.5 N (body: to starboard), which is
    +0.5 N east in the world; plus the wind bias (0.5, -0.4, 0.08). Surge's damping in place
    of sway's (a frame left out) would give 0.3 N, not 0.5.
    """
    params = Vessel3DofParams(M=(1.0, 1.0, 1.0), D=(2.0, 3.0, 0.5), Dn=(10.0, 20.0, 5.0))
    b = disturbance_at_rest(params, [math.pi / 2], (0.1, 0.0), (0.5, -0.4, 0.08))
    np.testing.assert_allclose(b, [[1.0, -0.4, 0.08]], atol=1e-12)
    # Heading east: the current is along surge, (2 + 10 x 0.1) x 0.1 = 0.3 N east.
    b = disturbance_at_rest(params, [0.0, math.pi / 2], [(0.1, 0.0), (0.0, 0.0)], (0, 0, 0))
    np.testing.assert_allclose(b, [[0.3, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-12)


def test_disturbance_at_rest_is_what_holds_the_hull_still():
    """Second formulation: the model's own derivatives. A body force that cancels the
    disturbance (tau = -R^T b_rest) leaves a still hull in a current still: eta_dot = 0 and
    nu_dot = 0, for any heading and current."""
    model = Vessel3Dof(CS_SAUCER)
    rng = np.random.default_rng(7)
    for psi, vx, vy in zip(rng.uniform(-math.pi, math.pi, 5), rng.uniform(-0.2, 0.2, 5),
                           rng.uniform(-0.2, 0.2, 5)):
        bias = rng.uniform(-0.5, 0.5, 3)
        b = disturbance_at_rest(CS_SAUCER, [psi], (vx, vy), bias)[0]
        tau = -(_R(psi).T @ b)
        rates = model.derivatives([0.0, 0.0, psi], [0.0, 0.0, 0.0], tau, current=(vx, vy),
                                  bias=bias)
        np.testing.assert_allclose(rates, 0.0, atol=1e-12)


def test_current_at_is_the_steady_current_plus_its_sinusoid():
    assert current_at(0.0, (0.05, -0.02), (0.01, 0.03), 60.0) == (0.05, -0.02)
    assert current_at(15.0, (0.05, -0.02), (0.01, 0.03), 60.0) == pytest.approx((0.06, 0.01))
    assert current_at(45.0, (0.05, -0.02), (0.01, 0.03), 60.0) == pytest.approx((0.04, -0.05))


def test_params_validate_and_from_mapping():
    p = Vessel3DofParams.from_mapping({'M': [9.51, 9.51, 0.116], 'D': (1.96, 1.96, 0.168),
                                       'Dn': np.array([7.095] * 3)})
    assert p == CS_SAUCER
    with pytest.raises(ValueError, match='^M:'):
        Vessel3DofParams(M=(1.0, 0.0, 1.0), D=(1, 1, 1), Dn=(1, 1, 1)).validate()
    with pytest.raises(ValueError, match='^Dn:'):
        Vessel3DofParams(M=(1, 1, 1), D=(1, 1, 1), Dn=(1, -1, 1)).validate()
    with pytest.raises(ValueError, match=r'^D\[1\]: must be finite'):
        Vessel3DofParams(M=(1, 1, 1), D=(1, math.nan, 1), Dn=(1, 1, 1)).validate()
    with pytest.raises(ValueError, match='^D:'):
        Vessel3DofParams(M=(1, 1, 1), D=(1, 1), Dn=(1, 1, 1)).validate()
    with pytest.raises(ValueError, match='^Dn: missing'):
        Vessel3DofParams.from_mapping({'M': [1, 1, 1], 'D': [1, 1, 1]})
    with pytest.raises(ValueError, match='^mass: unknown'):
        Vessel3DofParams.from_mapping({'M': [1, 1, 1], 'D': [1, 1, 1], 'Dn': [1, 1, 1],
                                       'mass': 3})
    with pytest.raises(ValueError, match='^M:'):
        Vessel3Dof(Vessel3DofParams(M=(1, 1, -1), D=(1, 1, 1), Dn=(1, 1, 1)))
    model = Vessel3Dof(CS_SAUCER)
    with pytest.raises(ValueError, match='dt'):
        model.step((0, 0, 0), (0, 0, 0), (0, 0, 0), 0.0)
    with pytest.raises(ValueError, match='tau'):
        model.step((0, 0, 0), (0, 0, 0), (0, math.inf, 0), 0.01)
    with pytest.raises(ValueError, match='current'):
        model.derivatives((0, 0, 0), (0, 0, 0), (0, 0, 0), current=(1, 2, 3))


# -- azimuth actuators ------------------------------------------------------------------------


def test_first_order_thrust_is_exact():
    act = AzimuthActuators(saucer_specs())
    act.step([1.0, -0.5, 0.0], [0.0, 0.0, 0.0], 0.1)  # one time constant
    np.testing.assert_allclose(act.thrust, np.array([1.0, -0.5, 0.0]) * (1 - math.exp(-1)),
                               rtol=1e-14)
    assert act.thrust[0] == pytest.approx(0.632, abs=5e-4)
    # The exact exponential composes: ten steps of tau/10 equal one step of tau.
    act2 = AzimuthActuators(saucer_specs())
    for _ in range(10):
        act2.step([1.0, -0.5, 0.0], [0.0, 0.0, 0.0], 0.01)
    np.testing.assert_allclose(act2.thrust, act.thrust, rtol=1e-13)
    # Zero time constant: instant.
    inst = AzimuthActuators(saucer_specs(time_constant=0.0))
    inst.step([0.7, 0.2, -0.3], [0.0, 0.0, 0.0], 0.001)
    np.testing.assert_array_equal(inst.thrust, [0.7, 0.2, -0.3])


def test_angle_rate_limit_and_clipping():
    act = AzimuthActuators(saucer_specs())
    dt = 0.01
    prev = act.angle
    for _ in range(200):
        act.step([0.0, 0.0, 0.0], [3.0, -1.0, 0.5], dt)  # 3 rad > 114 deg: clipped
        a = act.angle
        assert np.all(np.abs(a - prev) <= 3.0 * dt + 1e-15)
        prev = a
    np.testing.assert_allclose(act.angle, [math.radians(114.0), -1.0, 0.5], rtol=1e-15)
    assert act.angle[0] == SERVO_LIMIT
    # Time to reach: 1.99 rad at 3 rad/s -> 0.663 s.
    act.reset()
    for _ in range(66):
        act.step([0.0] * 3, [3.0, 0.0, 0.0], dt)
    assert act.angle[0] == pytest.approx(0.66 * 3.0, rel=1e-12)
    assert act.angle[0] < SERVO_LIMIT
    act.step([5.0, -5.0, 0.0], [-3.0, 0.0, 0.0], 10.0)  # thrust commands clipped too
    np.testing.assert_allclose(act.thrust, [1.5, -1.0, 0.0], rtol=1e-12)
    assert act.angle[0] == -SERVO_LIMIT


def test_actuator_tau_matches_geometry():
    specs = saucer_specs(time_constant=0.0, max_angle_rate=math.inf)
    act = AzimuthActuators(specs)
    T, a = np.array([1.0, 0.5, -0.8]), np.array([0.3, -1.2, 1.9])
    act.step(T, a, 0.01)
    tau = act.tau()
    X = Y = N = 0.0
    for s, Ti, ai in zip(specs, T, a):
        F = Ti * np.array([math.cos(ai), math.sin(ai), 0.0])
        r = np.array([*s.position, 0.0])
        X, Y, N = X + F[0], Y + F[1], N + np.cross(r, F)[2]
    np.testing.assert_allclose(tau, [X, Y, N], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(azimuth_tau([s.position for s in specs], T, a), tau, atol=1e-15)
    # Symmetric layout, all pushing forward: pure surge; all tangential: pure yaw.
    assert azimuth_tau(act.positions, [1, 1, 1], [0, 0, 0]) == pytest.approx([3, 0, 0])
    # Tangential (CCW) pushes at 90, 210, 330 deg point at 180, 300, 60 deg: the first is
    # outside +/-114 deg, so it is produced reversed (angle 0, thrust -1).
    tau_t = azimuth_tau(act.positions, [-1, 1, 1], [0.0, -math.pi / 3, math.pi / 3])
    np.testing.assert_allclose(tau_t, [0.0, 0.0, 3 * RADIUS], atol=1e-15)


def test_azimuth_spec_validation():
    with pytest.raises(ConfigurationError, match='max_reverse'):
        AzimuthSpec('a', (0, 0), 1.0, 0.0)
    with pytest.raises(ConfigurationError, match='position'):
        AzimuthSpec('a', (0, 0, 0), 1.0, 1.0)
    with pytest.raises(ConfigurationError, match='time_constant'):
        AzimuthSpec('a', (0, 0), 1.0, 1.0, time_constant=-0.1)
    with pytest.raises(ConfigurationError, match='angle_min'):
        AzimuthSpec('a', (0, 0), 1.0, 1.0, angle_min=0.5, angle_max=0.1)
    s = AzimuthSpec('a', [0, 1], 2, 1)
    assert s.position == (0.0, 1.0) and s.angle_max == math.pi  # no travel limit by default


# -- inputs are named in their errors; actuator states set by hand -----------------------------
# (gaps found by the mutation run, docs/testing.md)

@pytest.mark.parametrize('call, message', [
    (lambda v: v.derivatives([0.0] * 2, [0.0] * 3, [0.0] * 3), r'^eta: expected 3 values'),
    (lambda v: v.derivatives([0.0] * 3, [0.0] * 4, [0.0] * 3), r'^nu: expected 3 values'),
    (lambda v: v.derivatives([0.0] * 3, [0.0] * 3, [0.0] * 2), r'^tau: expected 3 values'),
    (lambda v: v.derivatives([0.0] * 3, [0.0] * 3, [0.0] * 3, current=[0.0] * 3),
     r'^current: expected 2 values'),
    (lambda v: v.derivatives([0.0] * 3, [0.0] * 3, [0.0] * 3, bias=[0.0] * 2),
     r'^bias: expected 3 values'),
    (lambda v: v.step([0.0] * 4, [0.0] * 3, [0.0] * 3, 0.1), r'^eta: expected 3 values'),
    (lambda v: v.step([0.0] * 3, [0.0] * 2, [0.0] * 3, 0.1), r'^nu: expected 3 values'),
    (lambda v: v.coriolis([0.0] * 4), r'^nu: expected 3 values'),
    (lambda v: v.damping([0.0] * 2), r'^nu: expected 3 values'),
])
def test_vessel_inputs_of_the_wrong_length_are_named(call, message):
    with pytest.raises(ValueError, match=message):
        call(Vessel3Dof(CS_SAUCER))


def test_from_mapping_errors_name_the_keys():
    good = {'M': [1.0, 1.0, 1.0], 'D': [1.0, 1.0, 1.0], 'Dn': [0.0, 0.0, 0.0]}
    with pytest.raises(ValueError, match=r'^Mx, Q: unknown key\(s\); expected M, D, Dn$'):
        Vessel3DofParams.from_mapping({**good, 'Q': [0.0] * 3, 'Mx': [0.0] * 3})
    with pytest.raises(ValueError, match=r'^D: expected 3 values, got 4'):
        Vessel3DofParams.from_mapping({**good, 'D': [1.0] * 4})


@pytest.mark.parametrize('call, message', [
    (lambda a: a.reset(thrust=[0.0] * 2), r'^thrust: expected 3 values'),
    (lambda a: a.reset(angle=[0.0] * 4), r'^angle: expected 3 values'),
    (lambda a: a.step([0.0] * 2, [0.0] * 3, 0.1), r'^thrust_cmd: expected 3 values'),
    (lambda a: a.step([0.0] * 3, [0.0] * 4, 0.1), r'^angle_cmd: expected 3 values'),
])
def test_actuator_inputs_of_the_wrong_length_are_named(call, message):
    with pytest.raises(ValueError, match=message):
        call(AzimuthActuators(saucer_specs()))


def test_actuator_reset_sets_and_clips_the_states():
    act = AzimuthActuators(saucer_specs())
    act.reset(thrust=[0.5, 9.0, -9.0], angle=[0.3, 3.0, -3.0])
    # thrust limits +1.5 / -1.0 N, travel +/-114 deg (saucer_specs)
    assert act.thrust.tolist() == [0.5, 1.5, -1.0]
    assert act.angle.tolist() == [0.3, SERVO_LIMIT, -SERVO_LIMIT]
    act.reset()
    assert act.thrust.tolist() == [0.0] * 3 and act.angle.tolist() == [0.0] * 3


def test_actuator_starts_at_the_reachable_angle_closest_to_zero():
    act = AzimuthActuators(saucer_specs(angle_min=0.5, angle_max=2.0)
                           + saucer_specs(angle_min=-2.0, angle_max=-0.25)[:1])
    assert act.angle.tolist() == [0.5, 0.5, 0.5, -0.25]


def test_actuator_layout_is_read_only_and_not_empty():
    act = AzimuthActuators(saucer_specs())
    with pytest.raises(ValueError, match='read-only'):
        act.positions[0, 0] = 1.0
    with pytest.raises(ConfigurationError, match='^azimuth layout is empty$'):
        AzimuthActuators([])


@pytest.mark.parametrize('field,args', [
    ('max_forward', dict(max_forward=math.inf)),
    ('max_reverse', dict(max_reverse=math.inf)),
    ('max_forward', dict(max_forward=-1.0)),
])
def test_azimuth_thrust_limits_must_be_finite_and_positive(field, args):
    # An infinite thrust limit would switch saturation off for that thruster (only the servo
    # slew rate may be infinite): refused, the message names the field and the rule.
    kw = {**dict(max_forward=1.0, max_reverse=1.0), **args}
    with pytest.raises(ConfigurationError, match=rf"^azimuth 'a': {field} must be a positive"):
        AzimuthSpec('a', (0, 0), **kw)
    assert AzimuthSpec('a', (0, 0), 1.0, 1.0, max_angle_rate=math.inf).max_angle_rate == math.inf
