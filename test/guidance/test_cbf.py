"""Guidance-level CBF safety filter (pure algorithm tier): the QP against a second solver
(quadprog), the barrier condition, identity and continuity, the infeasible case, and closed
loops (observer -> guidance -> filter -> DP controller -> the CS Saucer's 3-DOF model) over
randomized obstacles on a straight and a box path, also with the plant 30 % off the model.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import quadprog
from support.saucer_plant import DT, NOISE, dp_settings, observer_settings, vessel_params

from enbarr_core.control.dp_control import DpController
from enbarr_core.estimation.dp_observer import PassiveObserver
from enbarr_core.guidance.cbf import (
    blind_reason, CbfSettings, constraints, obstacle_rows, SafetyFilter, solve_qp)
from enbarr_core.guidance.guidance import GoToWaypoint, HoldPose, LosPath, Reference
from enbarr_core.models.vessel3dof import Vessel3Dof, Vessel3DofParams

# The Saucer: a round hull; the azimuths sit on its rim at 0.1375 m (saucer_core.yaml).
VESSEL_RADIUS = 0.1375
SETTINGS = CbfSettings(safety_radius=0.2, vessel_radius=VESSEL_RADIUS, tracking_margin=0.2,
                       gamma=0.5, max_speed=0.3)


def circle(x, y, r, vx=0.0, vy=0.0):
    return [x, y, x, y, r, vx, vy]


def rows(*obstacles):
    return np.array(obstacles, dtype=float).reshape(-1, 7)


def clearance(p, obstacle_rows_now):
    """Distance from the hull (a circle about p) to the nearest obstacle surface [m]."""
    bare = CbfSettings(safety_radius=0.0, vessel_radius=VESSEL_RADIUS, tracking_margin=0.0)
    _, _, B = constraints(np.asarray(p[:2], dtype=float), obstacle_rows_now, bare)
    return float(B.min()) if len(B) else math.inf


# --- the QP --------------------------------------------------------------------------------


def quadprog_solution(v_nom, n, b, max_speed):
    """The same QP written for quadprog: min 1/2 v^T v - v_nom^T v s.t. C^T v >= b."""
    k = np.arange(8) * math.pi / 8
    a = np.column_stack((np.cos(k), np.sin(k)))
    limit = max_speed * math.cos(math.pi / 16)
    C = np.vstack((n, a, -a))
    lower = np.concatenate((b, np.full(8, -limit), np.full(8, -limit)))
    try:
        return quadprog.solve_qp(np.eye(2), np.asarray(v_nom, dtype=float), C.T, lower, 0)[0]
    except ValueError:   # quadprog: "constraints are inconsistent, no solution"
        return None


def random_instance(rng, moving):
    """A QP of the filter's shape: p_d, up to 10 capsules around it, a nominal velocity."""
    p = rng.uniform(-1.0, 1.0, 2)
    k = int(rng.integers(0, 11))
    obstacles = []
    for _ in range(k):
        x, y = p + rng.uniform(-2.0, 2.0, 2)
        x2, y2 = (x, y) if rng.random() < 0.5 else (x, y) + rng.uniform(-1.0, 1.0, 2)
        v = rng.uniform(-0.3, 0.3, 2) if moving else (0.0, 0.0)
        obstacles.append([x, y, x2, y2, rng.uniform(0.0, 0.5), *v])
    v_nom = rng.uniform(-0.35, 0.35, 2)
    return p, rows(*obstacles), v_nom


@pytest.mark.parametrize('moving', [False, True])
def test_qp_answer_equals_quadprogs(moving):
    rng = np.random.default_rng(11 if moving else 7)
    solved = infeasible = 0
    for _ in range(400):
        p, obs, v_nom = random_instance(rng, moving)
        n, b, _ = constraints(p, obs, SETTINGS)
        ours = solve_qp(v_nom, n, b, SETTINGS.max_speed)
        theirs = quadprog_solution(v_nom, n, b, SETTINGS.max_speed)
        if theirs is None:
            assert not ours.feasible
            infeasible += 1
            continue
        assert ours.feasible
        np.testing.assert_allclose(ours.v, theirs, atol=1e-6)
        solved += ours.solved
    assert solved > 100                       # many instances needed the QP
    assert infeasible > 5                     # and both solvers saw infeasible ones


def test_closed_form_of_one_violated_barrier_equals_daqps_answer(monkeypatch):
    """A projection on one violated barrier is daqp's answer wherever it is used."""
    from enbarr_core.guidance import cbf
    rng = np.random.default_rng(19)
    daqp_calls = []
    solve = cbf._DaqpRows.solve

    def counted(self, *args):
        daqp_calls.append(args)
        return solve(self, *args)

    monkeypatch.setattr(cbf._DaqpRows, 'solve', counted)
    closed = 0
    for _ in range(1500):
        p, obs, v_nom = random_instance(rng, moving=True)
        n, b, _ = constraints(p, obs, SETTINGS)
        cons = [(float(nx), float(ny), float(bi), 0.0) for (nx, ny), bi in zip(n, b)]
        before = len(daqp_calls)
        ours = cbf._solve_qp(float(v_nom[0]), float(v_nom[1]), cons, SETTINGS.max_speed)
        if not ours.solved or len(daqp_calls) > before:
            continue
        closed += 1
        limit = SETTINGS.max_speed * math.cos(math.pi / 16)
        vx, vy, flag = cbf._daqp_rows(len(cons)).solve(float(v_nom[0]), float(v_nom[1]),
                                                       cons, limit)
        assert flag == 1
        assert (ours.vx, ours.vy) == pytest.approx((vx, vy), abs=1e-9)
        assert ours.active >= 1
    assert closed > 100                 # the closed form answered many
    assert len(daqp_calls) > 100        # and daqp the rest


def test_returned_velocity_meets_the_barrier_condition_and_the_speed_limit():
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(400):
        p, obs, v_nom = random_instance(rng, moving=True)
        n, b, B = constraints(p, obs, SETTINGS)
        qp = solve_qp(v_nom, n, b, SETTINGS.max_speed)
        if not qp.feasible:
            continue
        checked += 1
        # dB_i/dt = n_i^T (v - v_o,i) >= -gamma B_i, written out from the rows once more
        for i, (x, y, x2, y2, r, vx, vy) in enumerate(obs):
            d = np.array((x2 - x, y2 - y))
            s = 0.0 if d @ d == 0 else min(1.0, max(0.0, (p - (x, y)) @ d / (d @ d)))
            c = np.array((x, y)) + s * d
            n_i = (p - c) / np.linalg.norm(p - c)
            B_i = np.linalg.norm(p - c) - r - SETTINGS.margin
            assert B_i == pytest.approx(B[i])
            assert n_i @ (qp.v - (vx, vy)) >= -SETTINGS.gamma * B_i - 1e-6
        assert np.linalg.norm(qp.v) <= SETTINGS.max_speed + 1e-9
    assert checked > 250


def test_discrete_step_keeps_a_static_barrier_decaying_no_faster_than_gamma():
    """B(p + dt v) >= (1 - gamma dt) B(p): the convexity argument of the docstring."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        p, obs, v_nom = random_instance(rng, moving=False)
        n, b, B = constraints(p, obs, SETTINGS)
        qp = solve_qp(v_nom, n, b, SETTINGS.max_speed)
        if not qp.feasible:   # inside two zones at once: no way out at gamma's rate
            continue
        _, _, B_next = constraints(p + DT * qp.v, obs, SETTINGS)
        assert np.all(B_next >= (1.0 - SETTINGS.gamma * DT) * B - 1e-9)


# --- the filter ----------------------------------------------------------------------------


def test_identity_when_far():
    far = rows(circle(50.0, 50.0, 1.0), [-40.0, 0.0, -40.0, 10.0, 0.2, 0.0, 0.0])
    laws = [HoldPose((0.3, -0.2, 1.0)),
            GoToWaypoint((0.0, 0.0, 0.0), (2.0, 1.0, 0.5), 0.2, 0.05),
            LosPath([(0.0, 0.0), (3.0, 0.0), (3.0, 3.0)], 0.2, 0.5, 0.1, heading='course')]
    rng = np.random.default_rng(2)
    for law in laws:
        f = SafetyFilter(SETTINGS)
        for k in range(300):
            eta = np.array((0.01 * k, 0.3 * math.sin(0.05 * k), 0.1)) + rng.normal(0, 0.01, 3)
            nominal = law.reference(eta, DT)
            out = f.step(eta, nominal, far, DT)
            assert out.reference is nominal and not out.engaged and not out.solved
            assert out.min_barrier > 30.0


def test_no_obstacles_is_identity():
    law = LosPath([(0.0, 0.0), (3.0, 0.0)], 0.2, 0.5, 0.1)
    f = SafetyFilter(SETTINGS)
    eta = np.array((0.5, 0.2, 0.0))
    nominal = law.reference(eta, DT)
    out = f.step(eta, nominal, rows(), DT)
    assert out.reference is nominal and out.min_barrier == math.inf


def test_infeasible_returns_zero_velocity_at_the_present_desired_position_with_a_reason():
    # Two obstacles closing in from both sides faster than the desired position may move.
    squeeze = rows(circle(-0.6, 0.0, 0.1, vx=0.5), circle(0.6, 0.0, 0.1, vx=-0.5))
    f = SafetyFilter(SETTINGS)
    hold = HoldPose((0.0, 0.0, 0.3))
    eta = np.array((0.0, 0.0, 0.3))
    out = f.step(eta, hold.reference(eta, DT), squeeze, DT)
    assert out.infeasible and out.engaged and 'infeasible' in out.reason
    np.testing.assert_array_equal(out.reference.nu_d[:2], [0.0, 0.0])
    np.testing.assert_allclose(out.reference.eta_d, [0.0, 0.0, 0.3])
    assert out.reference.position_mask == (True, True, True)
    assert f.infeasible_count == 1
    out = f.step(eta, hold.reference(eta, DT), squeeze, DT)
    np.testing.assert_allclose(out.reference.eta_d[:2], [0.0, 0.0])  # did not move
    assert f.infeasible_count == 2


def test_head_on_obstacle_pushes_the_hold_away_in_time():
    """A boat coming straight at a held pose (slower than max_speed): p_d gives way (backs
    off, then slides aside to let it pass), B_i never decays faster than gamma, and the hold
    is taken up again."""
    f = SafetyFilter(SETTINGS)
    hold = HoldPose((0.0, 0.0, 0.0))
    boat = rows(circle(3.0, 0.0, 0.2, vx=-0.2))
    eta = np.array((0.0, 0.0, 0.0))
    last_B, furthest = None, 0.0
    for _ in range(int(30.0 / DT)):
        out = f.step(eta, hold.reference(eta, DT), boat, DT)
        assert not out.infeasible
        if last_B is not None:
            assert out.min_barrier >= (1.0 - SETTINGS.gamma * DT) * last_B - 1e-6
        last_B = out.min_barrier
        eta = out.reference.eta_d.copy()    # an ideal vessel on p_d
        furthest = max(furthest, float(np.hypot(*eta[:2])))
        boat[:, 0:4] += DT * np.tile(boat[:, 5:7], 2)
    assert last_B >= 0.0
    assert furthest > 0.5                   # it went out of the way
    assert not out.engaged                  # and back to the hold once the boat had passed
    np.testing.assert_array_equal(out.reference.eta_d, [0.0, 0.0, 0.0])


def test_reference_is_continuous_through_engagement_and_release():
    """Holding while an obstacle passes by: p_d, the desired velocity and the heading change
    by a bounded step every tick, through engagement and release."""
    f = SafetyFilter(SETTINGS)
    hold = HoldPose((0.0, 0.0, 0.7))
    boat = rows(circle(-4.0, 0.3, 0.2, vx=0.25))
    eta = np.array((0.0, 0.0, 0.7))
    prev, engaged_seen, released = None, False, False
    for _ in range(int(60.0 / DT)):
        out = f.step(eta, hold.reference(eta, DT), boat, DT)
        ref = out.reference
        engaged_seen |= out.engaged
        released |= engaged_seen and not out.engaged
        v = ref.nu_d[:2] @ np.array([[math.cos(0.7), math.sin(0.7)],
                                     [-math.sin(0.7), math.cos(0.7)]])  # R(psi_d) nu_d
        if prev is not None:
            assert np.linalg.norm(ref.eta_d[:2] - prev[0]) <= \
                SETTINGS.max_speed * DT + SETTINGS.release_distance + 1e-9
            assert np.linalg.norm(v - prev[1]) <= 0.02
            assert ref.eta_d[2] == pytest.approx(0.7)   # the held heading is kept
        prev = (ref.eta_d[:2].copy(), v)
        eta = ref.eta_d.copy()
        boat[:, 0:4] += DT * np.tile(boat[:, 5:7], 2)
    assert engaged_seen and released
    np.testing.assert_allclose(prev[0], [0.0, 0.0], atol=SETTINGS.release_distance)


def test_los_engages_at_the_vessel_and_keeps_the_course_heading():
    law = LosPath([(0.0, 0.0), (5.0, 0.0)], 0.2, 0.5, 0.1, heading='course')
    f = SafetyFilter(SETTINGS)
    wall = rows([1.0, -1.0, 1.0, 1.0, 0.05, 0.0, 0.0])
    eta = np.array((0.0, 0.1, 0.05))
    for _ in range(250):                     # 1 m at 0.2 m/s: the wall's zone is reached
        nominal = law.reference(eta, DT)
        out = f.step(eta, nominal, wall, DT)
        if out.engaged:
            break
        eta = eta + DT * np.array((0.2, 0.0, 0.0))
    assert out.engaged
    np.testing.assert_allclose(out.reference.eta_d[:2], eta[:2])      # no position step
    assert out.reference.eta_d[2] == nominal.eta_d[2]                  # the LOS course
    assert out.reference.nu_d[2] == nominal.nu_d[2]
    assert np.linalg.norm(out.reference.nu_d[:2] - nominal.nu_d[:2]) < 0.02


def test_engage_at_starts_at_rest_and_returns_to_the_law():
    f = SafetyFilter(SETTINGS)
    f.engage_at(np.array((0.5, 0.0)))
    hold = HoldPose((0.0, 0.0, 0.0))
    eta = np.array((0.5, 0.0, 0.0))
    out = f.step(eta, hold.reference(eta, DT), rows(), DT)
    assert out.engaged and np.allclose(out.reference.eta_d[:2], (0.5, 0.0), atol=0.01)
    for _ in range(int(20.0 / DT)):
        out = f.step(eta, hold.reference(eta, DT), rows(), DT)
    assert not out.engaged


def test_obstacle_lists_are_the_rows_at_age_zero():
    from enbarr_core.guidance.cbf import obstacle_lists
    from enbarr_interfaces.obstacles import CIRCLE, Obstacle, SEGMENT
    obstacles = [Obstacle(1, CIRCLE, 1.0, 2.0, 0.3, vx=0.1, vy=-0.2),
                 Obstacle(2, SEGMENT, -1.0, 0.5, 0.0, 3.0, 0.5)]
    assert obstacle_lists(obstacles) == obstacle_rows(obstacles).tolist()
    assert obstacle_lists(obstacles)[0][2:4] == [1.0, 2.0]   # a circle's second end: its centre


def test_obstacle_rows_are_moved_on_by_their_age():
    class Segment:
        x, y, radius, vx, vy = 1.0, 2.0, 0.3, 0.5, -0.25
        end = (3.0, 2.0)
    r = obstacle_rows([Segment()], age=2.0)
    np.testing.assert_allclose(r, [[2.0, 1.5, 4.0, 1.5, 0.3, 0.5, -0.25]])


def test_step_carries_the_obstacles_by_their_age_as_moved_does():
    """The guidance hands the step the obstacles of the last scan and their age: the step
    must give exactly what it gives on the rows moved to the estimate's time (a head-on boat
    and a crossing wall, so that the age decides the references)."""
    from enbarr_core.guidance.cbf import moved
    scan = rows(circle(2.0, 0.0, 0.2, vx=-0.2), [-1.0, 1.2, 3.0, 0.8, 0.1, 0.05, -0.1])
    hold = HoldPose((0.0, 0.0, 0.0))
    moved_filter, aged_filter = SafetyFilter(SETTINGS), SafetyFilter(SETTINGS)
    eta = np.array((0.0, 0.0, 0.0))
    engaged = 0
    for k in range(int(12.0 / DT)):
        age = (k % 9) * DT   # a scan every nine estimates
        if k % 9 == 0 and k:
            scan = moved(scan, 9 * DT)
        a = moved_filter.step(eta, hold.reference(eta, DT), moved(scan, age), DT)
        b = aged_filter.step(eta, hold.reference(eta, DT), scan.tolist(), DT, age=age)
        assert (a.engaged, a.active, a.infeasible) == (b.engaged, b.active, b.infeasible)
        assert a.min_barrier == b.min_barrier
        np.testing.assert_array_equal(a.reference.eta_d, b.reference.eta_d)
        np.testing.assert_array_equal(a.reference.nu_d, b.reference.nu_d)
        engaged += a.engaged
        eta = a.reference.eta_d.copy()
    assert engaged > 50   # the obstacles did shape the references


@pytest.mark.parametrize('kwargs, match', [
    ({'gamma': 0.0}, '^gamma'), ({'max_speed': -1.0}, '^max_speed'),
    ({'safety_radius': -0.1}, '^safety_radius'), ({'tracking_margin': math.nan},
                                                  '^tracking_margin'),
])
def test_settings_name_the_bad_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SafetyFilter(CbfSettings(**kwargs))


# --- blind ---------------------------------------------------------------------------------


def test_blind_reasons():
    s = 10**9
    assert blind_reason(5 * s, 5 * s - 100_000_000, 0.02, 0.5) is None
    assert 'no obstacles' in blind_reason(5 * s, None, 0.02, 0.5)
    assert 'obstacles 0.60 s old' in blind_reason(5 * s, 5 * s - 600_000_000, 0.02, 0.5)
    assert 'pose lost' in blind_reason(5 * s, 5 * s, 0.8, 0.5)
    assert blind_reason(5 * s, 5 * s, None, 0.5) is None


# --- closed loop ---------------------------------------------------------------------------


def saucer(scale=1.0):
    """The Saucer's model with mass and damping scaled by ``scale`` (the plant)."""
    p = vessel_params()
    return Vessel3Dof(Vessel3DofParams(tuple(m * scale for m in p.M),
                                       tuple(d * scale for d in p.D),
                                       tuple(d * scale for d in p.Dn)))


def closed_loop(law, obstacles, seconds, x0, *, scale=1.0, seed=1, settings=SETTINGS,
                avoid=True):
    """Noisy pose -> observer -> law -> filter -> DP controller -> plant, 50 Hz.

    Returns (minimum hull clearance of the TRUE vessel [m], final true eta, filter).
    """
    rng = np.random.default_rng(seed)
    plant = saucer(scale)
    obs, ctl, f = PassiveObserver(observer_settings()), DpController(dp_settings()), \
        SafetyFilter(settings)
    eta, nu = np.array(x0[:3], dtype=float), np.zeros(3)
    tau = np.zeros(3)
    world = np.array(obstacles, dtype=float).reshape(-1, 7)
    worst = clearance(eta, world)
    for _ in range(int(round(seconds / DT))):
        est = obs.step(eta + rng.normal(0.0, NOISE), tau, DT)
        ref: Reference = law.reference(est.eta_hat, DT)
        if avoid:
            ref = f.step(est.eta_hat, ref, world, DT).reference
        tau = ctl.step(est.eta_hat, est.nu_hat, est.b_hat, ref, DT).tau
        eta, nu = plant.step(eta, nu, tau, DT)
        world[:, 0:4] += DT * np.tile(world[:, 5:7], 2)
        worst = min(worst, clearance(eta, world))
    return worst, eta, f


def random_obstacles(rng, path, k):
    """k circles and a short wall near random points of the path, none on the start."""
    path = np.asarray(path, dtype=float)
    lengths = np.hypot(*np.diff(path, axis=0).T)
    out = []
    for i in range(k):
        s = rng.uniform(1.2, lengths.sum() - 0.3)
        seg = int(np.searchsorted(np.cumsum(lengths), s))
        a, d = path[seg], (path[seg + 1] - path[seg]) / lengths[seg]
        c = a + d * (s - np.concatenate(([0.0], np.cumsum(lengths)))[seg]) \
            + np.array((-d[1], d[0])) * rng.uniform(-0.4, 0.4)
        if i == k - 1 and rng.random() < 0.5:   # a wall across part of the path
            e = c + rng.uniform(-0.5, 0.5, 2)
            out.append([*c, *e, rng.uniform(0.0, 0.05), 0.0, 0.0])
        else:
            out.append(circle(*c, rng.uniform(0.1, 0.35)))
    return out


STRAIGHT = [(0.0, 0.0), (5.0, 0.0)]
BOX = [(0.0, 0.0), (3.0, 0.0), (3.0, 3.0), (0.0, 3.0), (0.0, 0.0)]


@pytest.mark.sim
@pytest.mark.parametrize('path, seconds', [(STRAIGHT, 35.0), (BOX, 70.0)])
@pytest.mark.parametrize('scale', [0.7, 1.0, 1.3])
def test_true_vessel_keeps_the_safety_radius_on_randomized_obstacles(path, seconds, scale):
    rng = np.random.default_rng(int(scale * 10) + len(path))
    for trial in range(3):
        obstacles = random_obstacles(rng, path, 3)
        law = LosPath(path, 0.2, 0.5, 0.1, heading='course')
        worst, _, f = closed_loop(law, obstacles, seconds, (0.0, 0.0, 0.0), scale=scale,
                                  seed=trial)
        assert worst >= SETTINGS.safety_radius, (trial, obstacles, worst)
        assert f.infeasible_count == 0


@pytest.mark.sim
def test_without_the_barrier_the_vessel_hits_the_same_obstacles():
    """The closed-loop test can fail: the same loop without the filter comes too close."""
    obstacles = [circle(2.5, 0.1, 0.3)]
    law = LosPath(STRAIGHT, 0.2, 0.5, 0.1)
    worst, _, _ = closed_loop(law, obstacles, 30.0, (0.0, 0.0, 0.0), avoid=False)
    assert worst < 0.0
    law = LosPath(STRAIGHT, 0.2, 0.5, 0.1)
    worst, eta, _ = closed_loop(law, obstacles, 40.0, (0.0, 0.0, 0.0))
    assert worst >= SETTINGS.safety_radius
    assert eta[0] > 4.5                     # and it got past


@pytest.mark.sim
def test_head_on_boat_on_the_path_in_closed_loop():
    boat = [circle(5.0, 0.05, 0.2, vx=-0.12)]
    law = LosPath(STRAIGHT, 0.2, 0.5, 0.1, heading='course')
    worst, _, f = closed_loop(law, boat, 40.0, (0.0, 0.0, 0.0), scale=1.3)
    assert worst >= SETTINGS.safety_radius
    assert f.infeasible_count == 0


@pytest.mark.sim
@pytest.mark.parametrize('scale', [0.7, 1.3])
def test_a_gap_narrower_than_the_zones_is_never_squeezed_through(scale):
    # Two buoys 0.24 m apart across the path, walls on from them to either side: each
    # buoy's zone alone leaves the path a way past its neighbour, together they close it.
    # The vessel stops short of the gap (and may slide along the walls), always clear.
    gap = [circle(2.5, 0.32, 0.2), circle(2.5, -0.32, 0.2),
           [2.5, 0.32, 2.5, 1.5, 0.05, 0.0, 0.0], [2.5, -0.32, 2.5, -1.5, 0.05, 0.0, 0.0]]
    law = LosPath(STRAIGHT, 0.2, 0.5, 0.1, heading='course')
    worst, eta, f = closed_loop(law, gap, 40.0, (0.0, 0.0, 0.0), scale=scale)
    assert worst >= SETTINGS.safety_radius
    assert eta[0] < 2.5 - 0.2 - VESSEL_RADIUS - SETTINGS.safety_radius
    assert f.infeasible_count == 0


@pytest.mark.sim
def test_go_to_waypoint_behind_an_obstacle_in_closed_loop():
    law = GoToWaypoint((0.0, 0.0, 0.0), (3.0, 0.0), 0.2, 0.05)
    worst, eta, _ = closed_loop(law, [circle(1.5, 0.0, 0.3)], 50.0, (0.0, 0.0, 0.0),
                                scale=0.7)
    assert worst >= SETTINGS.safety_radius
    assert np.hypot(eta[0] - 3.0, eta[1]) < 0.1


# --- the force-level option, compared ------------------------------------------------------


def force_closed_loop(path, obstacles, seconds, *, scale, seed):
    """The same loop with the force-level HOCBF filtering the DP controller's force (the
    law unfiltered). Returns (minimum true hull clearance [m], final eta, filter)."""
    from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceSafetyFilter
    vp, ds = vessel_params(), dp_settings()
    f = ForceSafetyFilter(ForceCbfSettings(vp.M, vp.D, vp.Dn, tuple(ds.tau_max),
                                           SETTINGS.safety_radius, VESSEL_RADIUS))
    rng = np.random.default_rng(seed)
    plant = saucer(scale)
    obs, ctl = PassiveObserver(observer_settings()), DpController(ds)
    law = LosPath(path, 0.2, 0.5, 0.1, heading='course')
    eta, nu, tau = np.zeros(3), np.zeros(3), np.zeros(3)
    world = np.array(obstacles, dtype=float).reshape(-1, 7)
    worst = clearance(eta, world)
    for _ in range(int(round(seconds / DT))):
        est = obs.step(eta + rng.normal(0.0, NOISE), tau, DT)
        ref = law.reference(est.eta_hat, DT)
        tau = ctl.step(est.eta_hat, est.nu_hat, est.b_hat, ref, DT).tau
        tau = f.step(est.eta_hat, est.nu_hat, tau, world).tau
        eta, nu = plant.step(eta, nu, tau, DT)
        world[:, 0:4] += DT * np.tile(world[:, 5:7], 2)
        worst = min(worst, clearance(eta, world))
    return worst, eta, f


@pytest.mark.sim
def test_force_level_hocbf_against_the_guidance_level_filter():
    """With its own model the force-level filter keeps the clearance (within the estimate's
    noise and the 50 Hz step: 1 cm) and needs no tracking margin; with the plant 30 % heavier
    than its model it no longer does, where the guidance-level one still does."""
    rng = np.random.default_rng(12)
    exact, heavy = [], []
    for trial in range(2):
        obstacles = random_obstacles(rng, STRAIGHT, 3)
        exact.append(force_closed_loop(STRAIGHT, obstacles, 30.0, scale=1.0, seed=trial)[0])
        heavy.append(force_closed_loop(STRAIGHT, obstacles, 30.0, scale=1.3, seed=trial)[0])
        guidance_heavy, _, _ = closed_loop(LosPath(STRAIGHT, 0.2, 0.5, 0.1, heading='course'),
                                           obstacles, 30.0, (0.0, 0.0, 0.0), scale=1.3,
                                           seed=trial)
        assert guidance_heavy >= SETTINGS.safety_radius
        assert heavy[-1] < guidance_heavy
    assert min(exact) >= SETTINGS.safety_radius - 0.01
    assert min(heavy) < SETTINGS.safety_radius        # the model error shows


def test_los_finishing_into_a_hold_inside_a_zone_does_not_step_the_reference():
    """The last waypoint lies in an obstacle's zone: when LOS finishes, its hold of the
    waypoint moved the position reference there at once (it did, by 0.14 m here and by 0.4 m
    into a zone with a 0.1 m tracking margin, the controller pulling the vessel after it). The
    filter goes on from where the reference was, at the speed limit, and keeps the zone."""
    law = LosPath(STRAIGHT, 0.2, 0.5, 0.1, heading='course')
    buoy = rows(circle(4.8, 0.45, 0.05))
    rng = np.random.default_rng(4)
    obs, ctl, f = PassiveObserver(observer_settings()), DpController(dp_settings()), \
        SafetyFilter(SETTINGS)
    plant = saucer()
    eta, nu, tau = np.zeros(3), np.zeros(3), np.zeros(3)
    last, finished, worst = None, False, math.inf
    for _ in range(int(45.0 / DT)):
        est = obs.step(eta + rng.normal(0.0, NOISE), tau, DT)
        nominal = law.reference(est.eta_hat, DT)
        out = f.step(est.eta_hat, nominal, buoy, DT)
        ref = out.reference
        finished |= nominal.finished
        position = ref.eta_d[:2] if ref.position_mask[0] else est.eta_hat[:2]
        if last is not None:
            assert np.linalg.norm(position - last) <= SETTINGS.max_speed * DT + 0.01
        last = position.copy()
        tau = ctl.step(est.eta_hat, est.nu_hat, est.b_hat, ref, DT).tau
        eta, nu = plant.step(eta, nu, tau, DT)
        worst = min(worst, clearance(eta, buoy))
    assert finished and out.engaged and out.min_barrier >= -1e-3
    assert worst >= SETTINGS.safety_radius


def test_force_filter_passes_a_blocking_obstacle_instead_of_stopping():
    """Straight at a buoy: without passing the filtered force has no sway (the CBF's local
    minimum: the vessel stops in front of it); with pass_gain 1 the force lost goes along the
    tangent, to starboard, and the HOCBF condition and the box still hold."""
    from dataclasses import replace
    from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceSafetyFilter
    vp = vessel_params()
    base = ForceCbfSettings(vp.M, vp.D, vp.Dn, (2.0, 2.0, 0.3), 0.2, VESSEL_RADIUS)
    buoy = rows(circle(0.6, 0.0, 0.05))
    eta, nu, tau_nom = np.zeros(3), np.array([0.2, 0.0, 0.0]), np.array([2.0, 0.0, 0.1])
    # h = 0.6 - 0.05 - r_vessel - 0.2, h_dot = -0.2, n = (-1, 0), a1 = a2 = 1: the condition
    # n^T (M^-1 tau + drift) >= -(a1 + a2) h_dot - a1 a2 h, written out for this state.
    h = 0.6 - 0.05 - VESSEL_RADIUS - 0.2
    drift_x = -(vp.D[0] + vp.Dn[0] * 0.2) * 0.2 / vp.M[0]
    stop = ForceSafetyFilter(base).step(eta, nu, tau_nom, buoy)
    assert stop.engaged and stop.tau[1] == pytest.approx(0.0, abs=1e-9)
    assert -stop.tau[0] / vp.M[0] - drift_x >= 2 * 0.2 - h - 1e-9
    f = ForceSafetyFilter(replace(base, pass_gain=1.0))
    out = f.step(eta, nu, tau_nom, buoy)
    assert out.engaged and out.active == 1
    assert out.tau[1] < -0.5 and f.side == 1                 # starboard (FLU: -y)
    assert -out.tau[0] / vp.M[0] - drift_x >= 2 * 0.2 - h - 1e-9
    assert np.all(np.abs(out.tau[:2]) <= 2.0 + 1e-9) and out.tau[2] == 0.1
    # A push along the tangent beyond the box is solved back into it.
    hard = ForceSafetyFilter(replace(base, pass_gain=3.0)).step(eta, nu, tau_nom, buoy)
    assert hard.tau[1] == pytest.approx(-2.0, abs=1e-9)
    assert -hard.tau[0] / vp.M[0] - drift_x >= 2 * 0.2 - h - 1e-9


def test_force_filter_settings_swapped_live_move_the_zones():
    """A new safety radius (live, from the node's parameters) is the zone's at the next step;
    a bad one is refused and the old settings stay."""
    from dataclasses import replace
    from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceSafetyFilter
    vp = vessel_params()
    base = ForceCbfSettings(vp.M, vp.D, vp.Dn, (2.0, 2.0, 0.3), 0.2, VESSEL_RADIUS)
    buoy = rows(circle(2.0, 0.0, 0.05))
    f = ForceSafetyFilter(base)
    state = (np.zeros(3), np.zeros(3), np.zeros(3), buoy)
    assert f.step(*state).min_barrier == pytest.approx(2.0 - 0.05 - VESSEL_RADIUS - 0.2)
    f.settings = replace(base, safety_radius=0.5)
    assert f.step(*state).min_barrier == pytest.approx(2.0 - 0.05 - VESSEL_RADIUS - 0.5)
    with pytest.raises(ValueError, match='a1'):
        f.settings = replace(base, a1=0.0)
    assert f.settings.safety_radius == 0.5


@pytest.mark.parametrize('change, match', [
    ({'M': (0.0, 9.51, 0.116)}, 'M: every element must be > 0'),
    ({'tau_max': (2.0, -1.0, 0.3)}, 'tau_max: every element must be > 0'),
    ({'a1': 0.0}, 'a1, a2: must be > 0'),
    ({'pass_gain': -1.0}, 'pass_gain: must be a finite number >= 0'),
    ({'D': (1.0, math.nan, 1.0)}, 'D: expected three finite numbers'),
])
def test_force_filter_settings_are_checked(change, match):
    from dataclasses import replace
    from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceSafetyFilter
    vp = vessel_params()
    base = ForceCbfSettings(vp.M, vp.D, vp.Dn, (2.0, 2.0, 0.3), 0.2, VESSEL_RADIUS)
    with pytest.raises(ValueError, match=match):
        ForceSafetyFilter(replace(base, **change))
