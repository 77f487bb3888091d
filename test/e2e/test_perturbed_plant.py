"""End-to-end: closed loops whose simulated plant is not the controller's model.

In the ordinary profiles the simulator and the controller read one vessel block, so the plant
is exactly the model and a wrong number (or a wrong model) goes unseen. Here the scenarios
``params/scenarios/perturbed_*.yaml`` give the simulator node its own vessel (30 % heavier
and 40 % draggier, or 30 % lighter and slicker) and an unmodelled current; the observer and
the controllers keep the profile's (manual's, Wu's) numbers. Each run is ``enbarr scenario``
(simulated time, so the figures do not depend on the machine's speed), judged from its bag
against what the controller should still achieve, with the budget of each bound stated.

The scenario's own metrics (``enbarr_core.tools.metrics``) are not used: only the bag.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from support.scenarios import run_scenario

from enbarr_core.framework.kinematics import quat_to_rotmat, ssa
from enbarr_interfaces import convert

def node_parameters(profile: Any, node: str) -> dict[str, Any]:
    """What ``node`` is given: the common parameters, then its own over them (as bringup)."""
    return {**profile.parameters, **profile.node(node).parameters}


def series(msgs: list[tuple[int, Any]]) -> np.ndarray:
    """Receive times [s] of recorded messages (simulated time)."""
    return np.array([t * 1e-9 for t, _ in msgs])


def ratios(plant: dict[str, Any], model: dict[str, Any], keys: tuple[str, ...]) -> np.ndarray:
    return np.concatenate([np.atleast_1d(np.asarray(plant[k], float)
                                         / np.asarray(model[k], float)) for k in keys])


# -- CS Saucer: DP station keeping ------------------------------------------------------------
SAUCER_VESSEL = ('vessel.inertia', 'vessel.linear_damping', 'vessel.nonlinear_damping')
# The manual push (0 .. 3 s, stick 0.6 ahead) and the press of triangle (4 s) of both scripts.
PUSH_WINDOW = (0.5, 2.5)  # s from the start: past the 0.1 s motor lag, before the stick drops
SETTLED_AFTER = 25.0      # s after triangle
STILL_AFTER = 40.0        # s after triangle (the runs last 60 s: 16 s of window)
# Settling budget. Linearized about rest, each axis of the DP loop is
# M s^3 + (D + Kd) s^2 + Kp s + Ki = 0 (Kp 10 N/m, Ki 1 N/(m s), Kd 12 N s/m, saucer_core);
# its slowest root is -0.117 1/s (8.5 s) for the plant's M and D of both scenarios. The hold
# starts with the vessel moving (~0.2 m/s after the push) and ends up to 0.25 m from where
# triangle was pressed, so what is left after t is at most 0.25 m e^(-t / 8.5 s):
# 13 mm after 25 s, 2.3 mm after 40 s. The motion capture's 2 mm / 0.005 rad noise reaches
# the truth through a loop of ~1 rad/s bandwidth, well under 1 mm.
SETTLED_M = 0.03          # bound from 25 s: 13 mm of transient, x2 for the observer's lag
STILL_M = 0.005           # bound from 40 s: 2.3 mm of transient, x2
STILL_MEAN_M = 0.0025     # bound on the mean (the steady offset) from 40 s
HEADING_DEG = 1.0         # 3.5 sigma of the raw heading noise (0.29 deg); the loop filters it
KP = 10.0                 # N/m, saucer_core.yaml dp_control.kp (surge, sway)


@pytest.fixture(scope='module', params=['perturbed_heavy', 'perturbed_light'])
def saucer(request: pytest.FixtureRequest,
           tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    run = run_scenario(request.param, tmp_path_factory.mktemp(request.param))
    msgs = run['msgs']
    od = msgs['/sim/odometry']
    run['t'] = series(od)
    run['t0'] = run['t'][0]
    run['eta'] = np.array([(m.pose.pose.position.x, m.pose.pose.position.y,
                            convert.quaternion_to_yaw(m.pose.pose.orientation)) for _, m in od])
    run['u'] = np.array([m.twist.twist.linear.x for _, m in od])
    modes = [(t * 1e-9, m.data) for t, m in msgs['/mode']]
    run['modes'] = modes
    run['hold'] = next(t for t, m in modes if m == 'automatic')
    ref = msgs['/guidance/reference']
    run['ref_t'] = series(ref)
    run['ref'] = np.array([convert.transform_to_eta(m.points[0].transforms[0])
                           for _, m in ref])
    run['plant'] = node_parameters(run['profile'], 'simulator')
    run['model'] = node_parameters(run['profile'], 'dp_control')
    return run


def test_saucer_plant_is_not_the_controllers_model(saucer: dict[str, Any]) -> None:
    """The simulator's vessel differs 20-40 % from the one the observer and the controller
    use, which is still the manual's; the current is one the controller knows nothing of."""
    plant, model = saucer['plant'], saucer['model']
    assert node_parameters(saucer['profile'], 'observer')[SAUCER_VESSEL[0]] == \
        model[SAUCER_VESSEL[0]] == [9.51, 9.51, 0.116]
    r = ratios(plant, model, SAUCER_VESSEL)
    assert np.all((np.abs(r - 1.0) >= 0.2 - 1e-9) & (np.abs(r - 1.0) <= 0.4 + 1e-9)), r
    assert math.hypot(*plant['current']) >= 0.1 - 1e-9


def test_saucer_simulator_ran_the_perturbed_hull(saucer: dict[str, Any]) -> None:
    """A momentum balance over the manual push gives back the plant's m11, not the model's.

    m11 (u(t2) - u(t1)) = integral of X - d11 u_r - dn11 |u_r| u_r over [t1, t2], with X the
    force the allocation delivered (the stick is constant, so X is) and the plant's damping
    on the velocity relative to the current (heading 0: u_r = u - V_x). Budget 3 %: the
    motor's 0.1 s lag leaves 0.9 N x 0.1 s x e^-5 = 6e-4 N s of impulse (0.005 kg); the
    trapezoid rule at 100 Hz is exact to 1e-5. The model's m11 is 30 % away.
    """
    msgs, t, u = saucer['msgs'], saucer['t'], saucer['u']
    plant, model = saucer['plant'], saucer['model']
    m11, d11, dn11 = (plant[k][0] for k in SAUCER_VESSEL)
    td = series(msgs['/allocation/delivered'])
    x = np.array([m.wrench.force.x for _, m in msgs['/allocation/delivered']])
    w = (t >= saucer['t0'] + PUSH_WINDOW[0]) & (t <= saucer['t0'] + PUSH_WINDOW[1])
    X = np.interp(t[w], td, x)
    assert np.ptp(X) < 1e-9 and X[0] > 0.5  # pushed ahead, steadily
    assert np.max(np.abs(saucer['eta'][w, 2])) < 1e-3  # heading 0: surge is east
    u_r = u[w] - plant['current'][0]
    net = X - d11 * u_r - dn11 * np.abs(u_r) * u_r
    m_est = np.trapezoid(net, t[w]) / (u[w][-1] - u[w][0])
    assert m_est == pytest.approx(m11, rel=0.03)
    assert abs(m_est - model[SAUCER_VESSEL[0]][0]) > 0.2 * model[SAUCER_VESSEL[0]][0]


def _hold_errors(run: dict[str, Any], after: float) -> tuple[np.ndarray, np.ndarray]:
    """World position error (n, 2) [m] and heading error (n,) [deg] from ``after`` seconds
    past triangle to the end, against the hold reference in force at each sample."""
    t = run['t']
    sel = t >= run['hold'] + after
    idx = np.clip(np.searchsorted(run['ref_t'], t[sel], side='right') - 1, 0,
                  len(run['ref_t']) - 1)
    ref = run['ref'][idx]
    return (run['eta'][sel, :2] - ref[:, :2],
            np.degrees(np.abs(ssa(run['eta'][sel, 2] - ref[:, 2]))))


def test_saucer_holds_its_pose_despite_model_error_and_current(saucer: dict[str, Any]) -> None:
    """Automatic from triangle to the end; the integral (with the observer's bias) takes
    out the steady offset the unmodelled current and damping would leave. Without it the
    vessel sits Kp-limited several centimetres downstream (11-14 cm measured with ki = 0):
    the bounds are the settling budget above, not a measured value plus a margin."""
    assert [m for _, m in saucer['modes']] == ['manual', 'automatic']  # latched start first
    assert saucer['hold'] - saucer['t0'] == pytest.approx(4.0, abs=0.05)
    settled, _ = _hold_errors(saucer, SETTLED_AFTER)
    assert np.max(np.linalg.norm(settled, axis=1)) < SETTLED_M
    still, heading = _hold_errors(saucer, STILL_AFTER)
    assert len(still) > 500  # 16 s at 50 Hz odometry at least
    assert np.max(np.linalg.norm(still, axis=1)) < STILL_M
    assert np.linalg.norm(still.mean(axis=0)) < STILL_MEAN_M
    assert np.max(heading) < HEADING_DEG


def test_saucer_holding_force_is_the_plants_drag(saucer: dict[str, Any]) -> None:
    """Held still in the current, the vessel's water-relative velocity is nu_r = -R^T V, so
    the force that holds it balances the plant's drag: tau = (D + Dn |nu_r|) nu_r per axis
    (eq. 1.5's diag(|u|, |v|)). The mean force the allocation delivered over the still
    window matches it within Kp x STILL_MEAN_M = 0.025 N (the proportional force of the
    offset the loop may still have); the model's drag differs by 0.04-0.08 N."""
    msgs, plant, model = saucer['msgs'], saucer['plant'], saucer['model']
    td = series(msgs['/allocation/delivered'])
    sel = td >= saucer['hold'] + STILL_AFTER
    F = np.array([(m.wrench.force.x, m.wrench.force.y)
                  for _, m in msgs['/allocation/delivered']])[sel].mean(axis=0)
    psi = float(np.mean(saucer['eta'][saucer['t'] >= saucer['hold'] + STILL_AFTER, 2]))
    c, s = math.cos(psi), math.sin(psi)
    vx, vy = plant['current']
    nu_r = -np.array([c * vx + s * vy, -s * vx + c * vy])

    def drag(p: dict[str, Any]) -> np.ndarray:
        d, dn = (np.array(p[k][:2]) for k in SAUCER_VESSEL[1:])
        return (d + dn * np.abs(nu_r)) * nu_r

    np.testing.assert_allclose(F, drag(plant), atol=KP * STILL_MEAN_M)
    assert np.max(np.abs(drag(model) - drag(plant))) > 2 * KP * STILL_MEAN_M


# -- Enbarr ROV: velocity feed-forward without a velocity sensor ------------------------------
ROV_VEHICLE = ('vehicle.mass', 'vehicle.inertia', 'vehicle.added_mass', 'vehicle.d_lin',
               'vehicle.d_quad')
U_GOAL = 0.4               # m/s, the script's surge goal from t = 0
ROV_WINDOW = (4.0, 7.0)    # s after the goal
# Budget of the surge prediction [m/s]. The reference reaches the goal within 2 s (0.5 m/s^2,
# then T = 0.4 s); the plant's surge lag (m + X_udot) / (d_lin + 2 d_quad u) is ~1 s in both
# plants, and the inertia feed-forward's 30 % error leaves < 0.05 m/s at 2 s: e^-2 x 0.05 =
# 0.007 at 4 s, less later. The hull turns slowly while it drives (up to 0.07 rad/s: the
# yaw-rate loop regulates the attitude filter's rate, which differs from the truth by that
# much in these runs) and slips sideways up to 0.07 m/s: the Coriolis and added-mass force
# on surge, r (m v + Y_vdot v_r), stays below 0.15 N against a damping slope above
# 15 N/(m/s): 0.010. Motor lag and allocation are exact at steady thrust.
SURGE_TOL = 0.012


@pytest.fixture(scope='module', params=['perturbed_rov_heavy', 'perturbed_rov_light'])
def rov(request: pytest.FixtureRequest,
        tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    run = run_scenario(request.param, tmp_path_factory.mktemp(request.param))
    msgs = run['msgs']
    run['t0'] = msgs['/surface_command/twist'][0][0] * 1e-9  # the script's t = 0
    run['plant'] = node_parameters(run['profile'], 'simulator')
    run['model'] = node_parameters(run['profile'], 'control_loop')
    return run


def test_rov_plant_is_not_the_feed_forward_model(rov: dict[str, Any]) -> None:
    plant, model = rov['plant'], rov['model']
    assert model['vehicle.d_lin'] == [4.03, 6.22, 5.18, 0.07, 0.07, 0.07]  # Wu's, as profiled
    r = ratios(plant, model, ROV_VEHICLE)
    assert np.all((np.abs(r - 1.0) >= 0.2 - 1e-9) & (np.abs(r - 1.0) <= 0.4 + 1e-9)), r
    # Trimmed neutral again: the change of weight is not a disturbance of its own.
    assert plant['vehicle.buoyancy'] == pytest.approx(plant['vehicle.mass'] * 9.81)
    assert np.linalg.norm(plant['current']) >= 0.05


def test_rov_feed_forward_surge_misses_by_the_damping_error(rov: dict[str, Any]) -> None:
    """Surge has no velocity sensor: the loop sends tau_X = d_lin u_d + d_quad u_d^2 of the
    model and nothing else. The plant settles where its own damping, on the velocity
    relative to the water, takes that force:
        d_lin' u_r + d_quad' u_r^2 = tau_X,  u = u_r + (R^T V)_x.
    So the steady surge error is set by the damping error (0.06 m/s slow for the draggier
    plant, 0.1 m/s fast for the slicker one) plus the current, and the loop would need a
    velocity measurement (velocity_topic) to remove it."""
    msgs, plant, model = rov['msgs'], rov['plant'], rov['model']
    tau_x = model['vehicle.d_lin'][0] * U_GOAL + model['vehicle.d_quad'][0] * U_GOAL ** 2
    dl, dq = plant['vehicle.d_lin'][0], plant['vehicle.d_quad'][0]
    u_r = (-dl + math.sqrt(dl * dl + 4.0 * dq * tau_x)) / (2.0 * dq)
    assert abs(u_r - U_GOAL) > 0.05  # the damping error alone is worth 4 x the budget
    # The command is the feed-forward alone. Budget 2e-3 N: the reference model is within
    # 0.2 e^-9 m/s of the goal at 4 s (its T = 0.4 s after a 0.4 s ramp), which moves the
    # feed-forward by 18.6 N/(m/s) x 2.5e-5 m/s + 17 kg x 6e-5 m/s^2 = 1.5e-3 N.
    fc = msgs['/force_command']
    tf = series(fc) - rov['t0']
    X = np.array([m.wrench.force.x for _, m in fc])[(tf >= ROV_WINDOW[0]) & (tf < ROV_WINDOW[1])]
    np.testing.assert_allclose(X, tau_x, atol=2e-3)
    od = msgs['/sim/odometry']
    t = series(od) - rov['t0']
    w = (t >= ROV_WINDOW[0]) & (t < ROV_WINDOW[1])
    assert w.sum() > 100
    V = np.asarray(plant['current'], dtype=float)
    for (_, m), inside in zip(od, w):
        if not inside:
            continue
        o = m.pose.pose.orientation
        u_c = (quat_to_rotmat([o.x, o.y, o.z, o.w]).T @ V)[0]
        u = m.twist.twist.linear.x
        assert abs(u - (u_r + u_c)) < SURGE_TOL, (u, u_r, u_c)
