"""Figures and a picture of a collision-avoidance run, from its bag and the profile's world.

The ground truth is the simulator's pose (``sim/odometry``) and the profile's ``world``
(:mod:`enbarr_core.world`), evaluated at the world time of each sample: a scenario's world
starts at the run's first instant (``scenario.T0_NS``). What the vessel did is read from
``guidance/avoidance`` (:mod:`enbarr_interfaces.avoidance`) and, with the barrier functions at
the force level (``avoidance.level`` force), ``control/avoidance`` for what the force filter
did (the guidance then only holds while blind), what it saw from ``obstacles``
(:mod:`enbarr_interfaces.obstacles`). Definitions (every figure is ``None`` when the run has
nothing to compute it from):

- ``min_clearance_m``: the least distance over the run between the hull (a circle of the
  guidance's ``avoidance.vessel_radius`` about the simulated CO) and any obstacle's surface;
  ``nearest_obstacle`` names it, ``clearance_by_obstacle`` gives each obstacle's least.
  The hard bound is the ``avoidance.safety_radius``, less a margin for what the vessel cannot
  know: the lidar's range noise and the pose estimate's error (a scenario states its target).
- ``clearance_margin_m``: ``min_clearance_m`` minus the safety radius (< 0: inside it).
- ``avoidance_s``: the time the safety filter changed the reference (``engaged``; at the
  force level: the time the force filter changed the force);
  ``blind_s``: the time it held because obstacles or the pose were stale; ``infeasible_steps``:
  the steps whose QP had no solution (the filter stopped, or at the force level braked).
- ``blind_travel_m``: how far the vessel moved while holding blind, leaving out the first
  ``BLIND_STOP_S`` of each blind interval (it has to stop first): a vessel that holds moves
  only by what its controller lets the current push it.
- ``cross_track_outside_avoidance_rms_m``: the path's cross-track error (as the path figures
  define it) over the guidance period, leaving out every interval the filter was engaged or
  blind and the ``RECOVERY_S`` after each, in which the vessel returns to the path.
- ``time_lost_s``: ``path_time_s`` (the path figures) less the time the path takes at the
  guidance speed (its length over ``path.speed``).
- ``qp_solve_p50_ms``, ``qp_solve_p99_ms``: the safety filter's step time (wall clock) over
  the steps it had obstacles to consider (at the force level: the force filter's).
- ``latency_p50_ms``, ``latency_p99_ms``: from the stamp of the scan the obstacles came from to
  the estimate the constrained reference answers (simulated time): the age of what the filter
  knew when it acted.
- ``tracking_position_error_rms_m``, ``tracking_velocity_error_rms_mps``: every reported
  circle obstacle against the nearest true circle (centre within ``MATCH_RADIUS``) at the
  stamp of its measurement.
- ``false_obstacles_per_min``: distinct obstacle ids that were ever reported where no true
  obstacle is (no true surface within ``FALSE_GATE`` of the reported shape), per minute of
  the run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from enbarr_interfaces import avoidance as avoidance_msg
from enbarr_interfaces import convert
from enbarr_interfaces import obstacles as obstacle_msg
from enbarr_core.framework.errors import FrameError
from enbarr_core.world.model import Circle, Polygon, Walls, World

#: What the avoidance figures and picture read besides the path figures' topics.
AVOIDANCE_TOPICS = ('/guidance/avoidance', '/control/avoidance', '/obstacles', '/scan')
RECOVERY_S = 5.0      # after an avoidance, the vessel returns to the path for this long [s]
MATCH_RADIUS = 1.0    # a reported circle is that true circle when its centre is this close [m]
FALSE_GATE = 0.5      # a reported obstacle with no true surface this close is false [m]
BLIND_STOP_S = 2.0    # a vessel going blind has stopped within this [s]
SCANS_DRAWN = 4       # scans drawn on the picture
AVOIDANCE_FIGURES = (
    'min_clearance_m', 'clearance_margin_m', 'avoidance_s', 'blind_s', 'blind_travel_m',
    'infeasible_steps',
    'cross_track_outside_avoidance_rms_m', 'time_lost_s', 'qp_solve_p50_ms', 'qp_solve_p99_ms',
    'latency_p50_ms', 'latency_p99_ms', 'tracking_position_error_rms_m',
    'tracking_velocity_error_rms_mps', 'false_obstacles_per_min')

Messages = dict[str, list[tuple[int, Any]]]


def guidance_avoidance(profile: Any) -> dict[str, Any]:
    """Return the guidance node's ``avoidance.*`` parameters in the profile (short names)."""
    for n in profile.nodes:
        if n.plugin == 'guidance':
            merged = {**profile.parameters, **n.parameters}
            return {k.split('.', 1)[1]: v for k, v in merged.items()
                    if k.startswith('avoidance.')}
    return {}


def force_level(profile: Any) -> bool:
    """Whether the profile's barrier functions act on the force (``avoidance.level``)."""
    return guidance_avoidance(profile).get('level', 'guidance') == 'force'


def avoids(profile: Any) -> bool:
    """Whether the profile's guidance runs the collision avoidance."""
    return bool(guidance_avoidance(profile).get('enabled'))


def _stamp_s(msg: Any) -> float:
    return convert.stamp_to_ns(msg.header.stamp) * 1e-9


def _intervals(t: np.ndarray, flag: np.ndarray) -> list[tuple[float, float]]:
    """[start, end) of each run of ``flag`` True over the samples at ``t``."""
    out: list[tuple[float, float]] = []
    start = None
    for i, on in enumerate(flag):
        if on and start is None:
            start = t[i]
        elif not on and start is not None:
            out.append((start, t[i]))
            start = None
    if start is not None:
        out.append((start, t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0)))
    return out


def _percentile_ms(x: list[float], q: float) -> float | None:
    return round(float(np.percentile(x, q)) * 1e3, 3) if x else None


def clearances(world: World, t: np.ndarray, p: np.ndarray, epoch_s: float,
               vessel_radius: float) -> np.ndarray:
    """Hull-to-surface distance (n samples, N obstacles) [m] along the true path ``p``."""
    out = np.empty((len(t), len(world)))
    for i, (ti, pi) in enumerate(zip(t, p)):
        out[i] = world.distance(pi, ti - epoch_s) - vessel_radius
    return out


def avoidance_figures(msgs: Messages, profile: Any, t: np.ndarray, eta: np.ndarray,
                      epoch_s: float, path: dict[str, Any] | None = None,
                      cross_track: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> dict[str, Any]:
    """Compute the avoidance figures (module docstring) of a run.

    ``t``, ``eta``: the truth's times [s] and poses; ``epoch_s``: the world's time 0 on that
    clock; ``path``: the path figures (for ``time_lost_s``); ``cross_track``: (times, errors)
    of the path's cross-track error over the guidance period.
    """
    world: World = profile.world
    params = guidance_avoidance(profile)
    vessel_radius = float(params.get('vessel_radius', 0.0))
    safety = float(params.get('safety_radius', 0.0))
    out: dict[str, Any] = dict.fromkeys(AVOIDANCE_FIGURES)
    if len(world) and len(t):
        c = clearances(world, t, eta[:, :2], epoch_s, vessel_radius)
        least = c.min(axis=0)
        k = int(np.argmin(least))
        out['min_clearance_m'] = round(float(least[k]), 4)
        out['clearance_margin_m'] = round(float(least[k]) - safety, 4)
        out['nearest_obstacle'] = world.names[k]
        out['clearance_by_obstacle'] = {n: round(float(v), 4)
                                        for n, v in zip(world.names, least)}
    status = [avoidance_msg.from_msg(m) for _, m in msgs.get('/guidance/avoidance', [])]
    # The filter that acts: the guidance's, or at the force level the controller's (the
    # guidance's status then only says when it held blind).
    acting = status
    if force_level(profile):
        acting = [avoidance_msg.from_msg(m) for _, m in msgs.get('/control/avoidance', [])]
    if status:
        st = np.array([s['estimate_stamp_ns'] * 1e-9 for s in status])
        blind = np.array([s['blind'] > 0.5 for s in status])
        dt = float(np.median(np.diff(st))) if len(st) > 1 else 0.0
        at = np.array([s['estimate_stamp_ns'] * 1e-9 for s in acting])
        engaged_at = np.array([s['engaged'] > 0.5 for s in acting], dtype=bool)
        # engaged on the guidance's samples (the same estimates at either level)
        engaged = np.isin(st, at[engaged_at]) if len(at) else np.zeros(len(st), dtype=bool)
        out['avoidance_s'] = round(float(engaged.sum()) * dt, 2)
        out['blind_s'] = round(float(blind.sum()) * dt, 2)
        if blind.any():
            travel = 0.0
            for a, b in _intervals(st, blind):
                sel = (t >= a + BLIND_STOP_S) & (t < b)
                if sel.sum() > 1:
                    travel += float(np.sum(np.hypot(*np.diff(eta[sel, :2], axis=0).T)))
            out['blind_travel_m'] = round(travel, 4)
        out['infeasible_steps'] = int(sum(s['infeasible'] > 0.5 for s in acting))
        solve = [s['solve_time'] for s in acting if s['obstacles'] > 0]
        out['qp_solve_p50_ms'] = _percentile_ms(solve, 50)
        out['qp_solve_p99_ms'] = _percentile_ms(solve, 99)
        ages = [(s['estimate_stamp_ns'] - s['obstacles_stamp_ns']) * 1e-9 for s in status
                if s['obstacles_stamp_ns'] > 0 and not s['blind'] > 0.5]
        out['latency_p50_ms'] = _percentile_ms(ages, 50)
        out['latency_p99_ms'] = _percentile_ms(ages, 99)
        if cross_track is not None and len(cross_track[0]):
            ct_t, ct = cross_track
            keep = np.ones(len(ct_t), dtype=bool)
            for a, b in _intervals(st, engaged | blind):
                keep &= ~((ct_t >= a) & (ct_t < b + RECOVERY_S))
            if keep.any():
                out['cross_track_outside_avoidance_rms_m'] = round(
                    float(np.sqrt(np.mean(ct[keep] ** 2))), 4)
    if path is not None and path.get('path_time_s') is not None:
        length, speed = _path_length_and_speed(profile)
        if speed:
            out['time_lost_s'] = round(path['path_time_s'] - length / speed, 2)
    out.update(_tracking(msgs, world, epoch_s, t))
    return out


def _path_length_and_speed(profile: Any) -> tuple[float, float | None]:
    for n in profile.nodes:
        if n.plugin == 'guidance':
            merged = {**profile.parameters, **n.parameters}
            w = np.array(merged.get('path.waypoints', [0.0]), dtype=float)
            if w.size >= 4:
                w = w.reshape(-1, 2)
                length = float(np.sum(np.hypot(*np.diff(w, axis=0).T)))
                speed = merged.get('path.speed')
                return length, (float(speed) if speed else None)
    return 0.0, None


def _tracking(msgs: Messages, world: World, epoch_s: float, t: np.ndarray) -> dict[str, Any]:
    """Tracking errors and false obstacles of the ``obstacles`` messages against the world."""
    reports = msgs.get('/obstacles', [])
    if not reports or not len(world):
        return {}
    circles = [i for i, o in enumerate(world.obstacles) if isinstance(o.shape, Circle)]
    pos_err: list[float] = []
    vel_err: list[float] = []
    false_ids: set[int] = set()
    for _, m in reports:
        for o in obstacle_msg.from_cloud(m):
            tw = o.stamp_ns * 1e-9 - epoch_s
            if _is_false(o, world, tw):
                false_ids.add(o.id)
                continue
            if o.kind != obstacle_msg.CIRCLE or not circles:
                continue
            shapes = world.shapes_at(tw)
            best, best_d = None, MATCH_RADIUS
            for i in circles:
                shape = shapes[i]
                assert isinstance(shape, Circle)
                d = math.hypot(o.x - shape.center[0], o.y - shape.center[1])
                if d < best_d:
                    best, best_d = i, d
            if best is None:
                continue
            vx, vy = world.velocities(tw)[best]
            pos_err.append(best_d)
            vel_err.append(math.hypot(o.vx - vx, o.vy - vy))
    minutes = float(t[-1] - t[0]) / 60.0 if len(t) > 1 else 0.0
    return {'tracking_position_error_rms_m': _rms(pos_err),
            'tracking_velocity_error_rms_mps': _rms(vel_err),
            'false_obstacles_per_min': round(len(false_ids) / minutes, 2) if minutes else None}


def _rms(x: list[float]) -> float | None:
    return round(float(np.sqrt(np.mean(np.square(x)))), 4) if x else None


def _is_false(o: obstacle_msg.Obstacle, world: World, tw: float) -> bool:
    """No true surface within ``FALSE_GATE`` of the reported shape's axis ends and middle."""
    (x2, y2) = o.end
    probes = ((o.x, o.y), (x2, y2), ((o.x + x2) / 2, (o.y + y2) / 2))
    return all(float(np.min(np.abs(world.distance(p, tw)))) > o.radius + FALSE_GATE
               for p in probes)


def draw_world(ax: Any, plt: Any, msgs: Messages, profile: Any, t: np.ndarray,
               eta: np.ndarray, epoch_s: float) -> None:
    """Draw the obstacles, their safety circles and a few scans' points on the path panel."""
    world: World = profile.world
    params = guidance_avoidance(profile)
    margin = float(params.get('vessel_radius', 0.0)) + float(params.get('safety_radius', 0.0))
    span = (t[0] - epoch_s, t[-1] - epoch_s) if len(t) else (0.0, 0.0)
    for k, o in enumerate(world.obstacles):
        shape = o.at(span[0])
        label = 'obstacle (at start)' if k == 0 else None
        if isinstance(shape, Circle):
            ax.add_patch(plt.Circle(shape.center, shape.radius, color='tab:brown', alpha=0.5,
                                    label=label))
            ax.add_patch(plt.Circle(shape.center, shape.radius + margin, fill=False,
                                    ls=':', color='tab:red',
                                    label='safety circle' if k == 0 else None))
        elif isinstance(shape, (Polygon, Walls)):
            for (ax_, ay), (bx, by) in shape.segments():
                ax.plot([ax_, bx], [ay, by], color='tab:brown', lw=2, label=label)
                label = None
        if o.moving:
            track = np.array([o.at(ti).reference for ti in np.linspace(*span, 30)])
            ax.plot(track[:, 0], track[:, 1], color='tab:brown', ls='--', lw=0.8)
    _draw_scans(ax, msgs, profile, t, eta)


def _draw_scans(ax: Any, msgs: Messages, profile: Any, t: np.ndarray, eta: np.ndarray) -> None:
    scans = msgs.get('/scan', [])
    if not scans or not len(t):
        return
    tree = profile.frames
    for n, i in enumerate(np.linspace(0, len(scans) - 1, min(SCANS_DRAWN, len(scans)))
                          .astype(int)):
        scan = scans[i][1]
        ts = _stamp_s(scan)
        j = int(np.clip(np.searchsorted(t, ts), 0, len(t) - 1))
        x, y, psi = eta[j]
        r = np.asarray(scan.ranges, dtype=float)
        a = scan.angle_min + scan.angle_increment * np.arange(len(r))
        ok = np.isfinite(r)
        pts = np.column_stack((r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())))
        try:
            mount = tree.lookup('base_link', scan.header.frame_id)
            pts = mount.apply(pts)
        except FrameError:  # a frame the tree lacks: drawn from the CO
            pass
        c, s = math.cos(psi), math.sin(psi)
        wx = x + c * pts[:, 0] - s * pts[:, 1]
        wy = y + s * pts[:, 0] + c * pts[:, 1]
        ax.plot(wx, wy, '.', ms=1.5, color='tab:purple', alpha=0.6,
                label='scan points (truth pose)' if n == 0 else None)
