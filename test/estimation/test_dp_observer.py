"""Passive DP observer (pure algorithm tier) against a simulated CS Saucer.

The plant is the manual's 3-DOF model (CS Saucer manual, section 1.4), integrated here with RK4
independently of the observer's own model code:

    eta_dot = R(psi) nu,   M nu_dot + (C(nu) + D + D_n(nu)) nu = tau + R(psi)^T b
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support import saucer_plant
from support.saucer_plant import DT, NOISE, observer_settings, rot, wrap
from support.vectors import cross

from enbarr_core.estimation.dp_observer import (
    ObserverEstimate,
    ObserverSettings,
    PassiveObserver,
    place_observer_gains,
)

B_WORLD = np.array([0.3, -0.2, 0.02])              # constant world force bias [N, N, N m]


def plant_step(x, tau, b=B_WORLD, dt=DT):
    """RK4 over dt with tau and b held: x = [x, y, psi, u, v, r]."""
    return saucer_plant.step(x, tau, b, dt)


def excitation(t):
    """A slowly varying force that moves and turns the vessel (so the bias is seen turning)."""
    return np.array([0.6 * math.sin(0.21 * t), 0.5 * math.cos(0.13 * t),
                     0.03 * math.sin(0.17 * t + 0.4)])


def pose_error(est: ObserverEstimate, x):
    err = est.eta_hat - x[:3]
    err[2] = wrap(err[2])
    return err


def simulate(obs, seconds, x, t0=0.0, noise=True, rng=None, dropout=lambda t: False):
    """Run plant + observer; return the final state, time and the logged errors."""
    rng = rng if rng is not None else np.random.default_rng(0)
    log = []
    tau = excitation(t0)
    t = t0
    for _ in range(int(round(seconds / DT))):
        x = plant_step(x, tau)              # tau held over [t, t + dt]
        t += DT
        y = x[:3] + (rng.normal(0.0, NOISE) if noise else 0.0)
        est = obs.step(None if dropout(t) else y, tau, DT)
        # 0 t, 1-3 pose error, 4-6 nu error, 7-9 bias error, 10 stale, 11 age, 12 accepted,
        # 13-18 true state
        log.append((t, *pose_error(est, x), *(est.nu_hat - x[3:]), *(est.b_hat - B_WORLD),
                    est.stale, est.age, est.accepted, *x))
        tau = excitation(t)
    return x, t, np.array(log, dtype=float)


def converged_observer(seconds=90.0, seed=1, noise=True):
    rng = np.random.default_rng(seed)
    x = np.array([0.5, -0.3, 0.4, 0.0, 0.0, 0.0])
    obs = PassiveObserver(observer_settings())
    obs.initialize(x[:3] + rng.normal(0.0, NOISE))
    x, t, log = simulate(obs, seconds, x, noise=noise, rng=rng)
    return obs, x, t, log, rng


# --- convergence -----------------------------------------------------------------------------


@pytest.mark.sim
def test_estimates_converge_with_noise_and_a_world_bias():
    obs, x, t, log, _ = converged_observer(120.0)
    late = log[:, 0] > 60.0
    pos_rms = np.sqrt(np.mean(log[late, 1] ** 2 + log[late, 2] ** 2))
    psi_rms = np.sqrt(np.mean(log[late, 3] ** 2))
    vel_rms = np.sqrt(np.mean(log[late, 4:6] ** 2, axis=0))
    r_rms = np.sqrt(np.mean(log[late, 6] ** 2))
    b_err = np.abs(log[late, 7:10]).max(axis=0)
    assert pos_rms < 0.004                 # below the 5 mm measurement noise
    assert psi_rms < math.radians(0.4)     # below the 0.5 deg noise
    assert np.all(vel_rms < 0.01)          # [m/s]
    assert r_rms < 0.02                    # [rad/s]
    assert b_err[0] < 0.06 and b_err[1] < 0.06 and b_err[2] < 0.006  # 20 % / 30 % of b
    # Averaged over the last 60 s the bias is right within a few percent.
    assert np.all(np.abs(np.mean(log[late, 7:10], axis=0)) < [0.01, 0.01, 0.001])
    assert obs.rejected == 0
    # The vessel really moved and turned, so the world bias was seen from many headings.
    assert np.ptp(np.unwrap(log[:, 15])) > math.pi
    assert np.ptp(log[:, 13]) > 1.0 and np.ptp(log[:, 14]) > 1.0


@pytest.mark.sim
def test_noise_free_error_converges_to_zero_exponentially():
    """T_b = inf (pure bias integrator): the whole error (pose, velocity, bias) decays
    exponentially to the O(dt^2) floor of the 50 Hz discretization.
    """
    settings = dataclasses.replace(observer_settings(), T_b=(math.inf,) * 3)
    obs = PassiveObserver(settings)
    x = np.array([0.5, -0.3, 0.4, 0.0, 0.0, 0.0])
    obs.initialize(x[:3] + [0.2, -0.15, 0.3])          # wrong pose, nu_hat = b_hat = 0
    _, _, log = simulate(obs, 60.0, x, noise=False)
    norm = np.linalg.norm(log[:, 1:10], axis=1)
    t = log[:, 0]
    assert norm[0] > 0.3
    # ||x_tilde(t)|| <= c exp(-lambda t) + floor, lambda = 0.25 1/s: below the 0.5 design pole
    # because the quadratic damping of the turning vessel slows the bias poles.
    envelope = 3.0 * norm[0] * np.exp(-0.25 * t) + 2e-5
    assert np.all(norm <= envelope)
    assert np.all(norm[t > 60.0] < 2e-5)
    assert norm[np.searchsorted(t, 30.0)] < 1e-3 * norm[0]
    # Finite T_b leaks the bias estimate: steady y_tilde = b_hat / (T_b K2) instead of 0.
    tb = 1000.0
    obs = PassiveObserver(dataclasses.replace(settings, T_b=(tb,) * 3))
    obs.initialize(x[:3])
    _, _, log = simulate(obs, 120.0, x.copy(), noise=False)
    late = log[:, 0] > 80.0
    y_tilde = -np.mean(log[late, 1:4], axis=0)
    b_hat = np.mean(log[late, 7:10], axis=0) + B_WORLD
    expected = b_hat / (tb * np.asarray(settings.K2))
    assert np.all(np.abs(expected) > 2e-5)
    np.testing.assert_allclose(y_tilde, expected, rtol=0.15)


def test_heading_error_wraps_through_pi():
    obs = PassiveObserver(observer_settings())
    obs.initialize([0.0, 0.0, math.pi - 0.01])
    est = obs.step([0.0, 0.0, -math.pi + 0.01], np.zeros(3), DT)  # 0.02 rad away, not 6.26
    assert est.accepted and not est.rejected_jump
    assert -math.pi <= est.eta_hat[2] < math.pi
    assert abs(wrap(est.eta_hat[2] - (math.pi - 0.01))) < 0.02


# --- dropouts, staleness, implausible jumps ---------------------------------------------------


def test_dropout_dead_reckons_and_reports_stale():
    obs, x, t, _, rng = converged_observer()
    t_drop, x_drop = t, x.copy()
    x, t, log = simulate(obs, 2.0, x, t0=t, rng=rng,
                         dropout=lambda tt: tt <= t_drop + 1.0 + 1e-9)
    during = log[:, 0] <= t_drop + 1.0 + 1e-9
    after = ~during
    age = log[during, 11]
    np.testing.assert_allclose(age, np.arange(1, during.sum() + 1) * DT, atol=1e-9)
    stale = log[during, 10].astype(bool)
    np.testing.assert_array_equal(stale, age > 0.5)
    assert not stale[age <= 0.5].any() and stale[-1]
    # Dead reckoning: after 1 s without a pose the estimate is still within 1 cm / 0.3 deg
    # (the model, tau and the bias estimate carry it).
    end = log[during][-1]
    assert math.hypot(end[1], end[2]) < 0.01
    assert abs(end[3]) < math.radians(0.3)
    assert np.all(np.abs(end[4:6]) < 0.01)
    # Measurements return: accepted at once, fresh again.
    first = log[after][0]
    assert first[12] == 1.0 and first[10] == 0.0 and first[11] == 0.0
    assert not log[after, 10].any()
    # A frozen estimate would be off by the distance travelled, several times more.
    travelled = math.hypot(*(log[during][-1][13:15] - x_drop[:2]))
    assert travelled > 5.0 * math.hypot(end[1], end[2])


def test_implausible_jump_is_rejected_counted_and_treated_as_a_dropout():
    obs, x, t, _, rng = converged_observer(30.0)
    tau = excitation(t)
    x = plant_step(x, tau)
    now = obs.step(x[:3], tau, DT)
    twin = PassiveObserver(obs.settings)
    twin.initialize(now.eta_hat, now.nu_hat, now.b_hat)  # the same state
    x = plant_step(x, tau)
    glitch = x[:3] + [1.0, 0.0, 0.0]                    # a 1 m mocap glitch
    est = obs.step(glitch, tau, DT)
    ref = twin.step(None, tau, DT)
    assert est.rejected_jump and not est.accepted and obs.rejected == 1
    np.testing.assert_array_equal(est.eta_hat, ref.eta_hat)  # exactly a dropout
    np.testing.assert_array_equal(est.nu_hat, ref.nu_hat)
    np.testing.assert_array_equal(est.b_hat, ref.b_hat)
    # A heading glitch counts too; the next good pose is accepted.
    est = obs.step(x[:3] + [0.0, 0.0, 0.8], tau, DT)
    assert est.rejected_jump and obs.rejected == 2
    est = obs.step(x[:3], tau, DT)
    assert est.accepted and not est.rejected_jump and est.age == 0.0
    assert obs.reinitializations == 0
    # Random outliers, however long, are not consistent with each other: never re-initialize.
    for _ in range(150):
        est = obs.step(x[:3] + rng.uniform(1.0, 3.0, 3) * rng.choice([-1, 1], 3), tau, DT)
        assert est.rejected_jump
    assert obs.reinitializations == 0 and obs.rejected == 152
    assert est.stale


def test_consistent_offset_after_long_dropout_reinitializes():
    """During a 20 s dropout the vessel is pushed by a force the observer does not know; the
    dead-reckoned estimate drifts more than max_position_jump. The returning (good) poses are
    rejected for stale_after, then the estimate re-initializes from them.
    """
    obs, x, t, _, rng = converged_observer(30.0)
    push = np.array([1.5, -1.0, 0.0])
    for _ in range(int(20.0 / DT)):
        tau = excitation(t)
        x = plant_step(x, tau + push)
        t += DT
        est = obs.step(None, tau, DT)
    assert math.hypot(*pose_error(est, x)[:2]) > 0.5 and est.stale
    rejected, reinit_at = 0, None
    for k in range(100):
        tau = excitation(t)
        x = plant_step(x, tau)
        t += DT
        est = obs.step(x[:3] + rng.normal(0.0, NOISE), tau, DT)
        if est.reinitialized:
            assert reinit_at is None and est.accepted and not est.rejected_jump
            reinit_at = k
            assert math.hypot(*pose_error(est, x)[:2]) < 0.02
        elif reinit_at is None:
            assert est.rejected_jump
            rejected += 1
        else:
            assert est.accepted
    assert reinit_at is not None and obs.reinitializations == 1
    assert reinit_at * DT == pytest.approx(obs.settings.stale_after, abs=1.5 * DT)
    assert rejected == reinit_at and obs.rejected == rejected
    assert not est.stale and math.hypot(*pose_error(est, x)[:2]) < 0.02


# --- discretization ---------------------------------------------------------------------------


def kirchhoff_coriolis(nu, M):
    """C(nu) nu of the planar body from Kirchhoff's equations in vector form, not from the
    observer's matrix: with the body's linear velocity v = (u, v, 0), angular velocity
    w = (0, 0, r), and the momenta p = (m11 u, m22 v, 0), h = (0, 0, m33 r) (the gradients
    of T = 1/2 nu' M nu), the force is w x p and the moment v x p + w x h; surge, sway, yaw.
    """
    u, v, r = nu
    lin, ang = np.array([u, v, 0.0]), np.array([0.0, 0.0, r])
    p, h = np.array([M[0] * u, M[1] * v, 0.0]), np.array([0.0, 0.0, M[2] * r])
    force, moment = cross(ang, p), cross(lin, p) + cross(ang, h)
    return np.array([force[0], force[1], moment[2]])


def observer_ode(s: ObserverSettings):
    """The observer ODE written out with matrices (second implementation; Coriolis from
    Kirchhoff's equations): ``rhs(z, y, tau)``. The constant matrices are built once, not at
    each of the reference's evaluations."""
    Mo_inv, Do = np.linalg.inv(np.diag(s.M)), np.diag(s.D)
    Dn_coeff, K1, K2, K3 = np.asarray(s.Dn), np.diag(s.K1), np.diag(s.K2), np.diag(s.K3)
    T_b = np.asarray(s.T_b)

    def rhs(z, y, tau):
        eta, nu, b = z[:3], z[3:6], z[6:]
        Dn = np.diag(Dn_coeff * np.abs(nu))
        y_tilde = y - eta
        y_tilde[2] = wrap(y_tilde[2])
        R = rot(y[2])
        eta_dot = R @ nu + K1 @ y_tilde
        b_dot = -b / T_b + K2 @ y_tilde
        nu_dot = Mo_inv @ (-(Do + Dn) @ nu - kirchhoff_coriolis(nu, s.M) + R.T @ b
                           + tau + R.T @ K3 @ y_tilde)
        return np.concatenate([eta_dot, nu_dot, b_dot])
    return rhs


def heun_vs_rk4(dt, noise, seconds=30.0):
    """Max |observer - fine RK4 of observer_rhs| per state over a run at step dt."""
    s = observer_settings()
    observer_rhs = observer_ode(s)
    rng = np.random.default_rng(7)
    obs = PassiveObserver(s)
    x = np.array([0.0, 0.0, 0.2, 0.1, 0.0, 0.05])
    # Right pose (a wrong one would make the first interpolated interval a jump), wrong
    # velocity and bias.
    nu0, b0 = np.array([0.0, 0.05, 0.0]), np.array([-0.2, 0.1, 0.01])
    obs.initialize(x[:3], nu0, b0)
    z = np.concatenate([x[:3], nu0, b0])
    y_prev = z[:3].copy()
    ref_log, obs_log = [], []
    for k in range(int(round(seconds / dt))):
        tau = excitation(k * dt)
        x = plant_step(x, tau, dt=dt)
        y = x[:3] + (rng.normal(0.0, NOISE) if noise else 0.0)
        est = obs.step(y, tau, dt)
        # RK4 on dt / 2, tau held, y(t) the line from the previous sample to this one. Its
        # global error is O(h^4) with h = dt / 2 (~1e-8 relative at 50 Hz), three orders below
        # the Heun error O(dt^2) that the assertions resolve (steps of dt / 5 move these
        # errors by less than 1/500 of their size: the reference has converged).
        dy = y - y_prev
        dy[2] = wrap(dy[2])
        n = 2
        h = dt / n
        for i in range(n):
            a, m, b = y_prev + i / n * dy, y_prev + (i + 0.5) / n * dy, y_prev + (i + 1) / n * dy
            k1 = observer_rhs(z, a, tau)
            k2 = observer_rhs(z + 0.5 * h * k1, m, tau)
            k3 = observer_rhs(z + 0.5 * h * k2, m, tau)
            k4 = observer_rhs(z + h * k3, b, tau)
            z = z + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        z[2] = wrap(z[2])
        y_prev = y
        ref_log.append(z.copy())
        obs_log.append(np.concatenate([est.eta_hat, est.nu_hat, est.b_hat]))
    ref = np.array(ref_log)
    diff = np.array(obs_log) - ref
    diff[:, 2] = wrap(diff[:, 2])
    return np.abs(diff).max(axis=0), np.abs(ref).max(axis=0)


@pytest.mark.sim
def test_heun_discretization_matches_a_fine_rk4_reference():
    err, scale = heun_vs_rk4(DT, noise=True)
    assert np.all(err < 5e-3 * scale)        # within 0.5 % of each state's range at 50 Hz
    assert err[:2].max() < 1e-4              # 0.1 mm in position
    assert err[2] < 1e-4                     # [rad]
    # Second order: halving dt cuts the error about 4 times (noise-free, smooth y).
    e50, _ = heun_vs_rk4(DT, noise=False, seconds=15.0)
    e100, _ = heun_vs_rk4(DT / 2, noise=False, seconds=15.0)
    assert np.all(e50 / e100 > 3.0)


# --- API ----------------------------------------------------------------------------------


def test_first_measurement_initializes_and_none_before_it_is_stale():
    obs = PassiveObserver(observer_settings())
    assert not obs.initialized
    est = obs.step(None, np.zeros(3), DT)
    assert est.stale and est.age == math.inf and not est.accepted
    np.testing.assert_array_equal(est.eta_hat, 0.0)
    est = obs.step([1.0, 2.0, 4.0], np.zeros(3), DT)
    assert obs.initialized and est.accepted and not est.stale
    np.testing.assert_allclose(est.eta_hat, [1.0, 2.0, 4.0 - 2.0 * math.pi])


def test_settings_swap_keeps_the_state_and_validates_first():
    obs, x, t, _, _ = converged_observer(20.0)
    tau = excitation(t)
    now = obs.step(x[:3], tau, DT)
    old = obs.settings
    with pytest.raises(ValueError, match='K3'):
        obs.settings = dataclasses.replace(old, K3=(1.0, 2.0, 0.1))  # x != y
    assert obs.settings is old
    new = dataclasses.replace(old, K1=(0.5, 0.5, 0.5))
    obs.settings = new
    twin = PassiveObserver(new)
    twin.initialize(now.eta_hat, now.nu_hat, now.b_hat)
    obs.step(None, tau, DT), twin.step(None, tau, DT)    # both forget the previous pose
    y = x[:3] + [0.01, -0.01, 0.01]
    a, b = obs.step(y, tau, DT), twin.step(y, tau, DT)
    assert a.accepted
    np.testing.assert_array_equal(a.eta_hat, b.eta_hat)  # state kept, new gains in use
    np.testing.assert_array_equal(a.nu_hat, b.nu_hat)
    np.testing.assert_array_equal(a.b_hat, b.b_hat)


@pytest.mark.parametrize('bad', [
    dict(dt=0.0), dict(dt=-0.01), dict(dt=math.nan), dict(dt=math.inf),
    dict(y=[0.0, math.nan, 0.0]), dict(y=[0.0, 0.0]), dict(tau=[0.0, math.inf, 0.0]),
])
def test_bad_inputs_raise(bad):
    obs = PassiveObserver(observer_settings())
    obs.initialize([0.0, 0.0, 0.0])
    args = dict(y=[0.0, 0.0, 0.0], tau=[0.0, 0.0, 0.0], dt=DT) | bad
    with pytest.raises(ValueError):
        obs.step(args['y'], args['tau'], args['dt'])


@pytest.mark.parametrize('field, value', [
    ('K1', (1.0, 1.0)),
    ('K2', (1.0, 1.0, math.nan)),
    ('K3', (-1.0, -1.0, 0.1)),
    ('T_b', (0.0, 100.0, 100.0)),
    ('M', (9.51, 9.51, 0.0)),
    ('D', (math.inf, 1.96, 0.168)),
    ('Dn', ('a', 1.0, 1.0)),
    ('stale_after', 0.0),
    ('max_position_jump', -1.0),
    ('max_heading_jump', math.nan),
])
def test_validate_names_the_field(field, value):
    bad = dataclasses.replace(observer_settings(), **{field: value})
    with pytest.raises(ValueError, match=field):
        bad.validate()
    with pytest.raises(ValueError, match=field):
        PassiveObserver(bad)


def test_placed_gains_give_the_requested_error_poles():
    m, d = np.array([9.51, 9.51, 0.116]), np.array([1.96, 1.96, 0.168])
    poles = np.array([(1.5, 1.0, 0.5), (2.0, 1.0, 0.3), (1.0 + 2.5j, 1.0 - 2.5j, 0.6)])
    k1, k2, k3 = place_observer_gains(m, d, poles)
    for j in range(3):
        # M s^3 + (D + M K1) s^2 + (D K1 + K3) s + K2
        roots = np.roots([m[j], d[j] + m[j] * k1[j], d[j] * k1[j] + k3[j], k2[j]])
        np.testing.assert_allclose(np.sort_complex(roots), np.sort_complex(-poles[j]),
                                   rtol=1e-6)
    # The profile's gains give the error poles its comments state, by their own polynomial.
    s = observer_settings()
    stated = [(1.5, 1.0, 0.5), (1.5, 1.0, 0.5), (1.0 + 2.5j, 1.0 - 2.5j, 0.6)]
    for j in range(3):
        roots = np.roots([s.M[j], s.D[j] + s.M[j] * s.K1[j], s.D[j] * s.K1[j] + s.K3[j],
                          s.K2[j]])
        np.testing.assert_allclose(np.sort_complex(roots), np.sort_complex(-np.array(stated[j])),
                                   rtol=1e-6)
    with pytest.raises(ValueError, match='too slow'):
        place_observer_gains(m, d, (0.01, 0.01, 0.01))
    with pytest.raises(ValueError, match='conjugate'):
        place_observer_gains(m, d, (1.0 + 1j, 1.0, 1.0))


# --- invariants of the observer's model ----------------------------------------------------


def free_motion(M, dt, seconds, nu0=(0.3, -0.2, 0.6), eta0=(0.4, -0.7, 2.9)):
    """The observer dead-reckoning a body with no damping, no force and no injection."""
    s = dataclasses.replace(observer_settings(), M=tuple(M), D=(0.0,) * 3, Dn=(0.0,) * 3,
                            K1=(0.0,) * 3, K2=(0.0,) * 3, K3=(0.0,) * 3, T_b=(math.inf,) * 3)
    obs = PassiveObserver(s)
    obs.initialize(eta0, nu0, np.zeros(3))
    out = [obs.step(None, np.zeros(3), dt) for _ in range(int(round(seconds / dt)))]
    return [(e.eta_hat, e.nu_hat) for e in out]


def invariants(M, eta, nu):
    """Kinetic energy, world linear impulse (2), angular impulse about the world origin:
    all conserved by M nu_dot + C(nu) nu = 0, eta_dot = R(psi) nu (Kirchhoff)."""
    m11, m22, m33 = M
    u, v, r = nu
    x, y, psi = eta
    P = rot(psi)[:2, :2] @ np.array([m11 * u, m22 * v])
    return np.array([0.5 * (m11 * u * u + m22 * v * v + m33 * r * r), P[0], P[1],
                     m33 * r + x * P[1] - y * P[0]])


def test_model_conserves_energy_and_impulse_of_a_free_body():
    """With unequal surge and sway inertia (so the Munk moment (m22 - m11) u v is not zero)
    every term of C(nu) matters: a wrong sign or a missing term changes the energy or the
    impulses at first order. Budget: Heun's global error, (w dt)^2 (w t) / 6 of each
    quantity for the fastest rate w ~ 1 rad/s here: 3e-4 at dt = 10 ms over 20 s; and
    second order: 5 ms must cut the drift about 4 times."""
    M = (9.5, 14.0, 0.3)
    drift = {}
    for dt in (0.01, 0.005):
        run = free_motion(M, dt, 20.0)
        start = invariants(M, np.array([0.4, -0.7, 2.9]), np.array([0.3, -0.2, 0.6]))
        values = np.array([invariants(M, eta, nu) for eta, nu in run])
        # Each quantity against the size of its terms (L sums m33 r and x P_y - y P_x,
        # which grow with the distance travelled while their sum stays put).
        terms_L = max(M[2] * abs(nu[2]) + abs(eta[0] * start[2]) + abs(eta[1] * start[1])
                      for eta, nu in run)
        scale = np.array([start[0], np.hypot(*start[1:3]), np.hypot(*start[1:3]), terms_L])
        drift[dt] = np.abs(values - start).max(axis=0) / scale
    assert np.all(drift[0.01] < 3e-4), drift[0.01]
    assert np.all(drift[0.01] / np.maximum(drift[0.005], 1e-15) > 3.0), drift
    # The body really turned (the Munk moment changes r as u and v trade places).
    eta_end = run[-1][0]
    assert abs(eta_end[2] - 2.9) > 0.5


def test_reinitialization_velocity_is_the_finite_difference_of_the_far_poses():
    """Hand numbers (mutation-testing survivors: the span, the sign of R^T, age and count).

    From rest at the origin the observer sees a vessel 5 m away moving at a world velocity
    (0.2, -0.1) m/s and turning at 0.05 rad/s, poses every dt = 0.125 s (exact in binary). The
    first far pose starts the evidence; after stale_after = 0.5 s (4 more poses) eta_hat is
    the pose and nu_hat the finite difference over that 0.5 s, in the body frame. The body
    velocity is checked by invariants, not by a rotation written again: its length is the
    world speed and its direction plus the heading is the world course.
    """
    dt, v_world, r = 0.125, np.array([0.2, -0.1]), 0.05
    obs = PassiveObserver(dataclasses.replace(observer_settings(), stale_after=0.5))

    def pose(t):
        return (5.0 + v_world[0] * t, 3.0 + v_world[1] * t, 1.0 + r * t)

    for round_ in (1, 2):
        obs.initialize((0.0, 0.0, 0.0))
        for k in range(5):
            est = obs.step(pose(k * dt), (0.0, 0.0, 0.0), dt)
            assert est.reinitialized is (k == 4), k
        assert obs.reinitializations == round_
        np.testing.assert_allclose(est.eta_hat, pose(0.5), rtol=1e-12)
        u, v, r_hat = est.nu_hat
        assert math.hypot(u, v) == pytest.approx(math.hypot(*v_world), rel=1e-9)
        course = math.atan2(v_world[1], v_world[0])
        assert wrap(math.atan2(v, u) + est.eta_hat[2] - course) == pytest.approx(0.0, abs=1e-9)
        assert r_hat == pytest.approx(r, rel=1e-9)
        assert est.age == 0.0 and est.accepted and not est.stale


@pytest.mark.parametrize('axis', [0, 1])
def test_far_poses_inconsistent_along_one_axis_never_reinitialize(axis):
    # Outliers 5 m away that jump 6 m along one axis only (the other axis and the heading
    # agree) are not consistent with each other: each resets the evidence, none re-initializes.
    obs = PassiveObserver(dataclasses.replace(observer_settings(), stale_after=0.5))
    obs.initialize((0.0, 0.0, 0.0))
    for k in range(40):
        far = [4.0, 4.0, 0.0]
        far[axis] = 3.0 if k % 2 else -3.0
        est = obs.step(far, (0.0, 0.0, 0.0), 0.125)
        assert est.rejected_jump and not est.reinitialized
    assert obs.reinitializations == 0


def test_a_step_that_blows_the_state_up_resets_the_estimate_and_never_raises():
    # One pose stamped 20 s ahead once gave the observer dt = 20 s. Heun over 20 s
    # of this stiff model (yaw D_n / M = 61 1/s per rad/s) grows the state by ~1e4 per step:
    # the next dead-reckoning steps overflowed to inf and math.cos(inf) raised
    # ValueError('math domain error') in every callback after. Whatever dt the caller gives,
    # a state that is no longer finite is dropped (counted) and the next pose starts over.
    obs = PassiveObserver(observer_settings())
    obs.initialize([0.0, 0.0, 0.0])
    tau = [0.5, 0.0, 0.05]
    obs.step([0.001, 0.0, 0.0], tau, 20.0)
    estimates = [obs.step(None, tau, 0.1) for _ in range(10)]  # raised at the 4th before
    lost = [e for e in estimates if e.diverged]
    assert len(lost) == 1 and obs.divergences == 1 and not obs.initialized
    assert lost[0].stale and lost[0].age == math.inf
    for e in estimates:
        assert np.all(np.isfinite(e.eta_hat)) and np.all(np.isfinite(e.nu_hat))
    e = obs.step([1.0, 2.0, 0.5], tau, 0.02)  # the next pose initializes it again
    assert obs.initialized and e.eta_hat == pytest.approx([1.0, 2.0, 0.5])
