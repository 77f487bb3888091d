"""Depth and heading hold (pure): the loops alone, then the Enbarr ROV in closed loop.

The closed loop is the simulated profile's vehicle (``params/enbarr_sim.yaml``: Wu 2018's
BlueROV2-class model, eight thrusters with their limits) under a 0.2 m/s current, driven by
its velocity loop with the profile's gains, the depth from the pressure sensor at its
resolution through ``estimation.depth_estimator``, the heading with an AHRS's noise. The plant
is also run 30 % heavier (mass, added mass, inertia) with 30 % more damping and 2 N light,
which the controller's model does not know. Targets (the pilot modes' figures): after settling,
depth error RMS at most 2 cm and heading error at most 1 deg.

Noise figures typed here: the MS5837-30BA's resolution at OSR 4096, 0.2 mbar = 20 Pa (TE data
sheet); an AHRS heading noise of 0.3 deg RMS and an accelerometer's 0.02 m/s^2 RMS (an
LSM9DS1-class IMU at 100 Hz).
"""

from __future__ import annotations

from functools import cache
import math

import numpy as np
import pytest
from support.rov import sim_parameters, sim_thrusters, vehicle_parameters

from enbarr_core.allocation.fixed import ThrustAllocator
from enbarr_core.control.pilot_hold import (
    DepthHold, DepthHoldSettings, HeadingHold, HeadingHoldSettings)
from enbarr_core.control.velocity_control import VelocityController, VelocityReference
from enbarr_core.control.velocity_control_node import VelocityControlNodeSettings
from enbarr_core.estimation.depth_estimator import DepthEstimator, DepthEstimatorSettings
from enbarr_core.framework.kinematics import quat_to_euler, quat_to_rotmat, ssa
from enbarr_core.models.rigid_body import RigidBodyModel, RigidBodyParams, RigidBodyState

KI = 0.3
DEPTH = DepthHoldSettings(gain=1.0, max_climb=0.5, deadband=0.05, integral_gain=KI,
                          integral_limit=0.2)
HEADING = HeadingHoldSettings(gain=2.0, max_rate=0.6, deadband=0.05, settle_rate=0.05,
                              settle_time=0.5)
DEPTH_STD = 20.0 / (997.0 * 9.80665)   # 20 Pa of fresh water [m]
HEADING_STD = math.radians(0.3)
ACCEL_STD = 0.02
G = 9.80665
FAIL_AT = 20.0          # [s] a thruster dies, after the dive and the turn
ENGAGE, STALE = 8.0, 30.0   # [s] depth hold entered mid-dive; its depth lost
DETECTION_DELAY = 0.5   # [s] until the allocator is told (the thruster monitor's latency)


# -- the loops alone ----------------------------------------------------------------------
@pytest.mark.unit
def test_depth_stick_drives_then_the_release_point_is_held():
    d = DepthHold(DEPTH)
    assert d.step(-1.0, -1.0) == pytest.approx(-0.5)     # full stick down: dive at max_climb
    assert d.target is None
    assert d.step(0.0, -1.3) == 0.0                      # released at z = -1.3: held there
    assert d.target == -1.3
    assert d.step(0.02, -1.2) == pytest.approx(-0.1)     # inside the deadband: back down
    assert d.step(0.0, 0.5) == -0.5                      # far off: at most max_climb
    assert d.step(math.nan, -1.3) == 0.0                 # a lost stick is a centred one


@pytest.mark.unit
def test_the_depth_integral_builds_up_and_is_clamped():
    d = DepthHold(DEPTH)
    d.engage(-2.0)
    assert d.step(0.0, -2.1, 1.0) == pytest.approx(0.1 + KI * 0.1)   # P plus one second of I
    for _ in range(100):
        d.step(0.0, -2.1, 1.0)
    assert d.integral == pytest.approx(0.2)                           # the clamp
    assert d.step(0.0, -2.1) == pytest.approx(0.3)                    # dt 0: no integration


@pytest.mark.unit
def test_heading_waits_for_the_turn_to_die_out_then_holds():
    h = HeadingHold(HEADING)
    assert h.step(1.0, 0.0, 0.6, 0.01) == pytest.approx(0.6)
    # released while still turning at 0.3 rad/s: no rate commanded, no target yet
    assert h.step(0.0, 0.5, 0.3, 0.01) == 0.0 and h.target is None
    assert h.step(0.0, 0.52, 0.01, 0.01) == 0.0           # below settle_rate: held from here
    assert h.target == 0.52
    assert h.step(0.0, 0.42, 0.0, 0.01) == pytest.approx(0.2)
    # across +-pi the error is wrapped
    h.engage(math.pi - 0.05)
    assert h.step(0.0, -math.pi + 0.05, 0.0, 0.01) == pytest.approx(-0.2)


@pytest.mark.unit
def test_heading_holds_after_settle_time_even_if_still_turning():
    h = HeadingHold(HEADING)
    h.step(1.0, 0.0, 0.6, 0.01)
    for _ in range(49):
        assert h.step(0.0, 1.0, 0.2, 0.01) == 0.0
    h.step(0.0, 1.0, 0.2, 0.01)
    assert h.target == 1.0


@pytest.mark.unit
@pytest.mark.parametrize('cls, settings, field', [
    (DepthHoldSettings, dict(gain=0.0, max_climb=0.5, deadband=0.05), 'gain'),
    (DepthHoldSettings, dict(gain=1.0, max_climb=0.5, deadband=1.0), 'deadband'),
    (HeadingHoldSettings, dict(gain=1.0, max_rate=math.inf, deadband=0.0, settle_rate=0.1,
                               settle_time=0.5), 'max_rate')])
def test_settings_name_the_bad_field(cls, settings, field):
    with pytest.raises(ValueError, match=f'^{field}'):
        cls(**settings).validate()


# -- the ROV in closed loop -----------------------------------------------------------------
def plant(scale: float, light: float) -> RigidBodyModel:
    v = sim_parameters('simulator')
    m = v['vehicle.mass'] * scale
    return RigidBodyModel(RigidBodyParams.from_mapping({
        'mass': m, 'inertia': [i * scale for i in v['vehicle.inertia']],
        'r_g': v['vehicle.r_g'], 'r_b': v['vehicle.r_b'],
        'buoyancy': m * G + light,
        'added_mass': [a * scale for a in v['vehicle.added_mass']],
        'd_lin': [d * scale for d in v['vehicle.d_lin']],
        'd_quad': [d * scale for d in v['vehicle.d_quad']]}))


def dive_and_hold(scale: float, light: float, seed: int, seconds: float = 70.0,
                  dead: str | None = None, tell: bool = True):
    """Pilot: full stick down for 3.2 s, then centred (stop, hold); a yaw turn of 2 s at 10 s;
    step disturbances at 40 and 50 s. ``dead`` stops at ``FAIL_AT`` whatever it is told; the
    allocator is told ``DETECTION_DELAY`` later (never when ``tell`` is False)."""
    rng = np.random.default_rng(seed)
    model = plant(scale, light)
    settings = VelocityControlNodeSettings.from_params({
        **{k: v for k, v in vehicle_parameters().items()},
        'kd': [0.0] * 6, 'derivative_filter': 0.02, 'goal_timeout': 1.0, 'max_gap': 0.5,
        'max_future': 0.01, 'velocity_topic': ''})
    control = VelocityController(settings.controller)
    thrusters = sim_thrusters()
    allocator = ThrustAllocator(thrusters)
    index = [th.name for th in thrusters].index(dead) if dead else -1
    depth_hold, heading_hold = DepthHold(DEPTH), HeadingHold(HEADING)
    estimator = DepthEstimator(DepthEstimatorSettings(0.05, 0.002, 0.1, 0.5))
    state = RigidBodyState.at_rest((0.0, 0.0, -0.3), yaw=0.4)
    dt, current = 0.01, (0.2, 0.0, 0.0)
    nu_dot = np.zeros(6)
    log = []
    for k in range(int(seconds / dt)):
        t = k * dt
        stamp = int(round(t * 1e9))
        # sensors
        roll, pitch, yaw = quat_to_euler(state.q)
        f = model.specific_force(state, nu_dot)
        up = float((quat_to_rotmat(state.q) @ f)[2])   # the specific force in odom's z
        estimator.predict(up - G + ACCEL_STD * rng.standard_normal(), stamp)
        if k % 5 == 0:   # 20 Hz pressure
            estimator.update(-state.p[2] + DEPTH_STD * rng.standard_normal(), DEPTH_STD ** 2,
                             stamp)
        psi = yaw + HEADING_STD * rng.standard_normal()
        # the pilot
        heave_stick = -1.0 if 1.0 <= t < 4.2 else 0.0   # 1.6 m, and 0.4 m of stop
        yaw_stick = 0.5 if 10.0 <= t < 12.0 else 0.0
        w_goal = depth_hold.step(heave_stick, -estimator.depth, dt)
        r_goal = heading_hold.step(yaw_stick, psi, float(state.nu[5]), dt)
        nu_d = np.array([0.0, 0.0, w_goal, 0.0, 0.0, r_goal])
        measured = np.array([math.nan, math.nan, estimator.vertical_velocity,
                             *state.nu[3:6].tolist()])
        # the stop's deceleration fed forward, as the node does
        accel = np.array([0.0, 0.0, depth_hold.goal_accel, 0.0, 0.0, 0.0])
        out = control.step(nu_d, measured, dt, nu_d_dot=accel, roll=roll, pitch=pitch)
        if tell and dead and t >= FAIL_AT + DETECTION_DELAY and not allocator.failed:
            allocator.fail(dead)
        thrust = allocator.allocate(out.tau)
        tau = thrust.tau_delivered
        if dead and t >= FAIL_AT:   # the hardware, whatever the allocator assumed
            tau = tau - allocator.B[:, index] * thrust.thrust[index]
        nu_before = state.nu.copy()
        # step disturbances the model does not know: a yaw moment from 40 s (a tether pulled
        # sideways), 3 N down from 50 s (a sample picked up)
        ext = [0.0, 0.0, -3.0 if t >= 50.0 else 0.0, 0.0, 0.0, 1.0 if t >= 40.0 else 0.0]
        state = model.step(state, tau, dt, tau_ext=ext, current=current)
        nu_dot = (state.nu - nu_before) / dt
        log.append((t, -state.p[2], yaw, depth_hold.target, heading_hold.target))
    return log


def settled_errors(log) -> tuple[float, float, np.ndarray]:
    """(depth error RMS [m], max heading error [deg], the heading targets) while settled:
    from 30 s (the dive, the turn and a failure at ``FAIL_AT`` long past) to the first step,
    and from 5 s after each step."""
    t = np.array([r[0] for r in log])
    depth = np.array([r[1] for r in log])
    yaw = np.array([r[2] for r in log])
    depth_target = np.array([math.nan if r[3] is None else -r[3] for r in log])
    heading_target = np.array([math.nan if r[4] is None else r[4] for r in log])
    assert 1.5 < depth_target[-1] < 2.5     # the dive went to about 2 m and was held there
    settled = ((t > 30.0) & (t < 40.0)) | ((t > 45.0) & (t < 50.0)) | (t > 55.0)
    depth_err = depth[settled] - depth_target[settled]
    heading_err = np.degrees(np.abs([ssa(a - b) for a, b in zip(yaw[settled],
                                                                  heading_target[settled])]))
    return float(np.sqrt(np.mean(depth_err ** 2))), float(heading_err.max()), heading_target


@pytest.mark.sim
@pytest.mark.parametrize('scale, light', [(1.0, 0.0), (1.3, 2.0)])
def test_the_rov_dives_and_holds_depth_and_heading_in_a_current(scale, light):
    rms, heading, heading_target = settled_errors(dive_and_hold(scale, light, seed=11))
    assert rms <= 0.02, f'depth error RMS {rms:.4f} m'
    assert heading <= 1.0, f'heading error {heading:.2f} deg'
    # the turn happened (the heading target moved by the turn, about 1 rad)
    assert abs(ssa(heading_target[-1] - 0.4)) > 0.5


def after_failure(log) -> tuple[float, float]:
    """(depth error RMS [m] from ``FAIL_AT`` to the first step, max heading error [deg] from
    ``FAIL_AT`` to the end, the yaw step included): what a lost thruster shows."""
    rows = [r for r in log if r[0] >= FAIL_AT]     # both holds engaged long before
    t = np.array([r[0] for r in rows])
    depth_err = np.array([r[1] + r[3] for r in rows])    # depth minus target (target is -z)
    heading_err = np.degrees(np.abs([ssa(r[2] - r[4]) for r in rows]))
    return (float(np.sqrt(np.mean(depth_err[t < 40.0] ** 2))), float(heading_err.max()))


@cache
def nominal_after_failure() -> tuple[float, float]:
    """``after_failure`` of the plant 30 % off on eight thrusters (deterministic)."""
    return after_failure(dive_and_hold(1.3, 2.0, seed=11))


@pytest.mark.sim
@pytest.mark.parametrize('dead', ['vert_front_left', 'front_right'])
def test_one_of_eight_thrusters_dies_in_depth_hold(dead):
    """The plant 30 % off and 2 N light; a thruster dies at 20 s, the allocator is told half a
    second later: depth and heading stay within twice their nominal errors."""
    nominal = nominal_after_failure()
    failed = after_failure(dive_and_hold(1.3, 2.0, seed=11, dead=dead))
    print(f'\n{dead}: depth RMS {failed[0] * 1e3:.1f} mm (nominal {nominal[0] * 1e3:.1f}), '
          f'heading max {failed[1]:.2f} deg (nominal {nominal[1]:.2f})')
    assert failed[0] <= 2.0 * nominal[0], (failed, nominal)
    assert failed[1] <= 2.0 * nominal[1], (failed, nominal)


@pytest.mark.sim
def test_a_dead_vertical_thruster_never_told_misses_the_bound():
    """Without telling the allocator, the hold alone (its integral) does not keep the depth
    within twice nominal: what the bound above is there to catch."""
    nominal = nominal_after_failure()
    untold = after_failure(dive_and_hold(1.3, 2.0, seed=11, seconds=40.0,
                                         dead='vert_front_left', tell=False))
    print(f'\nuntold: depth RMS {untold[0] * 1e3:.1f} mm (nominal {nominal[0] * 1e3:.1f})')
    assert untold[0] > 2.0 * nominal[0], (untold, nominal)


def stabilize_under_step(level_gain: float | None = None, seconds: float = 30.0):
    """Stabilize (no depth sensor): sticks centred, roll and pitch levelled, the heading held;
    from 10 s a payload hung off-centre pulls 2 N m in roll and -2 N m in pitch. The plant is
    30 % off the controller's model. ``level_gain`` replaces the profile's (None: keep it).
    Returns rows (t, roll, pitch, heading error) [s, rad, rad, rad]."""
    rng = np.random.default_rng(5)
    model = plant(1.3, 2.0)
    params = {**vehicle_parameters(), 'kd': [0.0] * 6, 'derivative_filter': 0.02,
              'goal_timeout': 1.0, 'max_gap': 0.5, 'max_future': 0.01, 'velocity_topic': ''}
    if level_gain is not None:
        params['level_gain'] = level_gain
    control = VelocityController(VelocityControlNodeSettings.from_params(params).controller)
    allocator = ThrustAllocator(sim_thrusters())
    heading_hold = HeadingHold(HEADING)
    state = RigidBodyState.at_rest((0.0, 0.0, -1.0), yaw=-0.7)
    dt = 0.01
    log = []
    for k in range(int(seconds / dt)):
        t = k * dt
        roll, pitch, yaw = quat_to_euler(state.q)
        psi = yaw + HEADING_STD * rng.standard_normal()
        r_goal = heading_hold.step(0.0, psi, float(state.nu[5]), dt)
        nu_d = np.array([0.0, 0.0, 0.0, 0.0, 0.0, r_goal])
        # stabilize measures no linear velocity: the linear axes are the model's feed-forward
        measured = np.array([math.nan, math.nan, math.nan, *state.nu[3:6].tolist()])
        out = control.step(nu_d, measured, dt, roll=roll, pitch=pitch)
        tau = allocator.allocate(out.tau).tau_delivered
        ext = [0.0, 0.0, 0.0, 2.0, -2.0, 0.0] if t >= 10.0 else [0.0] * 6
        state = model.step(state, tau, dt, tau_ext=ext)
        target = heading_hold.target
        log.append((t, roll, pitch, 0.0 if target is None else ssa(yaw - target)))
    return np.array(log)


@pytest.mark.sim
def test_stabilize_levels_against_a_step_moment():
    """5 s after the step, roll and pitch are back within 1 deg of level and the heading
    within 1 deg; without the leveling term the vehicle hangs at the payload's angle."""
    log = stabilize_under_step()
    after = log[log[:, 0] >= 15.0]
    tilt = np.degrees(np.abs(after[:, 1:3])).max()
    heading = np.degrees(np.abs(after[:, 3])).max()
    peak = np.degrees(np.abs(log[log[:, 0] >= 10.0][:, 1:3])).max()
    print(f'\nstabilize: peak tilt {peak:.2f} deg, then at most {tilt:.2f} deg; '
          f'heading at most {heading:.2f} deg')
    assert tilt <= 1.0 and heading <= 1.0, (tilt, heading)
    unlevelled = stabilize_under_step(level_gain=0.0)
    hang = np.degrees(np.abs(unlevelled[unlevelled[:, 0] >= 15.0][:, 1:3])).max()
    print(f'without leveling: {hang:.2f} deg')
    assert hang > 2.0 * tilt


def engage_mid_dive(scale: float, light: float, stop: bool = True, freeze: bool = True):
    """The node's pilot modes around the heave axis, as ``velocity_control_node._pilot`` runs
    them: stabilize diving at 0.3 m/s (the goal through the reference model, heave not
    measured: feed-forward only), depth hold entered at 8 s with the stick centred, the depth
    going stale at 30 s (the fallback to stabilize). ``stop`` False: the target taken at the
    instant of entry (as before the stop existed); ``freeze`` False: the heave integral
    dropped when the fallback loses the measured heave.
    Returns rows (t, depth [m], tau_z [N], depth target [m] or NaN)."""
    rng = np.random.default_rng(3)
    model = plant(scale, light)
    s = VelocityControlNodeSettings.from_params({
        **vehicle_parameters(), 'kd': [0.0] * 6, 'derivative_filter': 0.02,
        'goal_timeout': 1.0, 'max_gap': 0.5, 'max_future': 0.01, 'velocity_topic': ''})
    control = VelocityController(s.controller)
    control.freeze_lost_integral = freeze
    reference = VelocityReference(s.reference_time_constant, s.max_accel)
    allocator = ThrustAllocator(sim_thrusters())
    hold = DepthHold(DEPTH)
    estimator = DepthEstimator(DepthEstimatorSettings(0.05, 0.002, 0.1, 0.5))
    state = RigidBodyState.at_rest((0.0, 0.0, -0.3))
    dt, nu_dot, log = 0.01, np.zeros(6), []
    for k in range(int((STALE + 6.0) / dt)):
        t = k * dt
        stamp = int(round(t * 1e9))
        f = model.specific_force(state, nu_dot)
        estimator.predict(float((quat_to_rotmat(state.q) @ f)[2]) - G
                          + ACCEL_STD * rng.standard_normal(), stamp)
        if k % 5 == 0:
            estimator.update(-state.p[2] + DEPTH_STD * rng.standard_normal(), DEPTH_STD ** 2,
                             stamp)
        goal = np.array([0.0, 0.0, -0.3 if t < ENGAGE else 0.0, 0.0, 0.0, 0.0])
        nu_ref, nu_ref_dot = reference.step(goal, dt)
        nu_ref, nu_ref_dot = nu_ref.copy(), nu_ref_dot.copy()
        measured = np.array([math.nan, math.nan, math.nan, *state.nu[3:6].tolist()])
        if ENGAGE <= t < STALE:                                  # depth hold
            if k == round(ENGAGE / dt):
                hold.release()                                   # the node's _entered
            w = estimator.vertical_velocity if stop else math.nan
            nu_ref[2] = hold.step(0.0, -estimator.depth, dt, w)
            nu_ref_dot[2] = hold.goal_accel
            measured[2] = estimator.vertical_velocity
        if t >= ENGAGE:   # the reference carries on from the hold's goal (and after it)
            reference.nu_ref, reference.nu_ref_dot = nu_ref, nu_ref_dot
        out = control.step(nu_ref, measured, dt, nu_d_dot=nu_ref_dot)
        before = state.nu.copy()
        state = model.step(state, allocator.allocate(out.tau).tau_delivered, dt)
        nu_dot = (state.nu - before) / dt
        log.append((t, -state.p[2], float(out.tau[2]),
                    math.nan if hold.target is None else -hold.target))
    return np.array(log)


def around(log: np.ndarray, t: float) -> float:
    """The largest change of tau_z from one step to the next within 0.3 s of ``t`` [N]."""
    w = (log[:, 0] >= t - 0.3) & (log[:, 0] <= t + 0.3)
    return float(np.abs(np.diff(log[w, 2])).max())


@pytest.mark.sim
@pytest.mark.parametrize('scale, light', [(1.0, 0.0), (1.3, 2.0)])
def test_depth_hold_entered_mid_dive_is_bumpless(scale, light):
    """Entered while diving at 0.3 m/s: no step in the heave force, the vehicle stopped and
    then held where it stopped (no overshoot past the target); the depth lost at 30 s falls
    back to stabilize keeping the heave integral the hold had learnt. Taking the target at the
    instant of entry, as before, steps the force by the velocity loop's k_p w and overshoots;
    dropping the integral steps the force by what it carried."""
    log = engage_mid_dive(scale, light)
    entry, fallback = around(log, ENGAGE), around(log, STALE)
    held = log[(log[:, 0] > STALE - 4.0) & (log[:, 0] < STALE)]
    target = held[-1, 3]
    overshoot = float(log[(log[:, 0] >= ENGAGE) & (log[:, 0] < STALE), 1].max() - target)
    print(f'\nplant {scale}: entry step {entry:.2f} N, overshoot {overshoot * 1e3:.1f} mm, '
          f'target {target:.3f} m (entered at {log[round(ENGAGE / 0.01), 1]:.3f} m), '
          f'fallback step {fallback:.2f} N')
    assert entry < (1.0 if scale == 1.0 else 4.0), entry
    assert overshoot < 0.03, overshoot
    assert float(np.abs(held[:, 1] - target).max()) < 0.03
    assert fallback < (1.0 if scale == 1.0 else 2.0), fallback
    old = engage_mid_dive(scale, light, stop=False, freeze=False)
    old_target = old[(old[:, 0] > ENGAGE + 4.0) & (old[:, 0] < STALE)][-1, 3]
    old_overshoot = float(old[(old[:, 0] >= ENGAGE) & (old[:, 0] < STALE), 1].max()
                          - old_target)
    print(f'before: entry step {around(old, ENGAGE):.2f} N, overshoot '
          f'{old_overshoot * 1e3:.1f} mm, fallback step {around(old, STALE):.2f} N')
    assert around(old, ENGAGE) > 2.0 * entry and old_overshoot > 2.0 * overshoot
    if light:     # the integral carries the 2 N the model does not know
        dropped = around(engage_mid_dive(scale, light, freeze=False), STALE)
        print(f'integral dropped at the fallback: {dropped:.2f} N')
        assert dropped > 1.5 * fallback
