"""The collision-avoidance figures against hand-computed answers on made-up runs."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from enbarr_interfaces import avoidance as avoidance_msg
from enbarr_interfaces import obstacles as ob
from enbarr_core.tools.avoidance_metrics import avoidance_figures, avoids
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Static, Walls, World

pytestmark = pytest.mark.unit

EPOCH = 1.0        # the world's time 0 on the run's clock [s]
DT = 0.02          # truth samples [s]
NS = 1_000_000_000


def profile(world: World, **avoidance: float) -> SimpleNamespace:
    params = {'avoidance.enabled': True, 'avoidance.vessel_radius': 0.15,
              'avoidance.safety_radius': 0.2, 'path.waypoints': [0.0, 0.0, 10.0, 0.0],
              'path.speed': 0.2, **{f'avoidance.{k}': v for k, v in avoidance.items()}}
    return SimpleNamespace(world=world, parameters={},
                           nodes=[SimpleNamespace(plugin='guidance', parameters=params)])


def straight_run(seconds: float = 50.0, speed: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """The truth: from (0, 0) east at ``speed``, heading east; times from EPOCH."""
    t = EPOCH + np.arange(0.0, seconds, DT)
    eta = np.column_stack(((t - EPOCH) * speed, np.zeros_like(t), np.zeros_like(t)))
    return t, eta


def status(t: float, *, engaged: bool = False, blind: bool = False, infeasible: bool = False,
           solve: float = 1e-4, obstacles_age: float = 0.1, count: int = 1) -> tuple:
    values = {'solve_time': solve, 'active': float(engaged), 'infeasible': float(infeasible),
              'min_barrier': 1.0, 'engaged': float(engaged), 'blind': float(blind),
              'obstacles': float(count)}
    ns = int(round(t * NS))
    return ns, avoidance_msg.to_msg(values, ns, ns - int(round(obstacles_age * NS)))


def test_clearance_is_hull_to_surface_at_the_closest_pass() -> None:
    """East along y = 0 past a buoy of radius 0.2 at (5, 1) and a wall along y = -2: the hull
    (0.15) comes within 1 - 0.2 - 0.15 = 0.65 m of the buoy and 2 - 0.15 = 1.85 of the wall."""
    world = World([Obstacle('buoy', Circle((5.0, 1.0), 0.2), Static()),
                   Obstacle('wall', Walls(((-5.0, -2.0), (15.0, -2.0))), Static())])
    t, eta = straight_run()
    out = avoidance_figures({}, profile(world), t, eta, EPOCH)
    assert out['min_clearance_m'] == pytest.approx(0.65, abs=1e-9)
    assert out['clearance_margin_m'] == pytest.approx(0.45, abs=1e-9)
    assert out['nearest_obstacle'] == 'buoy'
    assert out['clearance_by_obstacle'] == {'buoy': pytest.approx(0.65),
                                            'wall': pytest.approx(1.85)}
    assert out['avoidance_s'] is None and out['qp_solve_p50_ms'] is None  # no status: none


def test_a_moving_obstacle_is_measured_where_it_is_at_each_instant() -> None:
    """A boat (radius 0.3) from (5, -10) north at 0.2 m/s while the vessel goes east from the
    origin at 0.2 m/s: their offset is (0.2 t - 5, 10 - 0.2 t), whose components sum to 5, so
    the centres come within 5 / sqrt(2) of each other. Read at the run's clock instead of the
    world's (1 s later), the boat would be 0.2 m further north: 5.2 / sqrt(2)."""
    world = World([Obstacle('boat', Circle((5.0, -10.0), 0.3), ConstantVelocity((0.0, 0.2)))])
    t, eta = straight_run(60.0)
    out = avoidance_figures({}, profile(world), t, eta, EPOCH)
    assert out['min_clearance_m'] == pytest.approx(5.0 / math.sqrt(2) - 0.3 - 0.15, abs=1e-4)


def test_the_avoidance_status_gives_times_solves_and_latency() -> None:
    """50 Hz status: engaged 3-5 s, blind 6-9 s (vessel still; obstacles 2 s old), two
    infeasible steps, solve times 0.1 ms except 20 of 2 ms, obstacles 0.1 s old except 20
    steps of 0.3 s."""
    t, eta = straight_run(20.0, speed=0.0)
    msgs = []
    for i, ti in enumerate(np.arange(EPOCH, EPOCH + 20.0, DT)):
        rel = ti - EPOCH
        msgs.append(status(ti, engaged=3.0 <= rel < 5.0, blind=6.0 <= rel < 9.0,
                           infeasible=i in (10, 11), solve=2e-3 if i < 20 else 1e-4,
                           obstacles_age=2.0 if 6.0 <= rel < 9.0 else
                           0.3 if 500 <= i < 520 else 0.1))
    # Steps with nothing to consider do not count as solves (they would make the p99 5 ms).
    msgs += [status(EPOCH + 20.0 + k * DT, solve=5e-3, count=0) for k in range(30)]
    out = avoidance_figures({'/guidance/avoidance': msgs}, profile(World()), t, eta, EPOCH)
    assert out['avoidance_s'] == pytest.approx(2.0, abs=DT)
    assert out['blind_s'] == pytest.approx(3.0, abs=DT)
    assert out['blind_travel_m'] == 0.0
    assert out['infeasible_steps'] == 2
    assert out['qp_solve_p50_ms'] == pytest.approx(0.1)
    assert out['qp_solve_p99_ms'] == pytest.approx(2.0)
    assert out['latency_p50_ms'] == pytest.approx(100.0)
    # Blind steps carry stale obstacles by definition: their age is not a latency (with them
    # the 99th percentile would be 2000 ms).
    assert out['latency_p99_ms'] == pytest.approx(300.0)


def test_at_the_force_level_the_force_filter_is_what_acted() -> None:
    """avoidance.level force: the guidance's status says only when it held blind (6-9 s;
    its 'solve' is 0, it solves nothing); the controller's says when the force was changed
    (3-5 s, and 12-14 s, whose cross-track of 0.5 m and its 5 s after are left out), its two
    infeasible steps and its solve times (0.1 ms, 20 of 2 ms)."""
    t, eta = straight_run(30.0, speed=0.0)
    rel = t - EPOCH
    guidance = [status(ti, blind=6.0 <= r < 9.0, solve=0.0,
                       obstacles_age=2.0 if 6.0 <= r < 9.0 else 0.1)
                for ti, r in zip(t, rel)]
    force = [status(ti, engaged=3.0 <= r < 5.0 or 12.0 <= r < 14.0, infeasible=i in (10, 11),
                    solve=2e-3 if i < 20 else 1e-4) for i, (ti, r) in enumerate(zip(t, rel))]
    ct = np.where((rel >= 12.0) & (rel < 19.0), 0.5, 0.01)
    msgs = {'/guidance/avoidance': guidance, '/control/avoidance': force}
    out = avoidance_figures(msgs, profile(World(), level='force'), t, eta, EPOCH,
                            cross_track=(t, ct))
    assert out['avoidance_s'] == pytest.approx(4.0, abs=2 * DT)
    assert out['blind_s'] == pytest.approx(3.0, abs=DT)
    assert out['infeasible_steps'] == 2
    assert out['qp_solve_p50_ms'] == pytest.approx(0.1)
    assert out['qp_solve_p99_ms'] == pytest.approx(2.0)
    assert out['cross_track_outside_avoidance_rms_m'] == pytest.approx(0.01)
    # The same run at the guidance level reads the guidance's status alone.
    out = avoidance_figures(msgs, profile(World()), t, eta, EPOCH)
    assert out['avoidance_s'] == 0.0 and out['infeasible_steps'] == 0


def test_blind_travel_leaves_out_the_stop_and_counts_the_drift() -> None:
    """Blind from 10 to 16 s while the vessel still drifts at 0.05 m/s: after the first 2 s
    (stopping), 4 s x 0.05 = 0.2 m."""
    t, eta = straight_run(20.0, speed=0.05)
    msgs = [status(ti, blind=10.0 <= ti - EPOCH < 16.0) for ti in t]
    out = avoidance_figures({'/guidance/avoidance': msgs}, profile(World()), t, eta, EPOCH)
    assert out['blind_travel_m'] == pytest.approx(0.2, abs=0.05 * 2 * DT)


def test_cross_track_outside_avoidance_leaves_out_the_interval_and_the_recovery() -> None:
    """Cross-track 0.5 m while engaged (10-15 s) and in the 5 s after, 0.01 m elsewhere."""
    t, eta = straight_run(40.0)
    rel = t - EPOCH
    ct = np.where((rel >= 10.0) & (rel < 20.0), 0.5, 0.01)
    msgs = [status(ti, engaged=10.0 <= ti - EPOCH < 15.0) for ti in t]
    out = avoidance_figures({'/guidance/avoidance': msgs}, profile(World()), t, eta, EPOCH,
                            cross_track=(t, ct))
    assert out['cross_track_outside_avoidance_rms_m'] == pytest.approx(0.01)


def test_time_lost_is_beyond_the_path_at_its_speed() -> None:
    t, eta = straight_run()
    out = avoidance_figures({}, profile(World()), t, eta, EPOCH, path={'path_time_s': 57.5})
    assert out['time_lost_s'] == pytest.approx(57.5 - 10.0 / 0.2)


def test_tracking_errors_and_false_obstacles_against_the_world() -> None:
    """A buoy moving east at 0.1 m/s, reported 0.03 east and 0.04 north of where it is at
    each report's stamp with velocity (0.1, 0.05); a wall reported where it is; an obstacle
    reported at (20, 20) where nothing is, over a 60 s run: one false obstacle a minute. A
    piece of a pier 0.6 m north of the buoy is a segment: never matched to the buoy."""
    world = World([Obstacle('buoy', Circle((3.0, 2.0), 0.2), ConstantVelocity((0.1, 0.0))),
                   Obstacle('wall', Walls(((0.0, 5.0), (10.0, 5.0))), Static()),
                   Obstacle('pier', Walls(((0.0, 2.6), (12.0, 2.6))), Static())])
    t, eta = straight_run(60.0)
    reports = []
    for k in range(1, 60):
        stamp = EPOCH + k
        x = 3.0 + 0.1 * (stamp - EPOCH)
        found = [ob.Obstacle(1, ob.CIRCLE, x + 0.03, 2.04, 0.2, vx=0.1, vy=0.05,
                             stamp_ns=int(round(stamp * NS))),
                 ob.Obstacle(2, ob.SEGMENT, 1.0, 5.0, 0.0, 8.0, 5.0,
                             stamp_ns=int(round(stamp * NS))),
                 ob.Obstacle(4, ob.SEGMENT, x, 2.6, 0.0, x + 1.0, 2.6,
                             stamp_ns=int(round(stamp * NS)))]
        if k == 30:
            found.append(ob.Obstacle(3, ob.CIRCLE, 20.0, 20.0, 0.2,
                                     stamp_ns=int(round(stamp * NS))))
        reports.append((int(round(stamp * NS)), ob.to_cloud(found, int(round(stamp * NS)),
                                                            'odom')))
    out = avoidance_figures({'/obstacles': reports}, profile(world), t, eta, EPOCH)
    assert out['tracking_position_error_rms_m'] == pytest.approx(0.05, abs=1e-9)
    assert out['tracking_velocity_error_rms_mps'] == pytest.approx(0.05, abs=1e-9)
    minutes = (t[-1] - t[0]) / 60.0
    assert out['false_obstacles_per_min'] == pytest.approx(1 / minutes, abs=0.01)


def test_avoids_reads_the_guidance_parameter() -> None:
    assert avoids(profile(World()))
    assert not avoids(profile(World(), enabled=False))
    assert not avoids(SimpleNamespace(parameters={}, nodes=[]))
