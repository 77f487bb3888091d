"""Guidance laws (pure algorithm tier): references alone, and closed loops with the observer
and the DP controller against a simulated CS Saucer.

The plant is the manual's 3-DOF model (CS Saucer manual, section 1.4), integrated here with RK4:

    eta_dot = R(psi) nu,   M nu_dot + (C(nu) + D + D_n(nu)) nu = tau + R(psi)^T b
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support import saucer_plant
from support.saucer_plant import DT, NOISE, dp_settings, observer_settings, rot, wrap

from enbarr_core.control.dp_control import DpController
from enbarr_core.estimation.dp_observer import PassiveObserver
from enbarr_core.guidance.guidance import (
    GoToWaypoint,
    HoldPose,
    LosPath,
    Reference,
    trapezoid,
)

B_WORLD = np.array([0.25, -0.15, 0.02])               # current-like world bias [N, N, N m]


def plant_step(x, tau, b=B_WORLD, dt=DT):
    """RK4 over dt with tau and b held: x = [x, y, psi, u, v, r]."""
    return saucer_plant.step(x, tau, b, dt)


def closed_loop(guidance, seconds, x0, seed=5, stop_when_finished_for=None, warmup=0.0):
    """Noisy mocap -> observer -> guidance -> controller -> plant, 50 Hz; first ``warmup``
    seconds (not logged) of holding x0's pose, so that the observer has found the bias.

    Log columns: 0 t, 1-6 true state, 7 cross-track, 8 along-track, 9 segment, 10 finished,
    11-13 eta_d, 14-16 nu_d, 17-19 tau.
    """
    rng = np.random.default_rng(seed)
    obs = PassiveObserver(observer_settings())
    ctl = DpController(dp_settings())
    x = np.array(x0, dtype=float)
    tau = np.zeros(3)
    log = []
    finished_for = 0.0
    n_warmup = int(round(warmup / DT))
    hold = HoldPose(x0[:3])
    for k in range(-n_warmup, int(round(seconds / DT))):
        est = obs.step(x[:3] + rng.normal(0.0, NOISE), tau, DT)
        law = hold if k < 0 else guidance
        ref = law.reference(est.eta_hat, DT)
        out = ctl.step(est.eta_hat, est.nu_hat, est.b_hat, ref, DT)
        tau = out.tau
        x = plant_step(x, tau)
        if k < 0:
            continue
        nan = math.nan
        log.append((k * DT, *x, nan if ref.cross_track is None else ref.cross_track,
                    nan if ref.along_track is None else ref.along_track,
                    -1 if ref.segment is None else ref.segment, ref.finished,
                    *ref.eta_d, *ref.nu_d, *tau))
        finished_for = finished_for + DT if ref.finished else 0.0
        if stop_when_finished_for is not None and finished_for >= stop_when_finished_for:
            break
    return np.array(log, dtype=float)


# --- LOS path following --------------------------------------------------------------------


def test_los_cross_track_sign_and_course():
    los = LosPath([(0.0, 0.0), (10.0, 0.0)], speed=0.2, lookahead=1.0, acceptance_radius=0.1)
    left = los.reference([2.0, 1.0, 0.0], DT)        # 1 m left of an eastward path
    assert left.cross_track == pytest.approx(1.0) and left.along_track == pytest.approx(2.0)
    assert left.eta_d[2] == pytest.approx(-math.pi / 4)   # chi_d = pi_p - atan(e / Delta)
    np.testing.assert_allclose(left.nu_d[:2], 0.2 * np.array([1.0, -1.0]) / math.sqrt(2))
    assert left.position_mask == (False, False, True)
    np.testing.assert_allclose(left.eta_d[:2], [2.0, 0.0])    # closest point on the path
    # Northward path, vessel 1 m east of it (right): e < 0, steer left (course > pi / 2).
    los = LosPath([(0.0, 0.0), (0.0, 10.0)], speed=0.2, lookahead=1.0, acceptance_radius=0.1)
    right = los.reference([1.0, 3.0, math.pi / 2], DT)
    assert right.cross_track == pytest.approx(-1.0) and right.along_track == pytest.approx(3.0)
    assert right.eta_d[2] == pytest.approx(math.pi / 2 + math.pi / 4)
    # nu_d is the desired world velocity in the body frame of the current heading.
    v_world = 0.2 * np.array([math.cos(3 * math.pi / 4), math.sin(3 * math.pi / 4)])
    np.testing.assert_allclose(right.nu_d[:2], rot(math.pi / 2)[:2, :2].T @ v_world)
    # r_d = chi_d_dot under ideal kinematics: U Delta e / (Delta^2 + e^2)^(3/2).
    assert right.nu_d[2] == pytest.approx(0.2 * 1.0 * -1.0 / 2.0 ** 1.5)


def test_los_feed_forward_matches_finite_differences():
    """A kinematic vessel that flies the LOS velocity and heading exactly: nu_d changes at the
    rate nu_d_dot says, and chi_d at the rate r_d says.
    """
    los = LosPath([(0.0, 0.0), (30.0, 5.0)], speed=0.3, lookahead=0.8, acceptance_radius=0.1)
    dt = 1e-3
    p, psi = np.array([1.0, 2.0]), 0.3
    prev = None
    e0 = math.inf
    for k in range(3000):
        ref = los.reference([p[0], p[1], psi], dt)
        if k >= 2:  # after the first call the heading jumps from 0.3 to chi_d
            fd = (ref.nu_d - prev.nu_d) / dt
            np.testing.assert_allclose(fd[:2], ref.nu_d_dot[:2], atol=2e-3)
            assert (wrap(ref.eta_d[2] - prev.eta_d[2])) / dt == pytest.approx(ref.nu_d[2],
                                                                               abs=2e-3)
        v_world = rot(psi)[:2, :2] @ ref.nu_d[:2]
        p = p + v_world * dt
        psi = ref.eta_d[2]                # heading = course (one step late: r ~ r_d)
        prev = ref
        if k == 0:
            e0 = ref.cross_track
    assert 0.0 < ref.cross_track < 0.7 * e0   # converging onto the path from its left


def test_los_converges_to_a_straight_line_in_closed_loop():
    los = LosPath([(0.0, 0.0), (12.0, 0.0)], speed=0.2, lookahead=0.6, acceptance_radius=0.15)
    log = closed_loop(los, 60.0, [0.0, 1.0, -0.5, 0.0, 0.0, 0.0])
    t, e = log[:, 0], log[:, 7]
    assert e[0] == pytest.approx(1.0, abs=0.02)
    assert np.all(np.abs(e[t > 25.0]) < 0.03)           # on the line
    assert np.all(e > -0.05)                             # no overshoot across it
    e_true = log[:, 2]                                   # cross-track of the true position
    assert np.sqrt(np.mean(e_true[t > 30.0] ** 2)) < 0.01
    speed = np.hypot(log[:, 4], log[:, 5])
    assert np.mean(speed[t > 30.0]) == pytest.approx(0.2, abs=0.01)
    np.testing.assert_allclose(wrap(log[t > 30.0, 3]), 0.0, atol=0.05)  # heading = course


def test_box_is_completed_with_small_cross_track_error():
    """2 m x 2 m box at 0.2 m/s, corners (0,0) (2,0) (2,2) (0,2) and back, heading = course."""
    box = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)]
    los = LosPath(box, speed=0.2, lookahead=0.5, acceptance_radius=0.15)
    log = closed_loop(los, 80.0, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], stop_when_finished_for=15.0)
    following = log[:, 10] == 0.0
    rms = np.sqrt(np.mean(log[following, 7] ** 2))
    assert rms < 0.1
    assert np.abs(log[following, 7]).max() < 0.2
    # Each segment in order, the whole box, then holding the last waypoint.
    segments = log[:, 9].astype(int)
    assert list(dict.fromkeys(segments)) == [0, 1, 2, 3]
    t_finish = log[np.argmax(log[:, 10] == 1.0), 0]
    assert 35.0 < t_finish < 50.0                         # 8 m at 0.2 m/s is 40 s
    assert log[-1, 10] == 1.0 and los.finished
    assert np.hypot(log[-1, 1], log[-1, 2]) < 0.03        # holding (0, 0)
    # The corners were visited: the true path passed near each of them.
    for cx, cy in box[1:4]:
        assert np.hypot(log[:, 1] - cx, log[:, 2] - cy).min() < 0.2
    # The thrusters were not pinned at their limits along the way.
    assert np.mean(np.abs(log[following, 17:19]) >= 1.999) < 0.05


def test_box_with_fixed_heading():
    box = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)]
    los = LosPath(box, speed=0.2, lookahead=0.5, acceptance_radius=0.15, heading='fixed')
    log = closed_loop(los, 80.0, [0.0, 0.0, 0.7, 0.0, 0.0, 0.0], stop_when_finished_for=10.0)
    following = log[:, 10] == 0.0
    assert np.sqrt(np.mean(log[following, 7] ** 2)) < 0.1
    assert los.finished and los.fixed_heading == pytest.approx(0.7, abs=0.05)
    np.testing.assert_allclose(wrap(log[:, 3] - los.fixed_heading), 0.0, atol=0.05)


def test_segment_switching_and_finished():
    los = LosPath([(0.0, 0.0), (4.0, 0.0), (4.0, 4.0)], speed=0.2, lookahead=1.0,
                  acceptance_radius=0.3)
    assert los.reference([1.0, 0.2, 0.0], DT).segment == 0
    ref = los.reference([3.75, 0.1, 0.0], DT)             # within 0.3 m of (4, 0)
    assert ref.segment == 1 and los.segment == 1
    assert ref.cross_track == pytest.approx(-(3.75 - 4.0))    # e on the new segment
    assert not ref.finished
    ref = los.reference([3.9, 5.0, 1.5], DT)              # past (4, 4) along-track
    assert ref.finished and los.finished
    assert ref.position_mask == (True, True, True)
    np.testing.assert_allclose(ref.eta_d, [4.0, 4.0, math.pi / 2])   # last path angle
    np.testing.assert_allclose(ref.nu_d, 0.0)
    assert los.reference([0.0, 0.0, 0.0], DT).finished   # stays finished
    # Past the end of the first segment without entering the circle also switches, and a
    # jump past several segments skips them all in one call.
    los = LosPath([(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0)], speed=0.2, lookahead=1.0,
                  acceptance_radius=0.0)
    assert los.reference([2.5, 1.0, 0.0], DT).segment == 2


# --- GoToWaypoint ------------------------------------------------------------------------


def test_trapezoid_profile():
    for v, a in ((0.5, 0.1), (0.1, 0.05), (10.0, 0.2)):   # cruise, cruise, triangle
        t = np.arange(0.0, 60.0, 1e-3)
        s, sd, sdd = np.array([trapezoid(ti, v, a) for ti in t]).T
        assert s[0] == 0.0 and s[-1] == 1.0
        assert np.all(np.diff(s) >= 0.0)
        assert sd.max() <= v + 1e-12 and np.abs(sdd).max() <= a + 1e-12
        np.testing.assert_allclose(np.gradient(s, t)[1:-1], sd[1:-1], atol=2e-3)
        if v >= math.sqrt(a):
            assert sd.max() == pytest.approx(math.sqrt(a), rel=1e-3)     # triangle peak


def test_go_to_waypoint_reference_respects_the_limits():
    speed, accel = 0.25, 0.05
    start = np.array([1.0, -1.0, 0.3])
    goto = GoToWaypoint(start, (4.0, 3.0), speed, accel)
    assert goto.length == pytest.approx(5.0)
    refs = [goto.reference(start, DT) for _ in range(int(40.0 / DT))]
    eta_d = np.array([r.eta_d for r in refs])
    nu_d = np.array([r.nu_d for r in refs])
    nu_d_dot = np.array([r.nu_d_dot for r in refs])
    # World velocity of the reference from finite differences: along the line, <= speed.
    v = np.diff(eta_d[:, :2], axis=0) / DT
    assert np.hypot(*v.T).max() <= speed + 1e-9
    assert np.hypot(*(np.diff(v, axis=0) / DT).T).max() <= accel + 1e-6
    np.testing.assert_allclose(4.0 * v[:, 0] - 3.0 * v[:, 1], 0.0, atol=1e-9)  # on the line
    assert np.hypot(*nu_d[:, :2].T).max() == pytest.approx(speed)          # cruise reached
    # nu_d = R(psi_d)^T eta_d_dot (heading held, so R is constant).
    np.testing.assert_allclose(rot(0.3)[:2, :2] @ nu_d[1:-1, :2].T,
                               0.5 * (v[1:] + v[:-1]).T, atol=3e-3)
    assert np.hypot(*nu_d_dot[:, :2].T).max() == pytest.approx(accel, rel=1e-9)
    np.testing.assert_allclose(eta_d[:, 2], 0.3)
    # Duration: t_a = v / a = 5 s (0.625 m each ramp), cruise 3.75 m / 0.25 = 15 s: 25 s.
    assert goto.duration == pytest.approx(25.0)
    np.testing.assert_allclose(eta_d[-1], [4.0, 3.0, 0.3])
    np.testing.assert_allclose(nu_d[-1], 0.0)
    assert refs[-1].finished is False                     # the vessel is not there yet
    assert refs[-1].position_mask == (True, True, True)


def test_go_to_waypoint_turns_heading_within_its_limits():
    goto = GoToWaypoint([0.0, 0.0, 3.0], (0.2, 0.0, -3.0), 0.2, 0.1, yaw_rate=0.1,
                        yaw_accel=0.05)
    refs = [goto.reference([0.0, 0.0, 3.0], DT) for _ in range(int(20.0 / DT))]
    psi = np.unwrap([r.eta_d[2] for r in refs])
    assert psi[-1] - 3.0 == pytest.approx(2.0 * math.pi - 6.0)   # short way round through pi
    r_d = np.array([r.nu_d[2] for r in refs])
    assert r_d.max() <= 0.1 + 1e-12 and np.abs(np.diff(r_d) / DT).max() <= 0.05 + 1e-9
    np.testing.assert_allclose(np.diff(psi) / DT, 0.5 * (r_d[1:] + r_d[:-1]), atol=1e-3)
    # A pure rotation (same position) works, and zero motion finishes at once.
    assert GoToWaypoint([0.0, 0.0, 0.0], (0.0, 0.0, 1.0), 0.2, 0.1).duration > 0.0
    still = GoToWaypoint([1.0, 1.0, 0.0], (1.0, 1.0), 0.2, 0.1)
    assert still.duration == 0.0 and still.reference([1.0, 1.0, 0.0], DT).finished


def test_go_to_waypoint_closed_loop_reaches_and_holds():
    start = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    goto = GoToWaypoint(start[:3], (2.0, 1.0, math.pi / 2), speed=0.15, accel=0.05)
    log = closed_loop(goto, goto.duration + 20.0, start, warmup=20.0)
    t = log[:, 0]
    track = np.hypot(log[:, 1] - log[:, 11], log[:, 2] - log[:, 12])
    assert track.max() < 0.02                              # follows the moving reference
    assert np.abs(log[:, 7]).max() < 0.02                  # and stays on the line
    speed = np.hypot(log[:, 4], log[:, 5])
    assert speed.max() < 0.15 * 1.1
    finished = log[:, 10] == 1.0
    assert finished.any() and finished[-1]
    t_done = t[np.argmax(finished)]
    assert goto.duration - DT <= t_done < goto.duration + 5.0  # log t lags the clock by dt
    end = log[-1]
    assert math.hypot(end[1] - 2.0, end[2] - 1.0) < 0.02
    assert abs(wrap(end[3] - math.pi / 2)) < 0.02


# --- HoldPose and validation ---------------------------------------------------------------


def test_hold_pose():
    ref = HoldPose([1.0, 2.0, 7.0]).reference([0.0, 0.0, 0.0], DT)
    assert isinstance(ref, Reference)
    np.testing.assert_allclose(ref.eta_d, [1.0, 2.0, 7.0 - 2.0 * math.pi])
    np.testing.assert_array_equal(ref.nu_d, 0.0)
    np.testing.assert_array_equal(ref.nu_d_dot, 0.0)
    assert ref.position_mask == (True, True, True)


@pytest.mark.parametrize('kwargs, match', [
    (dict(waypoints=[(0.0, 0.0)]), 'waypoints'),
    (dict(waypoints=[(0.0, 0.0), (0.0, 0.0)]), 'waypoints'),
    (dict(waypoints=[(0.0, 0.0, 0.0), (1.0, 0.0, 0.0)]), 'waypoints'),
    (dict(waypoints=[(0.0, 0.0), (math.nan, 1.0)]), 'waypoints'),
    (dict(speed=0.0), 'speed'),
    (dict(speed=math.inf), 'speed'),
    (dict(lookahead=-1.0), 'lookahead'),
    (dict(acceptance_radius=-0.1), 'acceptance_radius'),
    (dict(heading='north'), 'heading'),
    (dict(fixed_heading=1.0), 'fixed_heading'),
])
def test_los_validation_names_the_field(kwargs, match):
    args = dict(waypoints=[(0.0, 0.0), (1.0, 0.0)], speed=0.2, lookahead=0.5,
                acceptance_radius=0.1) | kwargs
    with pytest.raises(ValueError, match=match):
        LosPath(**args)


@pytest.mark.parametrize('kwargs, match', [
    (dict(start_eta=[0.0, 0.0]), 'start_eta'),
    (dict(waypoint=(1.0,)), 'waypoint'),
    (dict(waypoint=(1.0, math.inf)), 'waypoint'),
    (dict(speed=-0.1), 'speed'),
    (dict(accel=0.0), 'accel'),
    (dict(yaw_rate=0.0), 'yaw_rate'),
    (dict(arrival_radius=0.0), 'arrival_radius'),
])
def test_go_to_validation_names_the_field(kwargs, match):
    args = dict(start_eta=[0.0, 0.0, 0.0], waypoint=(1.0, 0.0), speed=0.2, accel=0.1) | kwargs
    with pytest.raises(ValueError, match=match):
        GoToWaypoint(**args)


@pytest.mark.parametrize('law', [
    HoldPose([0.0, 0.0, 0.0]),
    GoToWaypoint([0.0, 0.0, 0.0], (1.0, 0.0), 0.2, 0.1),
    LosPath([(0.0, 0.0), (1.0, 0.0)], 0.2, 0.5, 0.1),
])
def test_bad_dt_raises(law):
    for dt in (0.0, -0.02, math.nan):
        with pytest.raises(ValueError, match='dt'):
            law.reference([0.0, 0.0, 0.0], dt)


# -- gaps found by the mutation run (docs/testing.md) ------------------------------------------


def test_go_to_waypoint_feed_forward_matches_finite_differences_while_turning():
    """Moving and turning at once: nu_d = R(psi_d)^T eta_d_dot changes at the rate nu_d_dot
    says, including the r_d terms of d/dt R^T. Central differences at dt = 1 ms have an error
    of dt^2/6 |nu_d'''| < 1e-6 away from the profile's corners (where the acceleration steps;
    those samples are skipped); the r_d terms are r_d |v| ~ 0.05 * 0.2 = 1e-2.
    """
    dt = 1e-3
    goto = GoToWaypoint([1.0, -2.0, 0.4], (3.0, -1.0, 1.4), 0.2, 0.1, yaw_rate=0.1,
                        yaw_accel=0.05)
    refs = [goto.reference([1.0, -2.0, 0.4], dt) for _ in range(int(goto.duration / dt))]
    nu_d = np.array([r.nu_d for r in refs])
    nu_d_dot = np.array([r.nu_d_dot for r in refs])
    fd = (nu_d[2:] - nu_d[:-2]) / (2 * dt)
    smooth = np.all(np.abs(nu_d_dot[2:] - nu_d_dot[:-2]) < 1e-3, axis=1)  # not at a corner
    assert smooth.sum() > 0.9 * len(smooth)
    np.testing.assert_allclose(fd[smooth], nu_d_dot[1:-1][smooth], atol=1e-5)
    assert np.abs(nu_d[:, 2] * np.hypot(*nu_d[:, :2].T)).max() > 5e-3  # the r_d terms matter


def test_go_to_waypoint_along_and_cross_track_by_hand():
    # start (1, 2) -> (4, 6): length 5, direction (0.6, 0.8); left normal (-0.8, 0.6)
    goto = GoToWaypoint([1.0, 2.0, 0.0], (4.0, 6.0), 0.2, 0.1)
    ref = goto.reference([1.0 + 2 * 0.6 - 0.5 * 0.8, 2.0 + 2 * 0.8 + 0.5 * 0.6, 0.0], DT)
    assert (ref.along_track, ref.cross_track) == pytest.approx((2.0, 0.5), abs=1e-12)
    assert ref.segment == 0
    # a leg shorter than 1 m is a leg too: (0, 0) -> (0.3, 0.4), length 0.5
    short = GoToWaypoint([0.0, 0.0, 0.0], (0.3, 0.4), 0.2, 0.1)
    ref = short.reference([0.25 * 0.6 - 0.1 * 0.8, 0.25 * 0.8 + 0.1 * 0.6, 0.0], DT)
    assert (ref.along_track, ref.cross_track) == pytest.approx((0.25, 0.1), abs=1e-12)
    # no leg (already there): both zero wherever the vessel is
    still = GoToWaypoint([1.0, 1.0, 0.0], (1.0, 1.0), 0.2, 0.1)
    ref = still.reference([3.0, -2.0, 0.0], DT)
    assert (ref.along_track, ref.cross_track) == (0.0, 0.0)


@pytest.mark.parametrize('where, finished', [
    ((4.0, 6.25), True),          # exactly arrival_radius (0.25 m) away: arrived
    ((3.75, 6.0), True),
    ((4.0, 6.5), False),          # 0.5 m off in y only
    ((4.5, 6.0), False),          # 0.5 m off in x only
])
def test_go_to_waypoint_arrival_is_a_circle(where, finished):
    goto = GoToWaypoint([1.0, 2.0, 0.0], (4.0, 6.0), 0.2, 0.1, arrival_radius=0.25)
    ref = goto.reference([*where, 0.0], goto.duration + 1.0)   # the profile has ended
    assert ref.finished is finished and goto.finished is finished


def test_go_to_waypoint_names_a_bad_pose():
    goto = GoToWaypoint([0.0, 0.0, 0.0], (1.0, 0.0), 0.2, 0.1)
    with pytest.raises(ValueError, match=r'^eta_hat: expected 3 values'):
        goto.reference([0.0, 0.0], DT)


@pytest.mark.parametrize('kwargs, match', [
    (dict(start_eta=[0.0, 0.0]), r'^start_eta: expected 3 values'),
    (dict(waypoint=None), r'^waypoint: must be \(x, y\) or \(x, y, psi\), got None$'),
    (dict(speed=-0.1), r'^speed: must be finite and > 0'),
    (dict(accel=0.0), r'^accel: must be finite and > 0'),
    (dict(yaw_rate=0.0), r'^yaw_rate: must be finite and > 0'),
    (dict(yaw_accel=math.inf), r'^yaw_accel: must be finite and > 0'),
    (dict(arrival_radius=0.0), r'^arrival_radius: must be finite and > 0'),
])
def test_go_to_errors_start_with_the_field(kwargs, match):
    args = dict(start_eta=[0.0, 0.0, 0.0], waypoint=(1.0, 0.0), speed=0.2, accel=0.1) | kwargs
    with pytest.raises(ValueError, match=match):
        GoToWaypoint(**args)


def test_go_to_waypoint_defaults_are_the_documented_ones():
    goto = GoToWaypoint([0.0, 0.0, 0.0], (1.0, 0.0), 0.2, 0.1)
    assert (goto.yaw_rate, goto.yaw_accel, goto.arrival_radius) == (0.2, 0.2, 0.1)


def test_los_names_a_bad_pose():
    los = LosPath([(0.0, 0.0), (1.0, 0.0)], 0.2, 0.5, 0.1)
    with pytest.raises(ValueError, match=r'^eta_hat: expected 3 values'):
        los.reference([0.0, 0.0], DT)


# A path that does not start at the origin, on a diagonal: (2, 1) -> (10, 7) is 10 m long,
# direction (0.8, 0.6), left normal (-0.6, 0.8); then north to (10, 15).
DIAGONAL = [(2.0, 1.0), (10.0, 7.0), (10.0, 15.0)]


def test_los_track_and_closest_point_by_hand_off_the_origin():
    los = LosPath(DIAGONAL, speed=0.3, lookahead=1.0, acceptance_radius=0.5)
    x, y = 2.0 + 3.0 * 0.8 - 0.5 * 0.6, 1.0 + 3.0 * 0.6 + 0.5 * 0.8   # 3 m along, 0.5 m left
    ref = los.reference([x, y, 0.0], DT)
    assert (ref.along_track, ref.cross_track) == pytest.approx((3.0, 0.5), abs=1e-12)
    np.testing.assert_allclose(ref.eta_d[:2], [2.0 + 3.0 * 0.8, 1.0 + 3.0 * 0.6], atol=1e-12)
    assert ref.segment == 0 and not ref.finished


def test_los_switches_inside_the_circle_around_the_segment_end():
    los = LosPath(DIAGONAL, speed=0.3, lookahead=1.0, acceptance_radius=0.5)
    # (9.8, 6.6): 9.6 m along (not past the end), 0.447 m from (10, 7): switch
    assert los.reference([9.8, 6.6, 0.0], DT).segment == 1


@pytest.mark.parametrize('where, segment', [
    ((11.625, 0.5), 1),      # 9.625 m along, exactly 0.625 m from (12, 1): inside
    ((12.0, 4.0), 1),        # exactly at the end along-track (s = length), far off: past it
    ((11.5, 2.0), 0),        # short of the end and outside the circle
])
def test_los_switching_boundaries(where, segment):
    los = LosPath([(2.0, 1.0), (12.0, 1.0), (12.0, 11.0)], speed=0.3, lookahead=1.0,
                  acceptance_radius=0.625)
    assert los.reference([*where, 0.0], DT).segment == segment


def test_los_finished_reference_keeps_the_track_metrics():
    los = LosPath([(2.0, 1.0), (12.0, 1.0)], speed=0.3, lookahead=1.0, acceptance_radius=0.1)
    ref = los.reference([12.5, 1.25, 0.0], DT)           # 10.5 m along, 0.25 m left
    assert ref.finished is True and ref.segment == 0
    assert (ref.along_track, ref.cross_track) == pytest.approx((10.5, 0.25), abs=1e-12)
    ref = los.reference([3.0, 1.0, 0.0], DT)             # not finished again
    assert ref.finished is True


def test_los_feed_forward_with_the_heading_off_the_course():
    """The vessel turns at r_d but points 0.5 rad off the course, so it moves partly sideways:
    the r_d [[-s, c], [-c, -s]] v term of nu_d_dot is r_d U sin(0.5) ~ 7e-3 and its sign
    matters. Central differences at dt = 1 ms with psi integrating r_d exactly: error
    dt^2/6 |nu_d'''| < 1e-6, so 1e-5 is the bound.
    """
    los = LosPath([(0.0, 0.0), (30.0, 0.0)], speed=0.3, lookahead=0.8, acceptance_radius=0.1)
    dt = 1e-3
    p = np.array([1.0, 2.0])
    chi0 = -math.atan(2.0 / 0.8)
    psi = chi0 + 0.5
    refs = []
    for _ in range(2000):
        ref = los.reference([p[0], p[1], psi], dt)
        refs.append(ref)
        p = p + rot(psi)[:2, :2] @ ref.nu_d[:2] * dt
        psi = psi + ref.nu_d[2] * dt
    nu_d = np.array([r.nu_d for r in refs])
    nu_d_dot = np.array([r.nu_d_dot for r in refs])
    fd = (nu_d[2:, :2] - nu_d[:-2, :2]) / (2 * dt)
    np.testing.assert_allclose(fd, nu_d_dot[1:-1, :2], atol=1e-5)
    assert np.abs(nu_d[:, 1]).min() > 0.1 and np.abs(nu_d[:, 2]).max() > 0.03


def test_go_to_waypoint_short_leg_and_pure_turn_durations_by_hand():
    """Trapezoids worked by hand. A 0.5 m leg at 0.2 m/s, 0.1 m/s^2: 2 s up (0.2 m), 0.5 s
    cruise (0.1 m), 2 s down: 4.5 s. A 0.5 rad turn in place at 0.2 rad/s, 0.1 rad/s^2: the
    same numbers in radians, 4.5 s."""
    leg = GoToWaypoint([1.0, 1.0, 0.0], (1.3, 1.4), 0.2, 0.1)
    assert leg.duration == pytest.approx(4.5, rel=1e-12)
    turn = GoToWaypoint([1.0, 1.0, 0.0], (1.0, 1.0, 0.5), 0.2, 0.1, yaw_rate=0.2,
                        yaw_accel=0.1)
    assert turn.duration == pytest.approx(4.5, rel=1e-12)


@pytest.mark.parametrize('waypoints, match', [
    ([(0.0, 0.0), ('a', 1.0)], r'^waypoints: must be a list of \(x, y\), got '),
    ([(0.0, 0.0), (math.inf, 1.0)], r'^waypoints: must be finite$'),
    ([(0.0, 0.0), (1.0, 0.0), (1.0, 0.0)],
     r'^waypoints: points 1 and 2 coincide \(zero-length segment\)$'),
])
def test_los_waypoint_errors_say_which(waypoints, match):
    with pytest.raises(ValueError, match=match):
        LosPath(waypoints, 0.2, 0.5, 0.1)


def test_hold_pose_is_finished_from_the_start():
    ref = HoldPose([1.0, 2.0, 0.5]).reference([0.0, 0.0, 0.0], DT)
    assert ref.finished is True


def test_los_fixed_heading_given_is_held_wrapped():
    los = LosPath([(0.0, 0.0), (10.0, 0.0)], 0.2, 0.5, 0.1, heading='fixed', fixed_heading=7.0)
    ref = los.reference([1.0, 0.5, 0.3], DT)             # the vessel's own heading: 0.3
    assert ref.eta_d[2] == pytest.approx(7.0 - 2 * math.pi, abs=1e-12) and ref.nu_d[2] == 0.0
    with pytest.raises(ValueError, match=r'^fixed_heading: must be finite, got nan$'):
        LosPath([(0.0, 0.0), (1.0, 0.0)], 0.2, 0.5, 0.1, heading='fixed',
                fixed_heading=math.nan)
    with pytest.raises(ValueError, match=r"^fixed_heading: only with heading='fixed'$"):
        LosPath([(0.0, 0.0), (1.0, 0.0)], 0.2, 0.5, 0.1, fixed_heading=1.0)


@pytest.mark.parametrize('kwargs, match', [
    (dict(speed='fast'), r"^speed: must be a number, got 'fast'$"),
    (dict(speed=0.0), r'^speed: must be finite and > 0, got 0.0$'),
    (dict(lookahead=-1.0), r'^lookahead: must be finite and > 0, got -1.0$'),
    (dict(acceptance_radius=-0.1), r'^acceptance_radius: must be finite and >= 0, got -0.1$'),
])
def test_los_errors_start_with_the_field(kwargs, match):
    args = dict(waypoints=[(0.0, 0.0), (1.0, 0.0)], speed=0.2, lookahead=0.5,
                acceptance_radius=0.1) | kwargs
    with pytest.raises(ValueError, match=match):
        LosPath(**args)


def test_los_starts_on_the_first_segment_with_no_track_error():
    los = LosPath([(0.0, 0.0), (1.0, 0.0)], 0.2, 0.5, 0.1)
    assert (los.segment, los.cross_track, los.along_track, los.finished) == (0, 0.0, 0.0, False)
