"""Velocity controller (pure algorithm tier): closed loops against simulated plants."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from enbarr_core.control.velocity_control import (
    ControlOutput,
    VelocityController,
    VelocityControlSettings,
    VelocityReference,
)

DT = 0.01  # [s]
M = np.array([12.0, 15.0, 18.0, 0.3, 0.4, 0.35])   # plant inertia [kg, kg m^2]
D = np.array([6.0, 8.0, 10.0, 0.5, 0.6, 0.4])       # plant linear damping


def six(x: float) -> tuple[float, ...]:
    return (float(x),) * 6


def settings(**changes) -> VelocityControlSettings:
    base = VelocityControlSettings(
        kp=tuple(3.0 * M), ki=tuple(2.0 * M), kd=six(0.0),
        integral_limit=six(100.0), tau_max=six(1e3),
        d_lin=six(0.0), d_quad=six(0.0), inertia=six(0.0),
    )
    return dataclasses.replace(base, **changes)


class LinearPlant:
    """m v_dot + d v = tau per DOF, exact zero-order-hold discretization."""

    def __init__(self, m=M, d=D, dt=DT, v0=None):
        self.a = np.exp(-np.asarray(d) * dt / np.asarray(m))
        self.b = (1.0 - self.a) / np.asarray(d)
        self.v = np.zeros(len(self.a)) if v0 is None else np.array(v0, dtype=float)

    def step(self, tau):
        self.v = self.a * self.v + self.b * np.asarray(tau)  # v_k+1 = a v_k + b tau_k
        return self.v


def quadratic_plant_step(v, tau, m, d_lin, d_quad, dt, substeps=20):
    """M v_dot = tau - d_lin v - d_quad |v| v, RK4 with the input held over dt."""
    def f(x):
        return (tau - d_lin * x - d_quad * np.abs(x) * x) / m
    h = dt / substeps
    for _ in range(substeps):
        k1 = f(v)
        k2 = f(v + 0.5 * h * k1)
        k3 = f(v + 0.5 * h * k2)
        k4 = f(v + h * k3)
        v = v + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return v


# --- closed loop: integral removes the steady-state error --------------------------------


def test_step_reaches_setpoint_with_zero_steady_state_error():
    nu_d = np.array([0.5, -0.3, 0.2, 0.1, -0.2, 0.4])
    # Feed-forward model 40 % wrong, so the integral has to make up the difference.
    ctrl = VelocityController(settings(d_lin=tuple(0.6 * D), kd=tuple(0.05 * M)))
    plant = LinearPlant()
    for _ in range(int(20.0 / DT)):
        out = ctrl.step(nu_d, plant.v, DT)
        plant.step(out.tau)
    np.testing.assert_allclose(plant.v, nu_d, atol=1e-6)
    # The integral carries exactly the missing damping force D nu_d - 0.6 D nu_d.
    np.testing.assert_allclose(out.integral, 0.4 * D * nu_d, atol=1e-5)
    assert not out.saturated.any()

    # Without the integral the same loop keeps an error: v = (ff + kp) nu_d / (d + kp).
    p_only = VelocityController(settings(d_lin=tuple(0.6 * D), ki=six(0.0)))
    plant = LinearPlant()
    for _ in range(int(20.0 / DT)):
        plant.step(p_only.step(nu_d, plant.v, DT).tau)
    kp = 3.0 * M
    np.testing.assert_allclose(plant.v, (0.6 * D + kp) * nu_d / (D + kp), rtol=1e-6)
    assert np.all(np.abs(plant.v - nu_d) > 1e-3)


# --- feed-forward --------------------------------------------------------------------------


def test_feed_forward_alone_with_exact_model_gives_exact_steady_state():
    d_quad = np.array([20.0, 30.0, 35.0, 1.0, 1.2, 0.8])
    ctrl = VelocityController(settings(
        kp=six(0.0), ki=six(0.0), kd=six(0.0),
        d_lin=tuple(D), d_quad=tuple(d_quad), inertia=tuple(M),
        coriolis=False))  # the plant is six decoupled DOFs: no C(nu) nu to feed forward
    nu_d = np.array([0.8, -0.4, 0.3, 0.2, -0.3, 0.5])
    v, dt = np.zeros(6), 0.05
    for _ in range(int(60.0 / dt)):
        out = ctrl.step(nu_d, v, dt)
        v = quadratic_plant_step(v, out.tau, M, D, d_quad, dt, substeps=5)
    np.testing.assert_allclose(out.tau_ff, D * nu_d + d_quad * np.abs(nu_d) * nu_d, rtol=1e-12)
    np.testing.assert_allclose(out.tau, out.tau_ff)
    np.testing.assert_allclose(v, nu_d, rtol=1e-9, atol=1e-12)


def test_acceleration_feed_forward_tracks_a_ramp():
    accel = np.array([0.05, -0.04, 0.03, 0.02, -0.02, 0.03])
    exact = settings(kp=six(0.0), ki=six(0.0), d_lin=tuple(D), inertia=tuple(M),
                     coriolis=False)  # decoupled plant: no C(nu) nu
    no_inertia = dataclasses.replace(exact, inertia=six(0.0))
    errors = []
    for s in (exact, no_inertia):
        ctrl, plant = VelocityController(s), LinearPlant()
        for k in range(int(30.0 / DT)):
            # Mid-interval setpoint: the held force matches the exact one to O(dt^2).
            plant.step(ctrl.step(accel * (k + 0.5) * DT, plant.v, DT, nu_d_dot=accel).tau)
        errors.append(np.abs(plant.v - accel * (k + 1) * DT))
    np.testing.assert_allclose(errors[0], 0.0, atol=1e-6)  # M nu_d_dot + D nu_d: no lag
    np.testing.assert_allclose(errors[1], M * np.abs(accel) / D, rtol=1e-3)  # lag M a / D


# --- anti-windup ---------------------------------------------------------------------------


def _windup_scenario(controller, seconds=40.0):
    """Surge only: 4 m/s asked for 20 s (tau_max allows 2 m/s), then 1 m/s."""
    m, d = 10.0, 5.0
    a, b = math.exp(-d * DT / m), (1.0 - math.exp(-d * DT / m)) / d
    v, t, vs, integrals = 0.0, [], [], []
    for k in range(int(seconds / DT)):
        nu_d = 4.0 if k * DT < 20.0 else 1.0
        tau, integral = controller(nu_d, v)
        t.append(k * DT)
        vs.append(v)
        integrals.append(integral)
        v = a * v + b * tau
    return np.array(t), np.array(vs), np.array(integrals)


def _settling_after(t, v, t0, target, band):
    after = t >= t0
    outside = np.nonzero(np.abs(v[after] - target) > band)[0]
    return (t[after][outside[-1]] - t0) if outside.size else 0.0


def test_anti_windup_recovers_quickly_compared_with_a_plain_integrator():
    kp, ki, tau_max, i_lim, d_ff = 20.0, 10.0, 10.0, 8.0, 4.0
    ctrl = VelocityController(VelocityControlSettings(
        kp=six(kp), ki=six(ki), kd=six(0.0), integral_limit=six(i_lim), tau_max=six(tau_max),
        d_lin=six(d_ff), d_quad=six(0.0), inertia=six(0.0)))

    def ours(nu_d, v):
        out = ctrl.step(six(nu_d), six(v), DT)
        return out.tau[0], out.integral[0]

    plain_integral = 0.0

    def plain(nu_d, v):  # textbook PI + same feed-forward, integral of ki e unbounded
        nonlocal plain_integral
        e = nu_d - v
        plain_integral += ki * e * DT
        return float(np.clip(d_ff * nu_d + kp * e + plain_integral, -tau_max, tau_max)), \
            plain_integral

    t, v_ours, i_ours = _windup_scenario(ours)
    _, v_plain, i_plain = _windup_scenario(plain)
    assert v_ours[t < 20.0][-1] == pytest.approx(2.0, abs=1e-3)  # saturated: 10 N / 5
    assert np.all(np.abs(i_ours) <= i_lim)
    assert np.max(np.abs(i_plain)) > 300.0                       # the plain one winds up
    settle_ours = _settling_after(t, v_ours, 20.0, 1.0, 0.05)
    settle_plain = _settling_after(t, v_plain, 20.0, 1.0, 0.05)
    assert settle_ours < 5.0
    assert settle_plain > 15.0
    assert np.min(v_ours[t >= 20.0]) > 0.85                     # undershoot < 15 %
    assert v_ours[-1] == pytest.approx(1.0, abs=1e-3)

    # Each mechanism alone: conditional integration without any clamp also recovers.
    ctrl.settings = dataclasses.replace(ctrl.settings, integral_limit=six(math.inf))
    ctrl.reset()
    t, v_ci, i_ci = _windup_scenario(ours)
    assert np.max(np.abs(i_ci)) <= tau_max
    assert _settling_after(t, v_ci, 20.0, 1.0, 0.05) < 5.0


def test_integral_clamp_and_conditional_integration():
    # The model lacks 10 N of drag at 1 m/s but the integral may only give 3 N: it sits on the
    # clamp and a steady-state error remains (the clamp wins over the error).
    ctrl = VelocityController(settings(integral_limit=six(3.0), kp=six(5.0), ki=six(5.0)))
    plant = LinearPlant(m=six(10.0), d=six(10.0))
    for _ in range(int(30.0 / DT)):
        out = ctrl.step(six(1.0), plant.v, DT)
        assert np.all(np.abs(out.integral) <= 3.0)
        plant.step(out.tau)
    np.testing.assert_allclose(out.integral, 3.0)
    np.testing.assert_allclose(plant.v, (5.0 + 3.0) / (10.0 + 5.0), rtol=1e-6)

    # Conditional integration: the integral alone drives the output exactly to tau_max and
    # stops there; a P term that saturates the output freezes it; a reversed error unwinds it.
    ctrl = VelocityController(settings(tau_max=six(1.0), kp=six(0.0), ki=six(1.0)))
    out = ctrl.step(six(5.0), six(0.0), DT)   # ki e dt = 0.05 per step
    assert out.integral[0] == pytest.approx(0.05)
    for _ in range(100):
        out = ctrl.step(six(5.0), six(0.0), DT)
    np.testing.assert_allclose(out.integral, 1.0, rtol=1e-12)
    np.testing.assert_allclose(out.tau, 1.0, rtol=1e-12)
    out = ctrl.step(six(-5.0), six(0.0), DT)  # error reverses: unwinds at once
    np.testing.assert_allclose(out.integral, 0.95, rtol=1e-12)
    ctrl.settings = dataclasses.replace(ctrl.settings, kp=six(10.0))
    for _ in range(10):                       # kp e = 50 >> tau_max: saturated, I frozen
        out = ctrl.step(six(5.0), six(0.0), DT)
        assert out.saturated.all() and np.all(out.tau == 1.0)
        np.testing.assert_allclose(out.integral, 0.95, rtol=1e-12)


# --- bumpless gain change --------------------------------------------------------------------


def test_changing_ki_is_bumpless():
    nu_d = np.array([0.5, -0.3, 0.2, 0.1, -0.2, 0.4])
    a = VelocityController(settings(d_lin=tuple(0.5 * D)))
    b = VelocityController(settings(d_lin=tuple(0.5 * D)))
    plant = LinearPlant()
    for _ in range(150):  # mid-transient: error and integral both non-zero
        out_a = a.step(nu_d, plant.v, DT)
        b.step(nu_d, plant.v, DT)
        plant.step(out_a.tau)
    tau_before = out_a.tau
    e = nu_d - plant.v
    assert np.all(np.abs(out_a.integral) > 1e-2) and np.all(np.abs(e) > 1e-3)

    new_ki = tuple(4.0 * np.asarray(a.settings.ki))
    b.settings = dataclasses.replace(b.settings, ki=new_ki)
    out_a = a.step(nu_d, plant.v, DT)
    out_b = b.step(nu_d, plant.v, DT)
    # Only this step's increment differs: (ki_new - ki_old) e dt.
    np.testing.assert_allclose(out_b.tau - out_a.tau,
                               (np.asarray(new_ki) - np.asarray(settings().ki)) * e * DT,
                               rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(out_b.tau - out_a.tau)) < 0.05
    # A controller storing the integral of e (times the new ki) would jump by
    # (ki_new / ki_old - 1) * I, much larger than the bumpless difference.
    naive_jump = (np.asarray(new_ki) / np.asarray(settings().ki) - 1.0) * out_a.integral
    assert np.all(np.abs(naive_jump) > 20.0 * np.abs(out_b.tau - out_a.tau))
    assert np.max(np.abs(out_b.tau - tau_before)) < 0.5  # the loop itself moves smoothly


def test_settings_setter_validates_before_swapping():
    ctrl = VelocityController(settings())
    old = ctrl.settings
    with pytest.raises(ValueError, match='kd'):
        ctrl.settings = dataclasses.replace(old, kd=six(-1.0))
    assert ctrl.settings is old
    # A smaller integral_limit clamps the stored integral immediately.
    ctrl.step(six(1.0), six(0.0), 1.0)  # ki e dt = 2 m -> integral well above 0.1
    ctrl.settings = dataclasses.replace(old, integral_limit=six(0.1))
    out = ctrl.step(six(0.0), six(0.0), DT)
    assert np.all(np.abs(out.integral) <= 0.1)


# --- unmeasured DOFs -----------------------------------------------------------------------


def test_nan_measurement_gives_feed_forward_only():
    d_quad = np.array([20.0, 30.0, 35.0, 1.0, 1.2, 0.8])
    ctrl = VelocityController(settings(d_lin=tuple(D), d_quad=tuple(d_quad), kd=six(1.0)))
    nu_d = np.array([0.5, -0.3, 0.2, 0.1, -0.2, 0.4])
    ff = D * nu_d + d_quad * np.abs(nu_d) * nu_d
    rng = np.random.default_rng(3)
    for _ in range(50):  # no DVL: u, v, w unknown; rates from the gyro
        nu = np.r_[np.nan, np.nan, np.nan, rng.normal(scale=0.1, size=3)]
        out = ctrl.step(nu_d, nu, DT)
        np.testing.assert_array_equal(out.tau[:3], ff[:3])
        np.testing.assert_array_equal(out.integral[:3], 0.0)
        assert np.all(out.tau[3:] != ff[3:]) and np.all(out.integral[3:] != 0.0)
    # The DVL comes back: proportional and integral act, but no derivative kick.
    nu = np.r_[0.1, 0.1, 0.1, 0.0, 0.0, 0.0]
    out = ctrl.step(nu_d, nu, DT)
    kp, ki = np.asarray(ctrl.settings.kp), np.asarray(ctrl.settings.ki)
    e = nu_d[:3] - nu[:3]
    np.testing.assert_allclose(out.tau[:3], ff[:3] + kp[:3] * e + ki[:3] * e * DT)
    # ... and losing it again drops the integral to zero for that DOF.
    out = ctrl.step(nu_d, np.r_[np.nan, 0.1, 0.1, 0.0, 0.0, 0.0], DT)
    assert out.integral[0] == 0.0 and out.tau[0] == ff[0] and out.integral[1] != 0.0


# --- derivative and leveling ---------------------------------------------------------------


def test_derivative_on_measurement_has_no_setpoint_kick_and_is_filtered():
    kd, t_f = 2.0, 0.05
    ctrl = VelocityController(settings(kp=six(0.0), ki=six(0.0), kd=six(kd),
                                       derivative_filter=t_f))
    for _ in range(10):
        out = ctrl.step(six(0.0), six(0.0), DT)
    out = ctrl.step(six(1.0), six(0.0), DT)  # setpoint step, measurement constant
    np.testing.assert_array_equal(out.tau, 0.0)
    # Measurement ramp of slope 0.5: the filtered derivative converges to 0.5 like
    # 1 - (T_f / (T_f + dt))^k.
    slope = 0.5
    for k in range(1, 201):
        out = ctrl.step(six(1.0), six(slope * k * DT), DT)
        expected = -kd * slope * (1.0 - (t_f / (t_f + DT)) ** k)
        np.testing.assert_allclose(out.tau, expected, rtol=1e-9)
    # derivative_filter = 0: the raw backward difference.
    raw = VelocityController(settings(kp=six(0.0), ki=six(0.0), kd=six(kd),
                                      derivative_filter=0.0))
    raw.step(six(0.0), six(0.0), DT)
    np.testing.assert_allclose(raw.step(six(0.0), six(0.01), DT).tau, -kd * 0.01 / DT)


def test_leveling_drives_roll_and_pitch_to_zero():
    k_lvl = 1.5
    ctrl = VelocityController(settings(level_gain=k_lvl))
    plant = LinearPlant()
    roll, pitch = 0.3, -0.2
    for _ in range(int(15.0 / DT)):
        out = ctrl.step(np.zeros(6), plant.v, DT, roll=roll, pitch=pitch)
        plant.step(out.tau)
        roll += plant.v[3] * DT     # small angles: phi_dot = p, theta_dot = q
        pitch += plant.v[4] * DT
    assert abs(roll) < 1e-3 and abs(pitch) < 1e-3
    # Leveling shifts the rate setpoint only: with zero gains nothing happens.
    quiet = VelocityController(settings(level_gain=k_lvl, kp=six(0.0), ki=six(0.0)))
    np.testing.assert_array_equal(quiet.step(np.zeros(6), np.zeros(6), DT, roll=0.3).tau, 0.0)
    first = VelocityController(settings(level_gain=k_lvl)).step(
        np.zeros(6), np.zeros(6), DT, roll=0.3, pitch=-0.2)
    kp, ki = np.asarray(settings().kp), np.asarray(settings().ki)
    e = np.array([0.0, 0.0, 0.0, -k_lvl * 0.3, k_lvl * 0.2, 0.0])
    np.testing.assert_allclose(first.tau, kp * e + ki * e * DT)


# --- second formulation: python-control ----------------------------------------------------


@pytest.mark.parametrize('dof', range(6))
def test_closed_loop_matches_python_control_transfer_functions(dof):
    """The simulated loop equals  y/r = (C + F) P / (1 + P (C + D_f))  in the z domain.

    P(z) = b / (z - a) (ZOH of 1 / (m s + d)), C(z) = k_p + k_i dt z / (z - 1) (the integral
    includes e_k), D_f(z) = k_d (z - 1) / ((T_f + dt) z - T_f) (filtered backward difference on
    the measurement), F = the static feed-forward d_ff.
    """
    import control  # python-control imports scipy.signal, slow: only this test needs it

    m, d = M[dof], D[dof]
    kp, ki, kd, t_f, d_ff = 3.0 * m, 2.0 * m, 0.1 * m, 0.02, 0.5 * d
    ctrl = VelocityController(settings(kp=six(kp), ki=six(ki), kd=six(kd), d_lin=six(d_ff),
                                       derivative_filter=t_f, integral_limit=six(math.inf),
                                       tau_max=six(math.inf)))
    plant = LinearPlant(m=six(m), d=six(d))
    n = 800
    r = 0.7
    v_sim = np.empty(n)
    for k in range(n):
        v_sim[k] = plant.v[dof]
        plant.step(ctrl.step(six(r), plant.v, DT).tau)

    a = math.exp(-d * DT / m)
    P = control.tf([(1.0 - a) / d], [1.0, -a], DT)
    C = control.tf([kp + ki * DT, -kp], [1.0, -1.0], DT)
    Df = control.tf([kd, -kd], [t_f + DT, -t_f], DT)
    T = (C + d_ff) * control.feedback(P, C + Df)
    resp = control.step_response(T, T=np.arange(n) * DT)
    np.testing.assert_allclose(r * np.squeeze(resp.outputs), v_sim, atol=1e-9)
    T_min = control.minreal(T, verbose=False)  # cancels the integrator pole z = 1 of C + F
    assert control.dcgain(T_min) == pytest.approx(1.0)      # integral action: no offset
    assert np.all(np.abs(control.poles(T_min)) < 1.0)       # stable discrete loop

    # Continuous PI + plant: poles of m s^2 + (d + kp) s + ki, which the discrete loop
    # approaches as z = exp(s dt) (kd and the filter change them by O(kd / m)).
    Tc = control.feedback(control.tf([kp, ki], [1.0, 0.0]) * control.tf([1.0], [m, d]), 1)
    expected = np.sort_complex(np.roots([m, d + kp, ki]))
    np.testing.assert_allclose(np.sort_complex(control.poles(Tc)), expected, rtol=1e-9)
    assert control.dcgain(Tc) == pytest.approx(1.0)
    pi_only = VelocityController(settings(kp=six(kp), ki=six(ki), tau_max=six(math.inf),
                                          integral_limit=six(math.inf)))
    plant = LinearPlant(m=six(m), d=six(d))
    for _ in range(n):
        plant.step(pi_only.step(six(r), plant.v, DT).tau)
    t = n * DT
    v_c = r * np.squeeze(control.step_response(Tc, T=np.linspace(0.0, t, 2001)).outputs)[-1]
    assert plant.v[dof] == pytest.approx(v_c, abs=2e-3)


# --- validation ----------------------------------------------------------------------------


@pytest.mark.parametrize('field, value', [
    ('kp', six(1.0)[:5]),
    ('ki', (1.0, 1.0, 1.0, 1.0, 1.0, math.nan)),
    ('kd', six(-0.1)),
    ('integral_limit', six(-1.0)),
    ('tau_max', (1.0, 1.0, 0.0, 1.0, 1.0, 1.0)),
    ('d_lin', six(math.inf)),
    ('d_quad', ('a',) * 6),
    ('inertia', six(-2.0)),
    ('level_gain', -1.0),
    ('derivative_filter', math.nan),
])
def test_validate_names_the_field(field, value):
    bad = dataclasses.replace(settings(), **{field: value})
    with pytest.raises(ValueError, match=field):
        bad.validate()
    with pytest.raises(ValueError, match=field):
        VelocityController(bad)


def test_step_rejects_bad_inputs():
    ctrl = VelocityController(settings())
    for dt in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError, match='dt'):
            ctrl.step(np.zeros(6), np.zeros(6), dt)
    with pytest.raises(ValueError, match='nu_d'):
        ctrl.step(np.r_[math.nan, np.zeros(5)], np.zeros(6), DT)
    with pytest.raises(ValueError, match='nu'):
        ctrl.step(np.zeros(6), np.r_[math.inf, np.zeros(5)], DT)
    with pytest.raises(ValueError, match='nu_d_dot'):
        ctrl.step(np.zeros(6), np.zeros(6), DT, nu_d_dot=np.r_[math.nan, np.zeros(5)])
    with pytest.raises(ValueError, match='shape'):
        ctrl.step(np.zeros(5), np.zeros(6), DT)


def test_reset_and_output_type():
    ctrl = VelocityController(settings())
    out = ctrl.step(six(1.0), six(0.0), DT)
    assert isinstance(out, ControlOutput) and out.saturated.dtype == bool
    ctrl.reset()
    again = ctrl.step(six(1.0), six(0.0), DT)
    np.testing.assert_array_equal(again.tau, out.tau)


# --- VelocityReference: the reference model in front of the loop ---------------------------
#
# nu_ref_dot = sat((goal - nu_ref) / max(T, dt), a_max), nu_ref += nu_ref_dot dt per DOF.
# The expected values below are written from that recursion and its closed forms, not from
# the class.

T_REF = (0.5, 0.4, 0.8, 0.3, 0.3, 0.6)      # time constants [s]
A_MAX = (0.5, 0.4, 0.3, 2.0, 2.0, 1.0)      # acceleration limits [m/s^2, rad/s^2]


def test_reference_small_step_is_the_first_order_closed_form():
    """Below the acceleration limit the response to a step is exactly (1 - dt/T)^k away from
    the goal (the forward-Euler recursion), and within the Euler error of 1 - exp(-t/T)."""
    ref = VelocityReference(T_REF, six(100.0))          # limit far above goal / T
    goal = np.array([0.2, -0.1, 0.05, 0.3, -0.2, 0.1])
    T = np.array(T_REF)
    for k in range(1, 301):
        nu_ref, nu_ref_dot = ref.step(goal, DT)
        expected = goal * (1.0 - (1.0 - DT / T) ** k)
        # Budget: float64 rounding of k additions, |goal| 1e-16 per step -> 1e-13.
        np.testing.assert_allclose(nu_ref, expected, rtol=0.0, atol=1e-13)
        # The rate is what moved the reference in this step: (goal - nu_ref_before) / T.
        np.testing.assert_allclose(
            nu_ref_dot, goal * (1.0 - DT / T) ** (k - 1) / T, rtol=0.0, atol=1e-12)
    # 63 % at one time constant, as the continuous first-order lag 1 - exp(-t/T). With
    # h = dt / T and n = T / dt, ln(1 - h) lies in [-h - h^2/2 - h^3/(3(1 - h)), -h], so the
    # Euler response exceeds 1 - exp(-1) by between 0 and exp(-1) (1 - exp(-h/2 - h^2/(3(1-h)))):
    # that bound is the budget (0.0037 for T = 0.5 s).
    ref = VelocityReference(T_REF, six(100.0))
    for j, tc in enumerate(T_REF):
        ref.reset()
        n = round(tc / DT)
        for _ in range(n):
            nu_ref, _ = ref.step(goal, DT)
        h = DT / tc
        lead = nu_ref[j] / goal[j] - (1.0 - math.exp(-1.0))
        budget = math.exp(-1.0) * (1.0 - math.exp(-h / 2 - h * h / (3 * (1 - h))))
        assert -1e-12 <= lead <= budget, (j, lead, budget)


def test_reference_large_step_ramps_at_the_acceleration_limit_then_converges():
    """A step too big for the limit: a ramp of slope a_max until (goal - nu_ref) / T falls
    below a_max, then the first-order tail; never past the goal, rate never above a_max."""
    ref = VelocityReference(T_REF, A_MAX)
    goal = np.array([1.0, -1.0, 0.6, 3.0, -3.0, 1.5])
    a = np.array(A_MAX)
    T = np.array(T_REF)
    prev = err_prev = np.zeros(6)
    ramp_steps = np.floor((np.abs(goal) - a * T) / (a * DT)).astype(int)  # still limited
    for k in range(1, 1001):
        nu_ref, nu_ref_dot = ref.step(goal, DT)
        assert np.all(np.abs(nu_ref_dot) <= a + 1e-12)
        assert np.all(np.abs(nu_ref - prev) <= a * DT + 1e-12)      # no jump, ever
        assert np.all(np.sign(goal) * (goal - nu_ref) >= -1e-12)    # never beyond the goal
        ramping = k <= ramp_steps
        # During the ramp: exactly a_max k dt in the goal's direction.
        np.testing.assert_allclose(nu_ref[ramping], (np.sign(goal) * a * DT * k)[ramping],
                                   rtol=0.0, atol=1e-12)
        # After it (one transition step later): the error shrinks by exactly 1 - dt/T a step.
        tail = k > ramp_steps + 1
        err = goal - nu_ref
        np.testing.assert_allclose(err[tail], (err_prev * (1.0 - DT / T))[tail],
                                   rtol=1e-9, atol=1e-15)
        prev, err_prev = nu_ref.copy(), err
    # The ramp really was limited (the test would pass vacuously otherwise): it lasts
    # (|goal| - a T) / a, the closed form of the limited phase, here 0.9 to 2.1 s.
    assert np.all(ramp_steps >= 90)


def test_reference_without_the_limit_would_jump():
    """The same large step with a_max effectively off moves goal dt / T in the first step:
    far more than a_max dt. So the limit above is what keeps the ramp (a guard of the test)."""
    goal = np.array([1.0, -1.0, 0.6, 3.0, -3.0, 1.5])
    free = VelocityReference(T_REF, six(1e9))
    first, _ = free.step(goal, DT)
    limited = VelocityReference(T_REF, A_MAX)
    first_limited, _ = limited.step(goal, DT)
    np.testing.assert_allclose(first, goal * DT / np.array(T_REF), rtol=1e-12)
    np.testing.assert_allclose(np.abs(first_limited), np.array(A_MAX) * DT, rtol=1e-12)
    assert np.all(np.abs(first) > 2.0 * np.abs(first_limited))


def test_reference_step_in_each_direction_is_symmetric():
    up, down = VelocityReference(T_REF, A_MAX), VelocityReference(T_REF, A_MAX)
    goal = np.array([0.8, 0.5, -0.4, 1.0, -2.0, 0.7])
    for _ in range(200):
        a, _ = up.step(goal, DT)
        b, _ = down.step(-goal, DT)
        np.testing.assert_allclose(a, -b, rtol=0.0, atol=1e-15)


def test_reference_dt_longer_than_t_lands_on_the_goal_without_overshoot():
    """dt > T: the rate is (goal - nu_ref) / dt, so one step lands exactly on the goal."""
    ref = VelocityReference(six(0.05), six(1e3))
    goal = np.array([0.3, -0.2, 0.1, 0.4, -0.5, 0.6])
    nu_ref, nu_ref_dot = ref.step(goal, 0.2)
    np.testing.assert_allclose(nu_ref, goal, rtol=1e-15)
    np.testing.assert_allclose(nu_ref_dot, goal / 0.2, rtol=1e-15)
    again, rate = ref.step(goal, 0.2)
    np.testing.assert_allclose(again, goal, rtol=1e-15)
    np.testing.assert_array_equal(rate, 0.0)


def test_reference_reset_is_bumpless():
    """reset(nu) starts the reference at the vehicle's velocity with zero rate: holding that
    goal moves nothing, and a new goal is approached from nu at no more than a_max dt per
    step (no jump back to zero). reset() without an argument starts at rest."""
    ref = VelocityReference(T_REF, A_MAX)
    for _ in range(50):
        ref.step(six(1.0), DT)
    nu = np.array([0.2, -0.1, 0.05, 0.3, 0.0, -0.4])
    ref.reset(nu)
    np.testing.assert_array_equal(ref.nu_ref, nu)
    np.testing.assert_array_equal(ref.nu_ref_dot, 0.0)
    held, rate = ref.step(nu, DT)
    np.testing.assert_array_equal(held, nu)
    np.testing.assert_array_equal(rate, 0.0)
    goal = nu + np.array([1.0, 1.0, -1.0, 2.0, 3.0, -2.0])
    nxt, rate = ref.step(goal, DT)
    np.testing.assert_allclose(nxt - nu, np.sign(goal - nu) * np.array(A_MAX) * DT, rtol=1e-12)
    nu[0] = 5.0                                         # reset copied nu: no aliasing
    assert ref.nu_ref[0] != 5.0
    ref.reset()
    np.testing.assert_array_equal(ref.nu_ref, 0.0)
    np.testing.assert_array_equal(ref.nu_ref_dot, 0.0)


@pytest.mark.parametrize('time_constant, max_accel, name', [
    (six(0.0), A_MAX, 'time_constant'),
    ((0.5, 0.5, -0.1, 0.5, 0.5, 0.5), A_MAX, 'time_constant'),
    (six(math.nan), A_MAX, 'time_constant'),
    (T_REF, six(0.0), 'max_accel'),
    (T_REF, (1.0, 1.0, 1.0, 1.0, 1.0, -1.0), 'max_accel'),
    (T_REF, six(math.nan), 'max_accel'),
    ((0.5,) * 5, A_MAX, 'time_constant'),
    (T_REF, (1.0,) * 7, 'max_accel'),
])
def test_reference_rejects_bad_parameters_by_name(time_constant, max_accel, name):
    with pytest.raises(ValueError, match=name):
        VelocityReference(time_constant, max_accel)


def test_reference_step_rejects_bad_dt_and_goal_shape():
    ref = VelocityReference(T_REF, A_MAX)
    for dt in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError, match='dt'):
            ref.step(six(0.0), dt)
    with pytest.raises(ValueError, match='nu_goal'):
        ref.step(np.zeros(5), DT)
    with pytest.raises(ValueError, match='nu'):
        ref.reset(np.zeros(4))
    np.testing.assert_array_equal(ref.nu_ref, 0.0)      # refused calls changed nothing


def test_reference_refuses_a_non_finite_goal_and_an_infinite_time_constant():
    ref = VelocityReference(T_REF, A_MAX)
    ref.step(six(0.2), DT)
    before = ref.nu_ref.copy()
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match='nu_goal'):
            ref.step((0.1, bad, 0.0, 0.0, 0.0, 0.0), DT)
    np.testing.assert_array_equal(ref.nu_ref, before)   # not poisoned: the next step is sane
    assert np.all(np.isfinite(ref.step(six(0.2), DT)[0]))
    with pytest.raises(ValueError, match='time_constant'):
        VelocityReference((0.5, 0.5, math.inf, 0.5, 0.5, 0.5), A_MAX)
    VelocityReference(T_REF, six(math.inf))             # no acceleration limit is allowed


def test_coriolis_feed_forward_is_fossens_c_of_the_diagonal_inertia():
    """Against rigid_body.coriolis_matrix (the simulator's own C(nu), Fossen Thm 3.2)."""
    from enbarr_core.models.rigid_body import coriolis_force
    from enbarr_core.models.rigid_body import coriolis_matrix
    rng = np.random.default_rng(7)
    for _ in range(20):
        inertia = rng.uniform(0.1, 20.0, 6)
        nu = rng.uniform(-1.0, 1.0, 6)
        np.testing.assert_allclose(coriolis_force(inertia, nu),
                                   coriolis_matrix(np.diag(inertia), nu) @ nu, atol=1e-12)
    # Hand numbers: a turn at u = 0.3 m/s, r = 0.3 rad/s needs sway force M_u u r to hold the
    # circle (Y = r h_u) and a yaw moment (M_v - M_u) u v = 0 when v = 0.
    f = coriolis_force(np.array([17.0, 24.2, 26.07, 0.28, 0.28, 0.28]),
                       np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.3]))
    np.testing.assert_allclose(f, [0.0, 17.0 * 0.3 * 0.3, 0.0, 0.0, 0.0, 0.0], atol=1e-12)


# --- survivors of mutation testing (docs/testing.md): each pins one line of step() ----------


def test_step_adds_the_coriolis_feed_forward_with_its_sign():
    # coriolis_force itself is checked above; here the controller must ADD it: holding a turn
    # at u = 0.3 m/s, r = 0.3 rad/s needs Y = +M_u u r = +1.53 N (Fossen: M nu_dot + C nu = tau),
    # with every gain and the damping zero so the feed-forward is all there is.
    inertia = (17.0, 24.2, 26.07, 0.28, 0.28, 0.28)
    zero = six(0.0)
    nu_d = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.3])
    ctrl = VelocityController(settings(kp=zero, ki=zero, inertia=inertia))
    out = ctrl.step(nu_d, nu_d, DT)
    np.testing.assert_allclose(out.tau_ff, [0.0, 17.0 * 0.09, 0.0, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(out.tau, out.tau_ff, atol=1e-12)
    off = VelocityController(settings(kp=zero, ki=zero, inertia=inertia, coriolis=False))
    np.testing.assert_array_equal(off.step(nu_d, nu_d, DT).tau_ff, 0.0)


def test_with_an_unmeasured_dof_the_others_keep_their_integral_with_its_sign():
    # r is not measured (NaN): its integral is held at 0 and its output is feed-forward only;
    # u..q integrate k_i e dt per step (k_p = 0): after n steps I = n k_i e dt and tau = +I.
    ki, n = 2.0, 10
    ctrl = VelocityController(settings(kp=six(0.0), ki=six(ki)))
    nu = np.array([0.0, 0.0, 0.0, 0.0, 0.0, math.nan])
    for _ in range(n):
        out = ctrl.step(six(0.5), nu, DT)
    want = np.array([n * ki * 0.5 * DT] * 5 + [0.0])
    np.testing.assert_allclose(out.integral, want, rtol=1e-12)
    np.testing.assert_allclose(out.tau, want, rtol=1e-12)


def test_a_saturating_p_term_freezes_the_integral_even_for_a_small_error():
    # k_p e = 10 x 0.05 = 0.5 > tau_max = 0.2 in the direction e pushes: the integral is held
    # at 0, however small e u is (0.025 here; the existing test has e u = 250).
    ctrl = VelocityController(settings(kp=six(10.0), ki=six(1.0), tau_max=six(0.2)))
    for _ in range(10):
        out = ctrl.step(six(0.05), six(0.0), DT)
        np.testing.assert_array_equal(out.integral, 0.0)
        assert out.saturated.all()


def test_an_output_driven_exactly_to_tau_max_is_not_saturated():
    # Conditional integration stops the integral exactly at tau_max (u == tau_max): like a
    # thruster exactly at its limit, that output is not reported as saturated (|u| > tau_max).
    ctrl = VelocityController(settings(tau_max=six(1.0), kp=six(0.0), ki=six(1.0)))
    for _ in range(101):
        out = ctrl.step(six(5.0), six(0.0), DT)
    np.testing.assert_array_equal(out.tau, 1.0)
    assert not out.saturated.any()


def test_leveling_with_a_unit_gain_and_its_neutral_default_attitude():
    # k_lvl = 1: p_r = p_d - phi, q_r = q_d - theta (a gain of exactly 1 must not switch it
    # off); without roll/pitch given the attitude is taken as level (no correction).
    kp = np.asarray(settings().kp)
    ctrl = VelocityController(settings(level_gain=1.0, ki=six(0.0)))
    tau = ctrl.step(np.zeros(6), np.zeros(6), DT, roll=0.3, pitch=-0.2).tau
    np.testing.assert_allclose(tau, kp * np.array([0, 0, 0, -0.3, 0.2, 0]), rtol=1e-12)
    ctrl = VelocityController(settings(level_gain=1.0, ki=six(0.0)))
    np.testing.assert_array_equal(ctrl.step(np.zeros(6), np.zeros(6), DT).tau, 0.0)


@pytest.mark.parametrize('roll,pitch', [(math.nan, 0.0), (0.0, math.nan), (math.inf, 0.0)])
def test_either_non_finite_attitude_angle_is_refused(roll, pitch):
    ctrl = VelocityController(settings(level_gain=1.0))
    with pytest.raises(ValueError, match=r'^roll and pitch must be finite'):
        ctrl.step(np.zeros(6), np.zeros(6), DT, roll=roll, pitch=pitch)


def test_input_errors_start_with_the_argument_name():
    # Anchored: a message that merely contains the name somewhere (or a mangled name) fails.
    ctrl = VelocityController(settings())
    with pytest.raises(ValueError, match=r'^nu_d: '):
        ctrl.step(np.zeros(5), np.zeros(6), DT)
    with pytest.raises(ValueError, match=r'^nu: '):
        ctrl.step(np.zeros(6), np.zeros(5), DT)
    with pytest.raises(ValueError, match=r'^nu_d_dot: '):
        ctrl.step(np.zeros(6), np.zeros(6), DT, nu_d_dot=np.zeros(5))
