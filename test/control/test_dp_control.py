"""DP controller (pure algorithm tier): closed loops against a simulated CS Saucer.

The plant is the manual's 3-DOF model (CS Saucer manual, section 1.4), integrated here with RK4
independently of the controller's own model code:

    eta_dot = R(psi) nu,   M nu_dot + (C(nu) + D + D_n(nu)) nu = tau + R(psi)^T b
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support import saucer_plant
from support.saucer_plant import DT, NOISE, D, M, dp_settings, observer_settings, rot, wrap

from enbarr_core.control.dp_control import (
    DpController,
    DpControlSettings,
    DpOutput,
)
from enbarr_core.estimation.dp_observer import PassiveObserver
from enbarr_core.guidance.guidance import HoldPose, Reference

B_WORLD = np.array([0.4, -0.3, 0.03])                 # current-like world bias [N, N, N m]


def plant_step(x, tau, b=B_WORLD, dt=DT, quadratic=True):
    """RK4 over dt with tau and b held: x = [x, y, psi, u, v, r]."""
    return saucer_plant.step(x, tau, b, dt, quadratic)


def hold(eta) -> Reference:
    return HoldPose(eta).reference(eta, DT)


def settings(**changes) -> DpControlSettings:
    return dataclasses.replace(dp_settings(), **changes)


def run_truth(ctl, eta_d, seconds, x0, b=B_WORLD, dt=DT, quadratic=True):
    """Closed loop on the true state (b_hat = 0). Returns t, states, outputs."""
    ref = hold(eta_d)
    x = np.array(x0, dtype=float)
    ts, xs, outs = [], [], []
    for k in range(int(round(seconds / dt))):
        out = ctl.step(x[:3], x[3:], np.zeros(3), ref, dt)
        ts.append(k * dt)
        xs.append(x)
        outs.append(out)
        x = plant_step(x, out.tau, b, dt, quadratic)
    return np.array(ts), np.array(xs), outs


@pytest.mark.parametrize('quadratic', [True, False])
def test_the_plant_written_out_is_the_manuals_matrix_form(quadratic):
    """support.saucer_plant.rhs (per DOF, for speed) is its rhs_matrices (eqs. 1.2-1.6)."""
    rng = np.random.default_rng(4)
    for _ in range(50):
        x, tau, b = rng.normal(size=6) * [3, 3, 4, 1, 1, 1], rng.normal(size=3), rng.normal(size=3)
        np.testing.assert_allclose(saucer_plant.rhs(x, tau, b, quadratic),
                                   saucer_plant.rhs_matrices(x, tau, b, quadratic),
                                   rtol=1e-12, atol=1e-12)


# --- station keeping ---------------------------------------------------------------------


@pytest.mark.sim
def test_integral_removes_the_steady_error_of_a_current_like_bias():
    """Truth feedback, no bias feed-forward: only the integral can cancel the bias."""
    s = settings(bias_feedforward=False, integral_limit=(1.0, 1.0, 0.1))
    eta_d = np.array([0.0, 0.0, 0.3])
    t, xs, outs = run_truth(DpController(s), eta_d, 150.0, [0.2, -0.1, 0.0, 0, 0, 0])
    late = t > 120.0
    err = xs[late, :3] - eta_d
    assert np.abs(err).max() < 1e-3
    # The integral (body frame) carries the bias: tau = -I = -R^T b at rest.
    np.testing.assert_allclose(outs[-1].integral, rot(0.3).T @ B_WORLD, atol=1e-3)
    # Without the integral the error stays at b / Kp (world frame: R Kp^-1 R^T b).
    p_only = DpController(dataclasses.replace(s, Ki=(0.0, 0.0, 0.0)))
    t, xs, _ = run_truth(p_only, eta_d, 60.0, [0.2, -0.1, 0.0, 0, 0, 0])
    kp = np.asarray(s.Kp)
    R = rot(0.3)
    expected = R @ ((R.T @ B_WORLD) / kp)
    np.testing.assert_allclose(xs[-1, :3] - eta_d, expected, rtol=0.02, atol=1e-4)
    assert np.hypot(*expected[:2]) > 0.04


def station_keeping(seconds=120.0, seed=3, bias_feedforward=True):
    """Plant + noisy mocap + observer + controller holding the origin."""
    rng = np.random.default_rng(seed)
    obs = PassiveObserver(observer_settings())
    ctl = DpController(settings(bias_feedforward=bias_feedforward))
    x = np.array([0.3, -0.2, 0.4, 0.0, 0.0, 0.0])
    eta_d = np.array([0.0, 0.0, 0.0])
    ref = hold(eta_d)
    tau = np.zeros(3)
    log = []
    for k in range(int(round(seconds / DT))):
        est = obs.step(x[:3] + rng.normal(0.0, NOISE), tau, DT)
        out = ctl.step(est.eta_hat, est.nu_hat, est.b_hat, ref, DT)
        tau = out.tau
        log.append((k * DT, *x[:3], *tau, *out.integral))
        x = plant_step(x, tau)
    return np.array(log)


@pytest.mark.sim
def test_station_keeping_with_observer_and_noise():
    log = station_keeping()
    late = log[:, 0] > 60.0
    pos_rms = np.sqrt(np.mean(log[late, 1] ** 2 + log[late, 2] ** 2))
    psi_rms = np.sqrt(np.mean(wrap(log[late, 3]) ** 2))
    assert pos_rms < 0.005                     # [m], with 5 mm mocap noise
    assert psi_rms < math.radians(0.5)
    assert np.abs(log[late, 1:3]).max() < 0.015
    # The bias feed-forward does the work; the integral only trims.
    assert np.abs(log[late, 7:10]).mean(axis=0).max() < 0.1
    # The thrust stays within the Saucer's limits and does not chatter at the limits.
    assert np.all(np.abs(log[:, 4:7]) <= [2.0, 2.0, 0.3])
    assert np.all(np.abs(log[late, 4:7]) < [1.0, 1.0, 0.15])
    # Without the bias feed-forward the integral alone also holds the pose.
    log = station_keeping(150.0, bias_feedforward=False)
    late = log[:, 0] > 100.0
    assert np.sqrt(np.mean(log[late, 1] ** 2 + log[late, 2] ** 2)) < 0.008


def test_world_frame_integral_keeps_compensating_while_turning():
    """Integral (no bias feed-forward) converged at psi = 0; the heading setpoint then turns
    90 deg: the integral, stored in the world frame, still points against the world bias.
    """
    s = settings(bias_feedforward=False)
    ctl = DpController(s)
    _, xs, _ = run_truth(ctl, np.zeros(3), 120.0, np.zeros(6))
    np.testing.assert_allclose(ctl.integral, B_WORLD, atol=2e-3)  # z = R I = b (world)
    t, xs, outs = run_truth(ctl, np.array([0.0, 0.0, math.pi / 2]), 30.0, xs[-1])
    assert abs(wrap(xs[-1, 2] - math.pi / 2)) < 1e-2
    assert np.hypot(xs[:, 0], xs[:, 1]).max() < 0.03     # barely pushed off during the turn
    np.testing.assert_allclose(ctl.integral[:2], B_WORLD[:2], atol=0.03)
    np.testing.assert_allclose(outs[-1].integral[:2], rot(xs[-1, 2]).T[:2, :2] @ B_WORLD[:2],
                               atol=0.03)


# --- anti-windup -------------------------------------------------------------------------


def test_anti_windup_limits_overshoot_after_a_long_saturation():
    """A 4 m setpoint step in surge: tau_max saturates for ~10 s. A plain PID (same gains,
    integral of the error, output clipped) winds up and overshoots; ours does not (it only
    integrates once the output leaves the limit, like any PID).
    """
    s = settings(bias_feedforward=False)
    kp, ki, kd, tm = (np.asarray(v) for v in (s.Kp, s.Ki, s.Kd, s.tau_max))
    eta_d = np.array([4.0, 0.0, 0.0])
    b = np.zeros(3)
    t, xs, outs = run_truth(DpController(s), eta_d, 60.0, np.zeros(6), b=b)

    x = np.zeros(6)
    integral = np.zeros(3)
    plain = []
    for _ in range(len(t)):
        e = rot(x[2]).T @ np.r_[x[:2] - eta_d[:2], wrap(x[2] - eta_d[2])]
        integral += ki * e * DT
        tau = np.clip(-kp * e - integral - kd * x[3:], -tm, tm)
        plain.append(x)
        x = plant_step(x, tau, b)
    plain = np.array(plain)

    saturated = np.array([o.saturated[0] for o in outs])
    assert saturated[t < 5.0].all()                             # a long saturation
    overshoot_ours = xs[:, 0].max() - 4.0
    overshoot_plain = plain[:, 0].max() - 4.0
    assert overshoot_plain > 0.4
    assert overshoot_ours < 0.1 and overshoot_ours < 0.25 * overshoot_plain
    i_sat = np.array([o.integral[0] for o, sat in zip(outs, saturated) if sat])
    assert np.all(i_sat == 0.0)                 # nothing integrated while saturated
    assert np.all(np.abs([o.integral for o in outs]) <= np.asarray(s.integral_limit) + 1e-12)
    assert abs(xs[-1, 0] - 4.0) < 2e-3
    settle = t[np.nonzero(np.abs(xs[:, 0] - 4.0) > 0.02)[0][-1]]
    settle_plain = t[np.nonzero(np.abs(plain[:, 0] - 4.0) > 0.02)[0][-1]]
    assert settle < 30.0 and settle_plain > settle + 10.0


def test_conditional_integration_stops_at_the_limit():
    s = settings(Kp=(0.0, 0.0, 0.0), Kd=(0.0, 0.0, 0.0), Ki=(1.0, 1.0, 1.0),
                 integral_limit=(math.inf,) * 3, tau_max=(0.5, 0.5, 0.1))
    ctl = DpController(s)
    ref = hold(np.array([0.0, 0.0, -0.5]))
    for _ in range(200):    # e = [1, -1, 0.5]: I grows by Ki e dt until tau hits tau_max
        out = ctl.step([1.0, -1.0, 0.0], np.zeros(3), np.zeros(3), ref, DT)
        assert np.all(np.abs(out.tau) <= [0.5, 0.5, 0.1])
    np.testing.assert_allclose(out.error, [1.0, -1.0, 0.5])
    np.testing.assert_allclose(out.tau, [-0.5, 0.5, -0.1], rtol=1e-12)
    np.testing.assert_allclose(out.integral, [0.5, -0.5, 0.1], rtol=1e-12)  # not beyond
    ref = hold(np.array([0.0, 0.0, 0.5]))
    out = ctl.step([-1.0, 1.0, 0.0], np.zeros(3), np.zeros(3), ref, DT)     # unwinds at once
    np.testing.assert_allclose(out.integral, [0.48, -0.48, 0.09], rtol=1e-12)


# --- live gains and bumpless entry -----------------------------------------------------------


def _mid_transient(ctl):
    """Run a pose step to mid-transient; return the plant state and the last output."""
    ref = hold(np.array([0.15, -0.1, 0.1]))
    x = np.zeros(6)
    for _ in range(100):
        out = ctl.step(x[:3], x[3:], np.zeros(3), ref, DT)
        x = plant_step(x, out.tau)
    return x, out, ref


def test_gain_change_ramps_without_a_jump():
    s = settings(gain_ramp_time=1.0, Ki=(0.0, 0.0, 0.0), tau_max=(50.0, 50.0, 5.0))
    new = dataclasses.replace(s, Kp=(30.0, 30.0, 4.5), Kd=(25.0, 25.0, 1.2),
                              bias_feedforward=False)
    b_hat = np.array([0.2, 0.1, 0.01])
    eta, nu = np.array([0.1, -0.05, 0.1]), np.array([0.05, 0.03, -0.02])
    ref = hold(np.zeros(3))

    # Frozen inputs: the output moves only because of the settings change.
    hard = DpController(dataclasses.replace(s, gain_ramp_time=0.0))
    before = hard.step(eta, nu, b_hat, ref, DT).tau
    hard.settings = dataclasses.replace(new, gain_ramp_time=0.0)
    jump = hard.step(eta, nu, b_hat, ref, DT).tau - before
    assert np.abs(jump).max() > 1.0                        # what a hard switch does

    ctl = DpController(s)
    taus = [ctl.step(eta, nu, b_hat, ref, DT).tau]
    ctl.settings = new
    for _ in range(60):
        taus.append(ctl.step(eta, nu, b_hat, ref, DT).tau)
        assert ctl.ramping or len(taus) > 50
    steps = np.diff(taus, axis=0)
    # Linear blend over 1 s: 50 equal steps of jump dt / T, then nothing.
    np.testing.assert_allclose(steps[:50], np.tile(jump * DT / 1.0, (50, 1)), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(steps[50:], 0.0, atol=1e-12)
    np.testing.assert_allclose(taus[-1], before + jump, rtol=1e-12)
    assert not ctl.ramping

    # Closed loop, mid-transient: the switch adds at most |jump| dt / T per step to what the
    # loop itself moves, far below the hard switch.
    def closed(new_settings):
        ctl = DpController(s)
        ref = hold(np.array([0.15, -0.1, 0.1]))
        x = np.zeros(6)
        taus = []
        for k in range(200):
            if k == 100 and new_settings is not None:
                ctl.settings = new_settings
            out = ctl.step(x[:3], x[3:], b_hat, ref, DT)
            taus.append(out.tau)
            x = plant_step(x, out.tau)
        return np.abs(np.diff(taus, axis=0))[99:]

    own = closed(None).max(axis=0)
    ramped = closed(new).max(axis=0)
    instant = closed(dataclasses.replace(new, gain_ramp_time=0.0)).max(axis=0)
    assert np.all(ramped <= own + 2.0 * np.abs(jump) * DT / 1.0 + 1e-3)
    assert ramped[:2].max() < 0.3 * instant[:2].max()


def test_lowering_the_integral_limit_is_ramped_too():
    ctl = DpController(settings(bias_feedforward=False, gain_ramp_time=2.0))
    _, xs, outs = run_truth(ctl, np.zeros(3), 100.0, np.zeros(6))
    i0 = outs[-1].integral
    assert np.abs(i0[:2]).max() > 0.3
    ctl.settings = dataclasses.replace(ctl.settings, integral_limit=(0.05, 0.05, 0.01))
    x = xs[-1]
    ref = hold(np.zeros(3))
    prev = outs[-1].tau
    for k in range(int(3.0 / DT)):
        out = ctl.step(x[:3], x[3:], np.zeros(3), ref, DT)
        assert np.abs(out.tau - prev).max() < 0.05
        prev = out.tau
        x = plant_step(x, out.tau)
    assert np.all(np.abs(out.integral) <= [0.05, 0.05, 0.01])


def test_bumpless_reset_first_output_equals_tau_now():
    """Manual mode pushes with 1.2 N surge, 0.4 N sway, 0.05 N m; the operator switches to
    automatic holding the pose of that moment.
    """
    s = settings()
    ctl = DpController(s)
    x = np.zeros(6)
    tau_manual = np.array([1.2, 0.4, 0.05])
    for _ in range(int(8.0 / DT)):
        x = plant_step(x, tau_manual)
    assert np.hypot(x[3], x[4]) > 0.2
    ref = hold(x[:3])
    b_hat = np.array([0.1, -0.1, 0.0])
    ctl.reset(tau_manual)
    out = ctl.step(x[:3], x[3:], b_hat, ref, DT)
    np.testing.assert_allclose(out.tau, tau_manual, rtol=1e-12)    # bumpless
    hard = DpController(s).step(x[:3], x[3:], b_hat, ref, DT).tau  # what a plain switch gives
    jump = np.abs(hard - tau_manual).max()
    assert jump > 3.0
    taus = [out.tau]
    for _ in range(int(60.0 / DT)):
        x = plant_step(x, out.tau)
        out = ctl.step(x[:3], x[3:], b_hat, ref, DT)
        taus.append(out.tau)
    taus = np.array(taus)
    # The integral took over: no step afterwards (the excess beyond integral_limit bleeds off
    # over gain_ramp_time), and the vessel is brought back and held.
    assert np.abs(np.diff(taus, axis=0)).max() < 0.05 * jump
    assert np.all(np.abs(out.integral) <= np.asarray(s.integral_limit) + 1e-9)
    assert np.abs(x[:2] - ref.eta_d[:2]).max() < 0.02

    # Without tau_now the output jumps to what the PID asks at once.
    plain = DpController(s)
    plain.reset()
    first = plain.step(np.zeros(3), [0.1, 0.0, 0.0], np.zeros(3), hold(np.zeros(3)), DT)
    np.testing.assert_allclose(first.tau, [-0.1 * s.Kd[0], 0.0, 0.0], rtol=1e-12)
    # tau_now beyond tau_max is limited.
    ctl.reset([5.0, -5.0, 1.0])
    out = ctl.step(x[:3], x[3:], b_hat, ref, DT)
    np.testing.assert_allclose(out.tau, s.tau_max * np.array([1, -1, 1]))


# --- reference handling -------------------------------------------------------------------


def test_position_mask_false_removes_the_pose_error():
    ctl = DpController(settings(Ki=(0.0, 0.0, 0.0)))
    eta = np.array([5.0, -3.0, 0.4])            # far from eta_d in x and y
    nu_hat = np.array([0.15, 0.02, 0.01])
    nu_d = np.array([0.2, 0.0, 0.0])
    ref = Reference(np.array([0.0, 0.0, 0.5]), nu_d, np.zeros(3), (False, False, True))
    out = ctl.step(eta, nu_hat, np.zeros(3), ref, DT)
    np.testing.assert_allclose(out.error, [0.0, 0.0, -0.1])
    s = ctl.settings
    expected = out.tau_ff - np.asarray(s.Kp) * out.error - np.asarray(s.Kd) * (nu_hat - nu_d)
    np.testing.assert_allclose(out.tau, np.clip(expected, -np.asarray(s.tau_max), s.tau_max))
    assert not out.saturated[:2].any()
    full = DpController(settings(Ki=(0.0, 0.0, 0.0))).step(
        eta, nu_hat, np.zeros(3), dataclasses.replace(ref, position_mask=(True, True, True)),
        DT)
    assert full.saturated[:2].all()             # 5 m of error saturates X and Y


def test_nan_is_no_position_reference_where_the_mask_is_false():
    """As ``guidance/reference`` carries it: NaN where a pose component is not fed back."""
    eta, nu_hat, nu_d = np.array([5.0, -3.0, 0.4]), np.array([0.15, 0.02, 0.01]), np.zeros(3)
    closest = Reference(np.array([0.0, 0.0, 0.5]), nu_d, np.zeros(3), (False, False, True))
    nan = dataclasses.replace(closest, eta_d=np.array([np.nan, np.nan, 0.5]))
    a = DpController(settings()).step(eta, nu_hat, np.zeros(3), closest, DT)
    b = DpController(settings()).step(eta, nu_hat, np.zeros(3), nan, DT)
    np.testing.assert_array_equal(b.tau, a.tau)
    assert np.isfinite(b.tau).all()
    fed_back = dataclasses.replace(nan, position_mask=(True, False, True))
    with pytest.raises(ValueError, match=r'^ref\.eta_d\[0\]: must be finite'):
        DpController(settings()).step(eta, nu_hat, np.zeros(3), fed_back, DT)


def test_feed_forward_terms():
    s = settings(bias_feedforward=True)
    ctl = DpController(s)
    nu_d = np.array([0.2, -0.1, 0.05])
    nu_d_dot = np.array([0.01, 0.02, -0.01])
    psi = 0.7
    b_hat = np.array([0.3, -0.2, 0.01])
    ref = Reference(np.array([0.0, 0.0, psi]), nu_d, nu_d_dot)
    out = ctl.step([0.0, 0.0, psi], nu_d, b_hat, ref, DT)
    u, v, r = nu_d
    C = np.array([[0.0, -9.51 * r, 0.0], [9.51 * r, 0.0, 0.0], [0.0, 0.0, 0.0]])  # eq. 1.3
    expected = M @ nu_d_dot + (D + 7.095 * np.diag(np.abs(nu_d)) + C) @ nu_d - rot(psi).T @ b_hat
    np.testing.assert_allclose(out.tau_ff, expected, rtol=1e-12)
    np.testing.assert_allclose(out.tau, expected, rtol=1e-12)  # zero error: feed-forward only


# --- second formulation: python-control ----------------------------------------------------


@pytest.mark.sim
@pytest.mark.parametrize('dof', range(3))
def test_linearized_closed_loop_per_dof_matches_python_control(dof):
    """Per DOF, linear plant 1 / (M s^2 + D s) with the PID (derivative on nu):

        x / x_d = (Kp s + Ki) / (M s^3 + (D + Kd) s^2 + Kp s + Ki)

    python-control gives poles (all in the left half plane) and the step response; the
    simulated loop (controller at 100 Hz, linear plant: no D_n, no limits) follows it.
    """
    import control  # python-control imports scipy.signal, slow: only this test needs it

    s = settings(tau_max=(math.inf,) * 3, integral_limit=(math.inf,) * 3,
                 Dn=(0.0, 0.0, 0.0), bias_feedforward=False)
    m, d = M[dof, dof], D[dof, dof]
    kp, ki, kd = s.Kp[dof], s.Ki[dof], s.Kd[dof]
    P = control.tf([1.0], [m, d, 0.0])
    inner = control.feedback(P, control.tf([kd, 0.0], [1.0]))      # Kd on the velocity
    T = control.feedback(control.tf([kp, ki], [1.0, 0.0]) * inner, 1)
    poles = control.poles(T)
    np.testing.assert_allclose(np.sort_complex(poles),
                               np.sort_complex(np.roots([m, d + kd, kp, ki])), rtol=1e-6)
    assert np.all(poles.real < 0.0)
    assert control.dcgain(T) == pytest.approx(1.0)

    step = 0.1
    eta_d = np.zeros(3)
    eta_d[dof] = step
    dt = 0.01
    t, xs, _ = run_truth(DpController(s), eta_d, 40.0, np.zeros(6), b=np.zeros(3), dt=dt,
                         quadratic=False)
    resp = control.step_response(T, T=t)
    np.testing.assert_allclose(xs[:, dof], step * np.squeeze(resp.outputs), atol=0.02 * step)
    assert xs[-1, dof] == pytest.approx(step, abs=5e-3 * step)     # steady state 1


# --- validation ----------------------------------------------------------------------------


@pytest.mark.parametrize('field, value', [
    ('Kp', (1.0, 1.0)),
    ('Ki', (1.0, 1.0, math.nan)),
    ('Kd', (-1.0, 1.0, 1.0)),
    ('integral_limit', (-1.0, 1.0, 1.0)),
    ('tau_max', (2.0, 2.0, 0.0)),
    ('M', (9.51, 0.0, 0.116)),
    ('D', (math.inf, 1.96, 0.168)),
    ('Dn', ('a', 1.0, 1.0)),
    ('gain_ramp_time', -1.0),
    ('bias_feedforward', 'yes'),
])
def test_validate_names_the_field(field, value):
    bad = settings(**{field: value})
    with pytest.raises(ValueError, match=field):
        bad.validate()
    ctl = DpController(settings())
    old = ctl.settings
    with pytest.raises(ValueError, match=field):
        ctl.settings = bad
    assert ctl.settings is old


@pytest.mark.parametrize('bad', [
    dict(dt=0.0), dict(dt=-1.0), dict(dt=math.nan),
    dict(eta=[0.0, math.nan, 0.0]), dict(nu=[0.0, 0.0]), dict(b=[math.inf, 0.0, 0.0]),
])
def test_bad_inputs_raise(bad):
    ctl = DpController(settings())
    args = dict(eta=np.zeros(3), nu=np.zeros(3), b=np.zeros(3), dt=DT) | bad
    with pytest.raises(ValueError):
        ctl.step(args['eta'], args['nu'], args['b'], hold(np.zeros(3)), args['dt'])


def test_output_arrays_are_fresh():
    ctl = DpController(settings())
    a = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), hold(np.ones(3)), DT)
    b = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), hold(np.ones(3)), DT)
    assert isinstance(a, DpOutput) and a.tau is not b.tau
    assert a.saturated.dtype == np.bool_ and a.error.shape == (3,)


def test_masked_integral_bleeds_off_after_bumpless_entry():
    """Entering line-of-sight guidance bumplessly leaves a force in the integral; a DOF
    tracked by velocity only (mask False) cannot integrate it back, so it must bleed off
    over gain_ramp_time instead of biasing the whole leg.
    """
    ctrl = DpController(dp_settings())
    ref = Reference(eta_d=np.zeros(3), nu_d=np.zeros(3), nu_d_dot=np.zeros(3),
                    position_mask=(False, False, True))
    ctrl.reset(tau_now=(1.0, -0.5, 0.0))
    first = ctrl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.02)
    np.testing.assert_allclose(first.tau, (1.0, -0.5, 0.0), atol=1e-12)  # still bumpless
    for _ in range(int(5.0 / 0.02)):  # 5 gain_ramp_times
        out = ctrl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.02)
    assert np.all(np.abs(ctrl.integral[:2]) < 0.01)
    assert np.all(np.abs(out.tau[:2]) < 0.01)


def test_without_ki_the_bumpless_integral_bleeds_off_over_the_ramp_time():
    """Ki = 0 in a DOF (a PD loop): what reset(tau_now) put in I would stay a constant force
    for good, since nothing integrates it. It decays as e^(-t / gain_ramp_time) instead,
    checked against that closed form at one and three ramp times; a DOF with Ki keeps its
    integral (it integrates the error as before).
    """
    s = settings(Ki=(0.0, 0.0, s_ki := dp_settings().Ki[2]), gain_ramp_time=1.0)
    assert s_ki > 0.0
    ctl = DpController(s)
    ref = hold(np.zeros(3))
    ctl.reset((0.3, -0.2, 0.05))
    first = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, DT)
    np.testing.assert_allclose(first.tau, (0.3, -0.2, 0.05), atol=1e-12)  # still bumpless
    i0 = first.integral.copy()  # (-0.3, 0.2, -0.05): at zero error tau = -I
    for k in range(1, int(3.0 / DT) + 1):
        out = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, DT)
        if k in (int(1.0 / DT), int(3.0 / DT)):
            np.testing.assert_allclose(out.integral[:2], i0[:2] * math.exp(-k * DT / 1.0),
                                       rtol=1e-9)
    assert out.integral[2] == pytest.approx(i0[2], abs=1e-12)  # zero error: Ki e dt = 0


# --- gaps found by the mutation run (docs/testing.md) -------------------------------------


def test_plain_reset_clears_what_a_bumpless_entry_allowed():
    """After a bumpless entry the integral may exceed integral_limit while it bleeds off; a plain
    reset() ends that: the next step integrates from zero and clamps at integral_limit
    exactly. Hand numbers: Ki e dt = 10 * e * 0.1 = e, larger than each limit here.
    """
    s = settings(Ki=(10.0, 10.0, 10.0), integral_limit=(0.2, 0.2, 0.02),
                 tau_max=(math.inf, math.inf, math.inf))
    ctl = DpController(s)
    ref = hold(np.zeros(3))
    ctl.reset([30.0, -30.0, 3.0])       # far beyond the limits: a large allowance
    ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.1)
    ctl.reset()
    eta = np.array([1.0, -1.0, 0.5])    # e = R(0.5)^T [1, -1] = [0.398, -1.357], e3 = 0.5
    out = ctl.step(eta, np.zeros(3), np.zeros(3), ref, 0.1)
    np.testing.assert_allclose(out.integral, [0.2, -0.2, 0.02], rtol=1e-12)


def test_reset_names_a_bad_tau_now():
    with pytest.raises(ValueError, match=r'^tau_now: expected 3 values'):
        DpController(settings()).reset([1.0, 2.0])


@pytest.mark.parametrize('mask', [(False, True, True), (True, False, True), (True, True, False)])
def test_one_masked_component_may_be_nan(mask):
    """Any single component can be the one without a reference: NaN there is ignored and the
    output equals that of any finite value there."""
    eta, nu_hat = np.array([5.0, -3.0, 0.4]), np.array([0.15, 0.02, 0.01])
    eta_d = np.array([1.0, 2.0, 0.5])
    j = mask.index(False)
    with_nan = eta_d.copy()
    with_nan[j] = np.nan
    other = eta_d.copy()
    other[j] = 100.0
    taus = [DpController(settings()).step(eta, nu_hat, np.zeros(3),
                                          Reference(e, np.zeros(3), np.zeros(3), mask), DT).tau
            for e in (with_nan, other)]
    assert np.isfinite(taus[0]).all()
    np.testing.assert_array_equal(taus[0], taus[1])
    with pytest.raises(ValueError, match=r'^ref\.eta_d: expected 3 values'):
        DpController(settings()).step(eta, nu_hat, np.zeros(3),
                                      Reference(eta_d[:2], np.zeros(3), np.zeros(3), mask), DT)


@pytest.mark.parametrize('bad, match', [
    (dict(dt=0.0), r'^dt must be finite and > 0, got 0.0$'),
    (dict(eta=[0.0, math.nan, 0.0]), r'^eta_hat\[1\]: must be finite'),
    (dict(nu=[0.0, 0.0]), r'^nu_hat: expected 3 values'),
    (dict(b=[math.inf, 0.0, 0.0]), r'^b_hat\[0\]: must be finite'),
])
def test_bad_inputs_are_named(bad, match):
    ctl = DpController(settings())
    args = dict(eta=np.zeros(3), nu=np.zeros(3), b=np.zeros(3), dt=DT) | bad
    with pytest.raises(ValueError, match=match):
        ctl.step(args['eta'], args['nu'], args['b'], hold(np.zeros(3)), args['dt'])


def test_coriolis_feed_forward_by_hand_with_unequal_masses():
    """C(nu_d) nu_d = [-M22 v r, M11 u r, (M22 - M11) u v]; the Saucer's M11 = M22 hides the
    yaw term, so M = (10, 20, 1) here, no damping: [-0.4, 0.5, 1.0] for nu_d = (0.5, 0.2, 0.1).
    """
    s = settings(M=(10.0, 20.0, 1.0), D=(0.0, 0.0, 0.0), Dn=(0.0, 0.0, 0.0),
                 bias_feedforward=False)
    ref = Reference(np.zeros(3), np.array([0.5, 0.2, 0.1]), np.zeros(3))
    out = DpController(s).step(np.zeros(3), [0.5, 0.2, 0.1], np.zeros(3), ref, DT)
    np.testing.assert_allclose(out.tau_ff, [-0.4, 0.5, 1.0], rtol=1e-12)


def test_bumpless_excess_bleeds_off_with_time_constant_gain_ramp_time():
    """tau_now = 5 N with integral_limit 1 N: the excess integral decays as exp(-t / T) with
    T = gain_ramp_time = 2 s (not 1 s, where dt / T and dt * T agree): after 1 s at zero
    error the output is 5 exp(-0.5) N exactly (the clamp follows the allowance)."""
    s = settings(Ki=(0.0, 0.0, 0.0), integral_limit=(1.0, 1.0, 0.1),
                 tau_max=(math.inf, math.inf, math.inf), gain_ramp_time=2.0)
    ctl = DpController(s)
    ref = hold(np.zeros(3))
    ctl.reset([5.0, 0.0, 0.0])
    out = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.1)
    assert out.tau[0] == pytest.approx(5.0, rel=1e-12)
    for _ in range(10):
        out = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.1)
    assert out.tau[0] == pytest.approx(5.0 * math.exp(-0.5), rel=1e-12)


def test_masked_integral_decays_with_time_constant_gain_ramp_time():
    """The bleed of a masked DOF against its closed form I_n = I_0 e^(-n dt / T), with T = 2 s
    (at T = 1 s the mutants e^(-dt T) and e^(-dt / T) agree; cutting it at once, decay 0, also
    passed the 5 T check above). The entry integral is inside integral_limit, so no clamp acts.
    """
    T, dt, n = 2.0, 0.02, 50
    ctrl = DpController(settings(gain_ramp_time=T))
    ref = Reference(eta_d=np.zeros(3), nu_d=np.zeros(3), nu_d_dot=np.zeros(3),
                    position_mask=(False, False, True))
    ctrl.reset(tau_now=(0.1, -0.05, 0.0))
    first = ctrl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, dt)
    np.testing.assert_allclose(first.integral, (-0.1, 0.05, 0.0), atol=1e-15)  # tau = -I
    for _ in range(n):
        ctrl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, dt)
    np.testing.assert_allclose(ctrl.integral[:2], np.array([-0.1, 0.05]) * math.exp(-n * dt / T),
                               rtol=1e-12)


def test_a_bumpless_entry_inside_the_limits_allows_no_excess():
    """Only an entry integral beyond integral_limit gets a bleeding allowance; one inside it
    leaves the clamp at integral_limit from the next step on (hand numbers as in the plain
    reset test above: Ki e dt is larger than each limit).
    """
    s = settings(Ki=(10.0, 10.0, 10.0), integral_limit=(0.2, 0.2, 0.02),
                 tau_max=(math.inf, math.inf, math.inf))
    ctl = DpController(s)
    ref = hold(np.zeros(3))
    ctl.reset([0.05, -0.05, 0.005])     # entry integral -tau_now: inside every limit
    ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, 0.1)
    out = ctl.step(np.array([1.0, -1.0, 0.5]), np.zeros(3), np.zeros(3), ref, 0.1)
    np.testing.assert_allclose(out.integral, [0.2, -0.2, 0.02], rtol=1e-12)


@pytest.mark.parametrize('on', [True, False])
def test_bias_feedforward_is_minus_r_transpose_b_hat_only_when_on(on):
    """At rest on the setpoint with heading pi/2, b_hat = (0.4, -0.3, 0.03) world: the
    feed-forward is -R^T b_hat = -(b_y, -b_x, b_n) = (0.3, 0.4, -0.03) when on, and zero when
    off (the station-keeping tests only showed that off still converges).
    """
    ctl = DpController(settings(bias_feedforward=on))
    eta = np.array([1.0, 2.0, math.pi / 2])
    out = ctl.step(eta, np.zeros(3), np.array([0.4, -0.3, 0.03]), hold(eta), DT)
    want = np.array([0.3, 0.4, -0.03]) if on else np.zeros(3)
    np.testing.assert_allclose(out.tau_ff, want, atol=1e-15)


def test_gain_ramp_with_a_period_that_does_not_divide_it_ends_exactly_on_the_new_gains():
    """Frozen inputs, Ki = 0: tau is linear in every blended setting, so after k steps of
    dt = 0.3 s into a 2 s ramp it is before + min(1, k dt / T) (after - before): 0.15, 0.3,
    ... 0.9 of the change, then exactly the new gains at 2.1 s (no overshoot past them).
    """
    s = settings(gain_ramp_time=2.0, Ki=(0.0, 0.0, 0.0), tau_max=(50.0, 50.0, 5.0))
    new = dataclasses.replace(s, Kp=(30.0, 30.0, 4.5), Kd=(25.0, 25.0, 1.2))
    eta, nu = np.array([0.1, -0.05, 0.1]), np.array([0.05, 0.03, -0.02])
    b_hat, ref, dt = np.array([0.2, 0.1, 0.01]), hold(np.zeros(3)), 0.3
    before = DpController(s).step(eta, nu, b_hat, ref, dt).tau
    after = DpController(new).step(eta, nu, b_hat, ref, dt).tau
    ctl = DpController(s)
    ctl.step(eta, nu, b_hat, ref, dt)
    ctl.settings = new
    for k in range(1, 10):
        tau = ctl.step(eta, nu, b_hat, ref, dt).tau
        np.testing.assert_allclose(tau, before + min(1.0, k * dt / 2.0) * (after - before),
                                   rtol=1e-12, atol=1e-12, err_msg=f'step {k}')
    assert not ctl.ramping


def test_only_the_dofs_without_a_pose_error_bleed_after_a_bumpless_entry():
    """Mask (True, False, False): x is held by position, y and psi are not. What the entry put
    in the integral bleeds off as e^(-t / gain_ramp_time) in y and psi only; x keeps its own
    (zero error: Ki e dt adds nothing). Heading 0, so world and body axes agree.
    """
    ctl = DpController(settings(gain_ramp_time=1.0))
    ref = Reference(eta_d=np.zeros(3), nu_d=np.zeros(3), nu_d_dot=np.zeros(3),
                    position_mask=(True, False, False))
    ctl.reset(tau_now=(0.4, -0.3, 0.05))
    i0 = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, DT).integral.copy()
    n = int(2.0 / DT)
    for _ in range(n):
        out = ctl.step(np.zeros(3), np.zeros(3), np.zeros(3), ref, DT)
    assert out.integral[0] == pytest.approx(i0[0], abs=1e-12)
    # The bleed acts on the stored integral after a step's output is formed: the n-th output
    # after the entry step carries n - 1 decays.
    np.testing.assert_allclose(out.integral[1:], i0[1:] * math.exp(-(n - 1) * DT / 1.0),
                               rtol=1e-9)
