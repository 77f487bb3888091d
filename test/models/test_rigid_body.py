"""Tests of the 6-DOF rigid-body model (pure algorithm tier: numpy/scipy only, no rclpy)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from support.vectors import cross

from enbarr_core.framework.kinematics import quat_from_euler, quat_to_euler, quat_to_rotmat
from enbarr_core.models.rigid_body import RigidBodyModel, RigidBodyParams, RigidBodyState

G = 9.81
DT = 0.0025  # 400 Hz, the rate the simulator runs at [s]

# A BlueROV2-sized vehicle with deliberately non-trivial coupling: products of inertia, a CG
# off the centre line and 2 N of net buoyancy.
ROV = dict(
    mass=11.5,
    inertia=(0.26, 0.012, -0.008, 0.012, 0.23, 0.005, -0.008, 0.005, 0.37),
    r_g=(0.01, -0.005, -0.03),
    r_b=(0.0, 0.0, 0.01),
    buoyancy=11.5 * G + 2.0,
    added_mass=(5.5, 12.7, 14.57, 0.12, 0.12, 0.12),
    d_lin=(4.03, 6.22, 5.18, 0.07, 0.07, 0.07),
    d_quad=(18.18, 21.66, 36.99, 1.55, 1.55, 1.55),
)


def params(**overrides) -> RigidBodyParams:
    return RigidBodyParams(**{**ROV, **overrides})


def simulate(model: RigidBodyModel, state: RigidBodyState, tau, t_end: float,
             dt: float = DT) -> RigidBodyState:
    for _ in range(int(round(t_end / dt))):
        state = model.step(state, tau, dt)
    return state


# -- independent reference: Euler angles, Kirchhoff's equations, scipy ------------------------

def _S(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _R_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cf, -sf], [0.0, sf, cf]])
    Ry = np.array([[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]])
    Rz = np.array([[cp, -sp, 0.0], [sp, cp, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def _T_zyx(phi: float, theta: float) -> np.ndarray:
    """ZYX Euler-angle rates from body rates (valid away from theta = +-90 deg)."""
    return np.array([
        [1.0, math.sin(phi) * math.tan(theta), math.cos(phi) * math.tan(theta)],
        [0.0, math.cos(phi), -math.sin(phi)],
        [0.0, math.sin(phi) / math.cos(theta), math.cos(phi) / math.cos(theta)],
    ])


def reference_rhs(prm: RigidBodyParams, tau: np.ndarray):
    """dy/dt of y = [p(3), phi, theta, psi, nu(6)], written without the module under test.

    Kinetics from Kirchhoff's equations with T = 1/2 nu^T M nu, h = M nu:
    M nu_dot + [omega x h1; omega x h2 + v x h1] + D(nu) nu = tau + f_restoring.
    """
    m = prm.mass
    r_g, r_b = np.array(prm.r_g), np.array(prm.r_b)
    inertia = np.array(prm.inertia, dtype=float)
    I_o = np.diag(inertia) if inertia.size == 3 else inertia.reshape(3, 3)
    M = np.block([[m * np.eye(3), -m * _S(r_g)], [m * _S(r_g), I_o]])
    M = M + np.diag(prm.added_mass)
    dl, dq = np.array(prm.d_lin), np.array(prm.d_quad)
    W, B = m * prm.gravity, prm.buoyancy

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        phi, theta, psi = y[3:6]
        nu = y[6:]
        v, w = nu[:3], nu[3:]
        R = _R_zyx(phi, theta, psi)
        T = _T_zyx(phi, theta)
        h = M @ nu
        c_nu = np.concatenate((cross(w, h[:3]), cross(w, h[3:]) + cross(v, h[:3])))
        d_nu = (dl + dq * np.abs(nu)) * nu
        f_g = R.T @ np.array([0.0, 0.0, -W])
        f_b = R.T @ np.array([0.0, 0.0, B])
        f_restore = np.concatenate((f_g + f_b, cross(r_g, f_g) + cross(r_b, f_b)))
        nu_dot = np.linalg.solve(M, tau + f_restore - c_nu - d_nu)
        return np.concatenate((R @ v, T @ w, nu_dot))

    return rhs


def attitude_error(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle [rad] of the rotation R_a^T R_b (atan2 form: accurate for tiny angles too)."""
    E = R_a.T @ R_b
    sin_vec = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    return math.atan2(float(np.linalg.norm(sin_vec)), 0.5 * (np.trace(E) - 1.0))


EULER0 = (0.15, -0.1, 0.4)
NU0 = np.array([0.6, -0.2, 0.15, 0.3, -0.25, 0.5])
TAU = np.array([25.0, -8.0, 6.0, 0.8, -0.6, 1.2])


def test_matches_independent_solve_ivp_reference():
    """10 s with coupled 6-DOF motion: RK4 at 400 Hz matches scipy (rtol 1e-10) closely."""
    prm = params()
    model = RigidBodyModel(prm)
    p0 = np.array([1.0, -2.0, -3.0])
    state = RigidBodyState(p=p0, q=quat_from_euler(*EULER0), nu=NU0)
    t_end = 10.0
    sol = solve_ivp(reference_rhs(prm, TAU), (0.0, t_end), np.concatenate((p0, EULER0, NU0)),
                    method='DOP853', rtol=1e-10, atol=1e-12, dense_output=True)
    assert sol.success
    path = sol.sol(np.linspace(0.0, t_end, 2001))
    # The run is non-trivial (about 8 m of path, roll up to 33 deg, yaw rate above 1 rad/s) and
    # stays far from the Euler-angle singularity the reference has at pitch +-90 deg.
    assert np.sum(np.linalg.norm(np.diff(path[:3], axis=1), axis=0)) > 5.0
    assert np.max(np.abs(path[3])) > math.radians(20.0)
    assert np.max(np.abs(path[4])) < math.radians(60.0)
    y = sol.y[:, -1]

    final = simulate(model, state, TAU, t_end)

    # Measured: 3e-9 m, < 1e-9 rad, 4e-11 in nu; the tolerances leave a 30x margin.
    np.testing.assert_allclose(final.p, y[:3], rtol=0.0, atol=1e-7)  # [m]
    assert attitude_error(quat_to_rotmat(final.q), _R_zyx(*y[3:6])) < 1e-7  # [rad]
    np.testing.assert_allclose(final.nu, y[6:], rtol=0.0, atol=1e-8)  # [m/s, rad/s]
    assert abs(np.linalg.norm(final.q) - 1.0) < 1e-12


def test_rk4_is_fourth_order():
    """Halving dt cuts the error 16x: the quaternion stages do not degrade RK4.

    Quadratic damping is switched off here: |nu| nu is not smooth where a velocity crosses
    zero, which (correctly) lowers the observed order of any Runge-Kutta scheme.
    """
    prm = params(d_quad=(0.0,) * 6)
    model = RigidBodyModel(prm)
    t_end = 2.0
    sol = solve_ivp(reference_rhs(prm, TAU), (0.0, t_end),
                    np.concatenate((np.zeros(3), EULER0, NU0)),
                    method='DOP853', rtol=1e-13, atol=1e-14)
    y = sol.y[:, -1]
    errors, attitude_errors = [], []
    for dt in (0.02, 0.01):
        state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(*EULER0), nu=NU0)
        final = simulate(model, state, TAU, t_end, dt)
        errors.append(np.linalg.norm(final.p - y[:3]) + np.linalg.norm(final.nu - y[6:]))
        attitude_errors.append(attitude_error(quat_to_rotmat(final.q), _R_zyx(*y[3:6])))
    assert 14.0 < errors[0] / errors[1] < 18.0
    assert 14.0 < attitude_errors[0] / attitude_errors[1] < 18.0


def test_nu_dot_equals_matrix_form():
    """The fast path equals M^-1 (tau + tau_ext - C(nu) nu - D(nu) nu - g(eta))."""
    model = RigidBodyModel(params())
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        nu = rng.normal(size=6)
        tau, tau_ext = rng.normal(size=6) * 10.0, rng.normal(size=6)
        expected = np.linalg.solve(model.M, tau + tau_ext - model.coriolis(nu) @ nu
                                   - model.damping(nu) @ nu - model.restoring(q))
        np.testing.assert_allclose(model.nu_dot(q, nu, tau, tau_ext), expected,
                                   rtol=1e-10, atol=1e-10)


def test_step_holds_tau_plus_tau_ext():
    model = RigidBodyModel(params())
    state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(*EULER0), nu=NU0)
    ext = np.array([1.0, 2.0, -3.0, 0.1, 0.0, -0.2])
    a = model.step(state, TAU, DT, tau_ext=ext)
    b = model.step(state, TAU + ext, DT)
    np.testing.assert_array_equal(a.p, b.p)
    np.testing.assert_array_equal(a.nu, b.nu)


# -- closed-form steady states ----------------------------------------------------------------

def _surge_only(**overrides) -> RigidBodyParams:
    return RigidBodyParams(
        mass=10.0, inertia=(0.2, 0.3, 0.3), r_g=(0.0, 0.0, 0.0), r_b=(0.0, 0.0, 0.0),
        buoyancy=10.0 * G, added_mass=(5.0, 8.0, 8.0, 0.1, 0.1, 0.1),
        d_lin=(4.0, 0.0, 0.0, 0.0, 0.0, 0.0), d_quad=(20.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        **overrides)


@pytest.mark.sim
@pytest.mark.parametrize('yaw, heading', [(0.0, (1.0, 0.0)), (math.pi / 2, (0.0, 1.0))])
def test_surge_steady_state_is_root_of_damping_quadratic(yaw, heading):
    """Neutral vessel, surge damping only: d_lin u + d_quad u|u| = X at steady state."""
    prm = _surge_only()
    model = RigidBodyModel(prm)
    X = 30.0
    d_l, d_q = prm.d_lin[0], prm.d_quad[0]
    u_ss = (-d_l + math.sqrt(d_l * d_l + 4.0 * d_q * X)) / (2.0 * d_q)
    state = simulate(model, RigidBodyState.at_rest(yaw=yaw), [X, 0, 0, 0, 0, 0], 20.0)
    assert state.nu[0] == pytest.approx(u_ss, rel=1e-9)
    np.testing.assert_allclose(state.nu[1:], 0.0, atol=1e-12)
    # ENU: heading 0 is east (+x), heading 90 deg is north (+y); no heave.
    direction = state.p[:2] / np.linalg.norm(state.p[:2])
    np.testing.assert_allclose(direction, heading, atol=1e-12)
    assert abs(state.p[2]) < 1e-12


@pytest.mark.sim
def test_positively_buoyant_vessel_rises_at_terminal_velocity():
    """B > W: the vessel goes up (+z ENU) and d_lin w + d_quad w|w| = B - W at steady state."""
    prm = RigidBodyParams(
        mass=10.0, inertia=(0.2, 0.3, 0.3), r_g=(0.0, 0.0, -0.02), r_b=(0.0, 0.0, 0.0),
        buoyancy=10.0 * G + 5.0, added_mass=(5.0, 8.0, 8.0, 0.1, 0.1, 0.1),
        d_lin=(4.0, 6.0, 5.0, 0.1, 0.1, 0.1), d_quad=(20.0, 20.0, 30.0, 1.0, 1.0, 1.0))
    model = RigidBodyModel(prm)
    state = RigidBodyState.at_rest(p=(0.0, 0.0, -10.0), yaw=0.7)
    nu_dot = model.nu_dot(state.q, state.nu, np.zeros(6))
    assert nu_dot[2] == pytest.approx(5.0 / (10.0 + 8.0))  # (B - W) / (m + Z_wdot)
    state = simulate(model, state, np.zeros(6), 20.0)
    net = prm.buoyancy - prm.mass * G
    w_ss = (-5.0 + math.sqrt(25.0 + 4.0 * 30.0 * net)) / (2.0 * 30.0)
    assert state.p[2] > -10.0 + 0.5 * w_ss * 20.0
    assert state.nu[2] == pytest.approx(w_ss, rel=1e-9)
    np.testing.assert_allclose(state.p[:2], 0.0, atol=1e-12)


# -- the free surface (height > 0) -----------------------------------------------------------

def test_submerged_fraction_of_a_prism_centred_on_the_cb():
    model = RigidBodyModel(params(height=0.25))
    for z_b, s in ((-1.0, 1.0), (-0.125, 1.0), (-0.0625, 0.75), (0.0, 0.5), (0.0625, 0.25),
                   (0.125, 0.0), (2.0, 0.0)):
        assert model.submerged(z_b) == pytest.approx(s)
    assert RigidBodyModel(params()).submerged(5.0) == 1.0  # height 0: deep water


def test_free_surface_fast_path_equals_matrix_form():
    """At any height of the CO (fully under, emerging, out), with and without a current, the
    fast path takes the buoyancy the matrix form does: s B at r_b, s from the CB's height."""
    model = RigidBodyModel(params(height=0.25))
    rng = np.random.default_rng(7)
    for z in np.linspace(-0.3, 0.3, 13):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        nu, tau = rng.normal(size=6), rng.normal(size=6) * 10.0
        p = np.array([rng.normal(), rng.normal(), z])
        expected = np.linalg.solve(model.M, tau - model.coriolis(nu) @ nu
                                   - model.damping(nu) @ nu - model.restoring(q, p))
        np.testing.assert_allclose(model.nu_dot(q, nu, tau, p=p), expected, rtol=1e-10,
                                   atol=1e-10)
        # In a current only the hydrodynamic terms change: the restoring difference is the same.
        current = np.array([0.3, -0.2, 0.05])
        diff = model.nu_dot(q, nu, tau, current=current, p=p) - model.nu_dot(
            q, nu, tau, current=current)
        np.testing.assert_allclose(
            diff, np.linalg.solve(model.M, model.restoring(q) - model.restoring(q, p)),
            rtol=1e-9, atol=1e-10)


@pytest.mark.sim
def test_positively_buoyant_vessel_floats_with_w_over_b_submerged():
    """B > W with a free surface: the vessel rises, breaks the surface and settles where
    s B = W, the CB at z = h (1/2 - W/B); in deep water (height 0) it would still be rising
    at 0.33 m/s after the minute (test_positively_buoyant_vessel_rises_at_terminal_velocity).
    """
    h = 0.2
    prm = RigidBodyParams(
        mass=10.0, inertia=(0.2, 0.3, 0.3), r_g=(0.0, 0.0, -0.02), r_b=(0.0, 0.0, 0.0),
        buoyancy=10.0 * G + 5.0, added_mass=(5.0, 8.0, 8.0, 0.1, 0.1, 0.1),
        d_lin=(4.0, 6.0, 5.0, 0.1, 0.1, 0.1), d_quad=(20.0, 20.0, 30.0, 1.0, 1.0, 1.0),
        height=h)
    model = RigidBodyModel(prm)
    state = RigidBodyState.at_rest(p=(0.0, 0.0, -2.0), yaw=0.7)
    highest = -math.inf
    for _ in range(60):
        state = simulate(model, state, np.zeros(6), 1.0)
        highest = max(highest, float(state.p[2]))
    z_eq = h * (0.5 - 10.0 * G / (10.0 * G + 5.0))   # -0.0903 m
    assert state.p[2] == pytest.approx(z_eq, abs=1e-4)
    assert abs(state.nu[2]) < 1e-3
    assert z_eq < highest < h / 2  # overshot the float line, never left the water
    deep = simulate(RigidBodyModel(dataclasses.replace(prm, height=0.0)),
                    RigidBodyState.at_rest(p=(0.0, 0.0, -2.0)), np.zeros(6), 20.0)
    assert deep.p[2] > 3.0  # without the surface: 4.7 m above it


# -- energy and skew-symmetry -----------------------------------------------------------------

def test_coriolis_is_skew_symmetric():
    model = RigidBodyModel(params())
    rng = np.random.default_rng(2)
    for _ in range(50):
        nu = rng.normal(size=6) * 3.0
        C = model.coriolis(nu)
        np.testing.assert_allclose(C + C.T, 0.0, atol=1e-12)
        assert abs(nu @ C @ nu) < 1e-10


def test_kinetic_energy_and_kirchhoff_invariants_conserved_without_damping():
    """No damping, B = W at the same point (g = 0), tau = 0: 1/2 nu^T M nu is conserved.

    Energy only checks that C is skew; |h1| and h1 . h2 (h = M nu, Kirchhoff's invariants) also
    check that C has the right structure.
    """
    prm = params(buoyancy=ROV['mass'] * G, r_b=ROV['r_g'], d_lin=(0.0,) * 6, d_quad=(0.0,) * 6)
    model = RigidBodyModel(prm)
    np.testing.assert_allclose(model.restoring(quat_from_euler(0.4, -0.3, 1.0)), 0.0, atol=1e-12)
    rng = np.random.default_rng(3)
    nu0 = rng.normal(size=6) * np.array([0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
    state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(0.2, 0.1, -0.5), nu=nu0)
    h0 = model.M @ nu0
    T0 = model.kinetic_energy(nu0)
    for _ in range(4):
        state = simulate(model, state, np.zeros(6), 2.5)
        h = model.M @ state.nu
        assert model.kinetic_energy(state.nu) == pytest.approx(T0, rel=1e-9)
        assert np.linalg.norm(h[:3]) == pytest.approx(np.linalg.norm(h0[:3]), rel=1e-9)
        assert h[:3] @ h[3:] == pytest.approx(h0[:3] @ h0[3:], rel=1e-8)
    assert np.linalg.norm(state.nu - nu0) > 0.1  # energy moved between the DOFs


# -- restoring --------------------------------------------------------------------------------

def _bottom_heavy() -> RigidBodyParams:
    return RigidBodyParams(
        mass=10.0, inertia=(0.2, 0.3, 0.3), r_g=(0.0, 0.0, -0.05), r_b=(0.0, 0.0, 0.02),
        buoyancy=10.0 * G, added_mass=(5.0, 8.0, 8.0, 0.1, 0.1, 0.1),
        d_lin=(4.0, 6.0, 5.0, 0.3, 0.3, 0.3), d_quad=(20.0, 20.0, 30.0, 0.5, 0.5, 0.5))


@pytest.mark.sim
@pytest.mark.parametrize('axis', [0, 1])
def test_bottom_heavy_vessel_rights_itself(axis):
    """CG below CB, tilted 20 deg and released: righting moment -W BG sin(angle), back to level."""
    prm = _bottom_heavy()
    model = RigidBodyModel(prm)
    angle = math.radians(20.0)
    euler = [0.0, 0.0, 0.3]
    euler[axis] = angle
    state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(*euler), nu=np.zeros(6))
    BG = prm.r_b[2] - prm.r_g[2]
    moment = -model.restoring(state.q)[3 + axis]  # g is on the left-hand side
    assert moment == pytest.approx(-prm.mass * G * BG * math.sin(angle), rel=1e-12)
    tilt = []
    for _ in range(60):
        state = simulate(model, state, np.zeros(6), 0.5)
        tilt.append(abs(quat_to_euler(state.q)[axis]))
    assert tilt[1] < angle
    assert tilt[-1] < math.radians(0.5)


def test_top_heavy_vessel_capsizes():
    """CG above CB is unstable: the restoring moment pushes further away from level."""
    prm = dataclasses.replace(_bottom_heavy(), r_g=(0.0, 0.0, 0.05))
    model = RigidBodyModel(prm)
    q = quat_from_euler(math.radians(5.0), 0.0, 0.0)
    assert -model.restoring(q)[3] > 0.0


# -- accelerometer ----------------------------------------------------------------------------

def test_specific_force_at_rest_level_reads_plus_g():
    model = RigidBodyModel(_surge_only())
    state = RigidBodyState.at_rest(p=(3.0, 4.0, -5.0), yaw=1.2)
    nu_dot = model.nu_dot(state.q, state.nu, np.zeros(6))
    np.testing.assert_allclose(nu_dot, 0.0, atol=1e-12)
    np.testing.assert_allclose(model.specific_force(state, nu_dot), [0.0, 0.0, G], atol=1e-12)


def test_specific_force_rolled_at_rest_and_in_free_fall():
    # Rolled +30 deg at rest: gravity reaction seen in the body, [0, g sin, g cos].
    model = RigidBodyModel(_surge_only())
    roll = math.radians(30.0)
    state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(roll, 0.0, 0.0), nu=np.zeros(6))
    np.testing.assert_allclose(model.specific_force(state, np.zeros(6)),
                               [0.0, G * math.sin(roll), G * math.cos(roll)], atol=1e-12)
    # No buoyancy, damping or added mass: a tumbling body falls freely and reads zero.
    free = RigidBodyModel(RigidBodyParams(
        mass=2.0, inertia=(0.1, 0.2, 0.3), r_g=(0.0, 0.0, 0.0), r_b=(0.0, 0.0, 0.0),
        buoyancy=0.0, added_mass=(0.0,) * 6, d_lin=(0.0,) * 6, d_quad=(0.0,) * 6))
    state = RigidBodyState(p=np.zeros(3), q=quat_from_euler(0.3, -0.2, 0.1),
                           nu=np.array([1.0, -0.5, 0.2, 0.4, 0.3, -0.6]))
    nu_dot = free.nu_dot(state.q, state.nu, np.zeros(6))
    np.testing.assert_allclose(free.specific_force(state, nu_dot), 0.0, atol=1e-12)


# -- parameters and API -----------------------------------------------------------------------

@pytest.mark.parametrize('field, value', [
    ('mass', 0.0),
    ('mass', -1.0),
    ('mass', float('nan')),
    ('inertia', (0.2, 0.3)),
    ('inertia', (0.2, 0.3, -0.1)),
    ('inertia', (0.2, 0.1, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.3)),  # not symmetric
    ('inertia', (0.2, 0.5, 0.0, 0.5, 0.2, 0.0, 0.0, 0.0, 0.3)),  # symmetric, indefinite
    ('inertia', (0.001, 0.001, 0.001)),  # I_o - parallel-axis term < 0 for this r_g
    ('inertia', (0.2, float('inf'), 0.3)),
    ('r_g', (0.0, 0.0)),
    ('r_b', (0.0, float('nan'), 0.0)),
    ('buoyancy', -1.0),
    ('added_mass', (1.0, 1.0, 1.0, 1.0, 1.0)),
    ('added_mass', (1.0, -1.0, 1.0, 1.0, 1.0, 1.0)),
    ('d_lin', (1.0, 1.0, 1.0, 1.0, 1.0, -0.1)),
    ('d_quad', (1.0, 1.0, 1.0, 1.0, float('nan'), 1.0)),
    ('d_quad', 'abc'),
    ('gravity', 0.0),
    ('height', -0.1),
])
def test_validate_names_the_bad_field(field, value):
    prm = params(**{field: value, **({'r_g': (0.3, 0.0, -0.3)} if field == 'inertia' else {})})
    with pytest.raises(ValueError, match=rf'^{field}\b'):
        prm.validate()
    with pytest.raises(ValueError, match=rf'^{field}\b'):
        RigidBodyModel(prm)


def test_valid_params_pass_and_from_mapping_accepts_lists():
    params().validate()
    mapping = {k: list(v) if isinstance(v, tuple) else v for k, v in ROV.items()}
    prm = RigidBodyParams.from_mapping(mapping)
    assert prm == params()
    assert prm.gravity == G
    diag = RigidBodyParams.from_mapping({**mapping, 'inertia': [0.2, 0.3, 0.4], 'gravity': 9.8})
    np.testing.assert_allclose(RigidBodyModel(diag).M[3:, 3:], np.diag([0.32, 0.42, 0.52]),
                               atol=1e-15)
    assert diag.gravity == 9.8
    nested = RigidBodyParams.from_mapping(
        {**mapping, 'inertia': np.reshape(ROV['inertia'], (3, 3)).tolist()})
    assert nested.inertia == ROV['inertia']


@pytest.mark.parametrize('change, match', [
    ({'mass': None}, r'^mass: missing'),
    ({'masss': 1.0}, r'^masss\b'),
    ({'d_lin': [1.0, 2.0]}, r'^d_lin\b'),
    ({'mass': 'heavy'}, r'^mass\b'),
    ({'mass': True}, r'^mass\b'),
    ({'buoyancy': -5.0}, r'^buoyancy\b'),
])
def test_from_mapping_errors_name_the_key(change, match):
    mapping = {**ROV, **change}
    mapping = {k: v for k, v in mapping.items() if v is not None}
    with pytest.raises(ValueError, match=match):
        RigidBodyParams.from_mapping(mapping)


@pytest.mark.parametrize('dt', [0.0, -0.01, float('nan'), float('inf'), None])
def test_step_rejects_bad_dt(dt):
    model = RigidBodyModel(params())
    with pytest.raises(ValueError, match=r'^dt\b'):
        model.step(RigidBodyState.at_rest(), np.zeros(6), dt)


def test_step_rejects_bad_tau():
    model = RigidBodyModel(params())
    with pytest.raises(ValueError, match=r'^tau\b'):
        model.step(RigidBodyState.at_rest(), np.zeros(3), DT)
    with pytest.raises(ValueError, match=r'^tau\b'):
        model.step(RigidBodyState.at_rest(), [float('nan'), 0, 0, 0, 0, 0], DT)
    with pytest.raises(ValueError, match=r'^tau_ext\b'):
        model.step(RigidBodyState.at_rest(), np.zeros(6), DT, tau_ext=np.zeros(5))


def test_state_and_matrices_are_read_only():
    model = RigidBodyModel(params())
    state = RigidBodyState.at_rest(p=(1.0, 2.0, 3.0), yaw=math.pi / 2)
    np.testing.assert_allclose(quat_to_euler(state.q), (0.0, 0.0, math.pi / 2), atol=1e-15)
    with pytest.raises(ValueError):
        state.p[0] = 5.0
    with pytest.raises(ValueError):
        model.M[0, 0] = 5.0
    np.testing.assert_allclose(model.M, model.M.T, atol=1e-15)
    np.testing.assert_allclose(model.M @ model.M_inv, np.eye(6), atol=1e-12)
    with pytest.raises(ValueError, match=r'^q\b'):
        RigidBodyState(p=np.zeros(3), q=np.zeros(3), nu=np.zeros(6))


def test_module_does_not_import_rclpy():
    import enbarr_core.models.rigid_body as rb

    with open(rb.__file__, encoding='utf-8') as f:
        assert 'rclpy' not in f.read()


# -- a constant, irrotational current (Fossen 2021, eq. 10.1) ---------------------------------

def reference_rhs_in_current(prm: RigidBodyParams, tau: np.ndarray, v_c: np.ndarray):
    """dy/dt of y = [p(3), phi, theta, psi, nu(6)] in a current, without the module under test.

    Fossen 2021, eq. 10.1, with the rigid body on the velocity over ground and the water's
    reaction on the relative velocity nu_r = nu - [R^T v_c; 0]:
    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r = tau + f_rest,
    nu_r_dot = nu_dot + [omega x R^T v_c; 0]; each C from Kirchhoff's equations of its own M.
    """
    m = prm.mass
    r_g, r_b = np.array(prm.r_g), np.array(prm.r_b)
    inertia = np.array(prm.inertia, dtype=float)
    I_o = np.diag(inertia) if inertia.size == 3 else inertia.reshape(3, 3)
    M_RB = np.block([[m * np.eye(3), -m * _S(r_g)], [m * _S(r_g), I_o]])
    M_A = np.diag(prm.added_mass)
    dl, dq = np.array(prm.d_lin), np.array(prm.d_quad)
    W, B = m * prm.gravity, prm.buoyancy

    def kirchhoff(M: np.ndarray, nu: np.ndarray, w: np.ndarray) -> np.ndarray:
        h = M @ nu
        return np.concatenate((cross(w, h[:3]), cross(w, h[3:]) + cross(nu[:3], h[:3])))

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        phi, theta, psi = y[3:6]
        nu = y[6:]
        v, w = nu[:3], nu[3:]
        R = _R_zyx(phi, theta, psi)
        T = _T_zyx(phi, theta)
        v_cb = R.T @ v_c
        nu_r = nu - np.concatenate((v_cb, np.zeros(3)))
        shift = np.concatenate((cross(w, v_cb), np.zeros(3)))  # nu_r_dot - nu_dot
        f_g = R.T @ np.array([0.0, 0.0, -W])
        f_b = R.T @ np.array([0.0, 0.0, B])
        f_rest = np.concatenate((f_g + f_b, cross(r_g, f_g) + cross(r_b, f_b)))
        rhs_ = (tau + f_rest - kirchhoff(M_RB, nu, w) - kirchhoff(M_A, nu_r, w)
                - (dl + dq * np.abs(nu_r)) * nu_r - M_A @ shift)
        nu_dot = np.linalg.solve(M_RB + M_A, rhs_)
        return np.concatenate((R @ v, T @ w, nu_dot))

    return rhs


CURRENT = np.array([0.3, -0.2, 0.05])  # m/s (east, north, up)


def test_current_matches_independent_solve_ivp_reference():
    """Coupled vehicle (products of inertia, CG off the centre line, net buoyancy) turning in
    a 3-D current: the RK4 fast path against scipy's DOP853 on Euler angles and the matrix form
    of eq. 10.1. Budget: RK4 at 400 Hz over 3 s, global error O(dt^4) ~ 1e-9; 1e-6 leaves
    room for the reference's own 1e-11 tolerances and still sees any missing term (the smallest,
    M_A nu_c_dot, moves nu by ~1e-2 here).
    """
    prm = params()
    model = RigidBodyModel(prm)
    t_end = 3.0
    y0 = np.concatenate(([0.5, -1.0, -2.0], EULER0, NU0))
    ref = solve_ivp(reference_rhs_in_current(prm, TAU, CURRENT), (0.0, t_end), y0,
                    method='DOP853', rtol=1e-11, atol=1e-12)
    state = RigidBodyState(p=y0[:3], q=quat_from_euler(*EULER0), nu=NU0)
    for _ in range(int(round(t_end / DT))):
        state = model.step(state, TAU, DT, current=CURRENT)
    y_ref = ref.y[:, -1]
    np.testing.assert_allclose(state.p, y_ref[:3], atol=1e-6)
    np.testing.assert_allclose(state.nu, y_ref[6:], atol=1e-6)
    assert attitude_error(quat_to_rotmat(state.q), _R_zyx(*y_ref[3:6])) < 1e-6
    # The current changed the answer by far more than the budget (it is not ignored).
    still = solve_ivp(reference_rhs(prm, TAU), (0.0, t_end), y0, method='DOP853', rtol=1e-11,
                      atol=1e-12)
    assert np.max(np.abs(still.y[6:, -1] - y_ref[6:])) > 1e-2


def _neutral() -> RigidBodyParams:
    return params(buoyancy=ROV['mass'] * G, r_g=(0.0, 0.0, -0.03), r_b=(0.0, 0.0, 0.0),
                  inertia=(0.26, 0.23, 0.37))


@pytest.mark.parametrize('yaw', [0.0, 0.9, -2.5])
def test_moving_with_the_water_is_force_free(yaw):
    """A neutral, level vehicle drifting with the water (nu = [R^T v_c; 0]) feels no force:
    nu_r = 0, so damping, added mass and Coriolis all vanish (Galilean invariance)."""
    model = RigidBodyModel(_neutral())
    q = quat_from_euler(0.0, 0.0, yaw)
    nu = np.concatenate((quat_to_rotmat(q).T @ CURRENT, np.zeros(3)))
    np.testing.assert_allclose(model.nu_dot(q, nu, np.zeros(6), current=CURRENT), 0.0,
                               atol=1e-12)
    # In still water the same velocity is braked by the damping.
    assert np.linalg.norm(model.nu_dot(q, nu, np.zeros(6))) > 0.01


@pytest.mark.sim
def test_vehicle_at_rest_is_carried_by_the_current():
    """No thrust, starting at rest: the neutral vehicle ends moving with the water over ground
    (p_dot -> v_c) and stops turning. Budget: the slowest mode is yaw, (I_z + N_rdot) / N_r =
    0.49 / 0.07 = 7 s (the anisotropic added mass turns the hull while it accelerates), so
    after 120 s e^-17 ~ 4e-8 of a start-up of ~0.4 m/s, ~0.1 rad/s is left: 1e-5 is ample."""
    model = RigidBodyModel(_neutral())
    state = RigidBodyState.at_rest(yaw=0.6)
    p0 = state.p.copy()
    for _ in range(int(round(120.0 / 0.01))):
        state = model.step(state, np.zeros(6), 0.01, current=CURRENT)
    R = quat_to_rotmat(state.q)
    np.testing.assert_allclose(R @ state.nu[:3], CURRENT, atol=1e-5)
    np.testing.assert_allclose(state.nu[3:], 0.0, atol=1e-5)
    # It travelled about 120 s of current, less the start-up lag of a few seconds.
    assert np.all(np.abs(state.p - p0 - 120.0 * CURRENT) < np.abs(5.0 * CURRENT) + 1e-9)


@pytest.mark.sim
@pytest.mark.parametrize('yaw', [0.0, math.pi / 2])
def test_surge_in_a_head_current_is_still_water_speed_plus_current(yaw):
    """Surge damping only, thrust X ahead, current u_c along the heading: the damping sees
    u - u_c, so u = u_still + u_c with d_lin u_still + d_quad u_still |u_still| = X. Equal
    surge and sway added mass: no Munk moment, which would turn this yaw-undamped hull away
    from a straight course (at 90 deg, cos(pi/2) = 6e-17 would seed it)."""
    prm = dataclasses.replace(_surge_only(), added_mass=(5.0, 5.0, 8.0, 0.1, 0.1, 0.1))
    model = RigidBodyModel(prm)
    X, u_c = 30.0, -0.25  # against the heading
    d_l, d_q = prm.d_lin[0], prm.d_quad[0]
    u_still = (-d_l + math.sqrt(d_l * d_l + 4.0 * d_q * X)) / (2.0 * d_q)
    v_c = u_c * np.array([math.cos(yaw), math.sin(yaw), 0.0])
    state = RigidBodyState.at_rest(yaw=yaw)
    for _ in range(int(round(20.0 / DT))):
        state = model.step(state, [X, 0, 0, 0, 0, 0], DT, current=v_c)
    assert state.nu[0] == pytest.approx(u_still + u_c, rel=1e-9)
    np.testing.assert_allclose(state.nu[1:], 0.0, atol=1e-12)


def test_current_must_be_three_finite_numbers():
    model = RigidBodyModel(params())
    state = RigidBodyState.at_rest()
    with pytest.raises(ValueError, match='current'):
        model.step(state, np.zeros(6), DT, current=[0.1, 0.2])
    with pytest.raises(ValueError, match='current'):
        model.step(state, np.zeros(6), DT, current=[0.1, math.nan, 0.0])


# -- gaps found by the mutation run (docs/testing.md) ------------------------------------------

def test_kinetic_energy_by_hand():
    """T = 1/2 nu^T M nu: pure surge sees m + X_udot, pure yaw I_zz + N_rdot (ROV above)."""
    model = RigidBodyModel(params())
    assert model.kinetic_energy([2.0, 0, 0, 0, 0, 0]) == pytest.approx(0.5 * (11.5 + 5.5) * 4.0,
                                                                         rel=1e-12)
    assert model.kinetic_energy([0, 0, 0, 0, 0, 3.0]) == pytest.approx(0.5 * (0.37 + 0.12) * 9.0,
                                                                         rel=1e-12)


def test_from_mapping_unknown_keys_message_lists_both_sides():
    with pytest.raises(ValueError, match=(
            r'^massa, x: unknown key\(s\); expected mass, inertia, r_g, r_b, buoyancy, '
            r'added_mass, d_lin, d_quad, gravity, height$')):
        RigidBodyParams.from_mapping({**ROV, 'x': 1.0, 'massa': 2.0})


def test_nu_dot_names_its_inputs():
    model = RigidBodyModel(params())
    with pytest.raises(ValueError, match=r'^q: expected shape \(4,\)'):
        model.nu_dot([0.0, 0.0, 1.0], np.zeros(6), np.zeros(6))
    with pytest.raises(ValueError, match=r'^nu: expected shape \(6,\)'):
        model.nu_dot([0.0, 0.0, 0.0, 1.0], np.zeros(5), np.zeros(6))


def test_the_references_cross_product_is_numpys() -> None:
    """The references above use ``support.vectors.cross`` (np.cross is slow on 3-vectors)."""
    rng = np.random.default_rng(3)
    for a, b in rng.normal(size=(20, 2, 3)):
        np.testing.assert_allclose(cross(a, b), np.cross(a, b), rtol=1e-15, atol=1e-15)
