"""Figures and a picture of a recorded DP run (``enbarr scenario``), from the bag alone.

Every error is the simulator's truth (``sim/odometry``) against the guidance reference in
force at that instant (the latest ``guidance/reference`` stamped at or before the sample;
samples before the first reference are compared with the first one). Averages are over the
odometry samples, which come at the simulator's fixed rate. Times are in seconds from the
instant the mode began (the ``/mode`` message's record time).

**Station keeping** (``kind: station_keeping``). The automatic period runs from the first
``automatic`` mode to the next mode change (or the end of the run). ``settle_time`` is
stated by the scenario (``scenario.settle_time``), not found in the data, so the figures
can fail:

- ``position_error_rms_m``, ``position_error_max_m``, ``heading_error_rms_deg``,
  ``heading_error_max_deg``: over the FIXED evaluation window from ``settle_time`` after
  automatic began to the end of the automatic period (``window_s``: its start and end,
  from the start of the run). An empty window is an ``error``.
- ``time_to_settle_s``: the first time after which the position error stays within
  ``settle_band[0]`` [m] and the heading error within ``settle_band[1]`` [deg] to the end
  of the automatic period (0 if it never left the band; ``None`` if the last sample is
  outside). ``settled``: it is not ``None``; ``settled_in_time``: it is at most
  ``settle_time``.
- ``overall_position_error_rms_m``, ``overall_position_error_max_m``,
  ``overall_heading_error_rms_deg``, ``overall_heading_error_max_deg``: over the WHOLE
  automatic period, transient included.
- ``dropout_position_error_max_m`` (when the profile's ``sim_mocap`` node has
  ``dropout_windows``): the largest position error while the motion capture was lost and
  the second after, within the automatic period.

**Path** (``kind: path``). The guidance period runs from the first ``guidance`` mode to the
next mode change (or the end of the run). The path is the guidance node's
``path.waypoints``; with one waypoint, the line from where the vessel was when guidance
began.

- ``all_waypoints_visited``: the vessel came within ``VISIT_RADIUS`` of every waypoint, IN
  ORDER (each after the one before).
- ``path_time_s``: when it first came within ``ARRIVAL_RADIUS`` of the last waypoint after
  visiting the one before it (``None`` if it did not).
- ``cross_track_rms_m``: distance to the ACTIVE leg, the legs taken in order (leg k until
  the vessel is nearer leg k+1: no skipping ahead, no going back, so a vessel that drives
  the path the wrong way is far from it), RMS from the start of guidance to the arrival
  (to the end of the guidance period if it never arrives), so that the holding after the
  arrival does not dilute it; ``cross_track_max_m``: the largest over the whole guidance
  period.
- ``final_position_error_m``: distance from the last waypoint at the end of the guidance
  period.

**Run** (``kind: run``): no mode is judged (a test reads the bag); only the figures below.

Every kind: ``initial_mode`` (the mode in force when the recording began: the latched
``/mode`` the recorder takes first, at a time that depends on when it subscribed, so it is
given without one), ``modes`` (the changes after it: time from the start of the run, mode)
and ``thrust_saturation_s``,
the time the allocation delivered less than the controller asked. A run that never reached
the mode it is judged in gets an ``error`` and no figures.

A profile that avoids obstacles adds the figures of ``avoidance_metrics``; one with a
simulated camera and a detector those of ``vision_metrics`` (detection precision and recall
against the rendered ground truth, fusion position error and latency).

The picture draws the hull outline from the profile's geometry (``hull_radius``). Its axes
follow the chart, not the code's ENU: north up, east right (the same numbers: ENU x is east,
y north), headings as on a compass (0 = north, clockwise, degrees; ``framework.frames``),
and a heading error is positive when the vessel points clockwise of its reference.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

import numpy as np

from enbarr_interfaces import convert

from enbarr_core.framework.frames import compass_error_deg, compass_heading_deg
from enbarr_core.framework.kinematics import ssa
from enbarr_core.recording.bag import read_bag
from enbarr_core.tools.scenario import T0_NS
from enbarr_core.tools.avoidance_metrics import (AVOIDANCE_FIGURES, avoidance_figures,
                                                 avoids, draw_world)
from enbarr_core.tools.failsafe_metrics import (FAILSAFE_FIGURES, FAILSAFE_FLAGS,
                                                failsafe_figures, has_failsafes)
from enbarr_core.tools.vision_metrics import sees, VISION_FIGURES, vision_figures

#: The topics ``compute_metrics`` reads (``enbarr scenario`` records these by default).
METRIC_TOPICS = ('/sim/odometry', '/mode', '/force_command', '/allocation/delivered',
                 '/guidance/reference')
#: What ``plot_run`` reads besides them.
PLOT_TOPICS = ('/azimuth_commands', '/observer/bias')


@dataclass(frozen=True)
class Figure:
    """A figure of the JSON line that a scenario's ``targets`` may bound."""

    kinds: tuple[str, ...] | None = None  # the scenario kinds that report it (None: every)
    boolean: bool = False                 # a yes/no figure (its target: true or false)


_SK, _PATH = ('station_keeping',), ('path',)
#: Every figure a target may bound, by name (the module docstring defines them). A new
#: metric that a scenario may be judged by is added here too.
FIGURES: dict[str, Figure] = {
    'mode_changes': Figure(), 'thrust_saturation_s': Figure(), 'final_speed_mps': Figure(),
    **{name: Figure(_SK) for name in (
        'automatic_s', 'position_error_rms_m', 'position_error_max_m', 'heading_error_rms_deg',
        'heading_error_max_deg', 'time_to_settle_s', 'overall_position_error_rms_m',
        'overall_position_error_max_m', 'overall_heading_error_rms_deg',
        'overall_heading_error_max_deg', 'dropout_position_error_max_m')},
    'settled': Figure(_SK, boolean=True), 'settled_in_time': Figure(_SK, boolean=True),
    **{name: Figure(_PATH) for name in (
        'cross_track_rms_m', 'cross_track_max_m', 'path_time_s', 'final_position_error_m')},
    'all_waypoints_visited': Figure(_PATH, boolean=True),
    **{name: Figure() for name in AVOIDANCE_FIGURES},
    **{name: Figure() for name in VISION_FIGURES},
    **{name: Figure() for name in FAILSAFE_FIGURES},
    **{name: Figure(boolean=True) for name in FAILSAFE_FLAGS},
}


def figures_of(kind: str) -> dict[str, bool]:
    """Return the figures a scenario of ``kind`` reports: name -> whether it is yes/no."""
    return {name: f.boolean for name, f in FIGURES.items()
            if f.kinds is None or kind in f.kinds}

GUIDANCE_PLUGINS = ('guidance',)  # nodes whose path.waypoints is the path to follow
VISIT_RADIUS = 0.25    # a waypoint counts as visited this close [m]
ARRIVAL_RADIUS = 0.1   # arrived at the last waypoint this close [m]
DROPOUT_AFTER = 1.0    # the dropout error is judged up to this long after a window [s]
WORLD_EPOCH_S = T0_NS * 1e-9  # a scenario's world time 0 on its clock [s]
WORLD_MARGIN = 1.5      # the path panel shows the world this far around the run [m]
STAMP_TOL = 1e-6       # times closer than this are equal: stamps are integer ns read as float s
FINAL_SPEED_SPAN = 1.0  # final_speed_mps is over this last stretch of the run [s]


def _stamp(msg: Any) -> float:
    return convert.stamp_to_ns(msg.header.stamp) * 1e-9


def _series(msgs: list[tuple[int, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], eta (n, 3)) of Odometry messages."""
    t = np.array([_stamp(m) for _, m in msgs])
    eta = np.array([(m.pose.pose.position.x, m.pose.pose.position.y,
                     convert.quaternion_to_yaw(m.pose.pose.orientation)) for _, m in msgs])
    return t, eta


def _references(msgs: list[tuple[int, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], eta_d (n, 3)) of ``guidance/reference`` messages; NaN where not fed back."""
    if not msgs:
        return np.zeros(0), np.zeros((0, 3))
    t = np.array([_stamp(m) for _, m in msgs])
    eta_d = np.array([convert.transform_to_eta(m.points[0].transforms[0]) for _, m in msgs])
    return t, eta_d


def _modes(msgs: list[tuple[int, Any]]) -> list[tuple[float, str]]:
    return [(t * 1e-9, m.data) for t, m in msgs]


def _period(modes: list[tuple[float, str]], mode: str) -> tuple[float, float] | None:
    """[start, end) [s] of the first period in ``mode``: to the next change, or +inf."""
    start = next((t for t, m in modes if m == mode), None)
    if start is None:
        return None
    end = next((t for t, m in modes if t > start and m != mode), math.inf)
    return start, end


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point of ``p`` (n, 2) to the segment from ``a`` to ``b``."""
    ab = b - a
    s = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def _active_leg(p: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Index of the leg being followed at each point of ``p`` (n, 2).

    Legs are taken in order: leg k (waypoint k to k+1) stays active until the vessel is
    nearer leg k+1 than leg k (round a corner, or past the end of leg k); no leg is skipped
    and none is gone back to. The last leg stays active.
    """
    legs = np.zeros(len(p), dtype=int)
    k, last = 0, len(waypoints) - 2
    for i, q in enumerate(p[:, None, :]):
        while k < last and (_segment_distance(q, waypoints[k + 1], waypoints[k + 2])[0]
                            < _segment_distance(q, waypoints[k], waypoints[k + 1])[0]):
            k += 1
        legs[i] = k
    return legs


def _cross_track(p: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Distance of each point of ``p`` (n, 2) to the leg active there (``_active_leg``)."""
    legs = _active_leg(p, waypoints)
    d = np.zeros(len(p))
    for k in range(len(waypoints) - 1):
        on = legs == k
        d[on] = _segment_distance(p[on], waypoints[k], waypoints[k + 1])
    return d


def _visits(p: np.ndarray, waypoints: np.ndarray) -> list[int]:
    """Sample index of the visit of each waypoint, in order (each after the one before).

    Shorter than ``waypoints`` when one was not visited (and so none after it).
    """
    out: list[int] = []
    i = 0
    for w in waypoints:
        near = np.nonzero(np.linalg.norm(p[i:] - w, axis=1) < VISIT_RADIUS)[0]
        if not len(near):
            break
        i += int(near[0])
        out.append(i)
    return out


def _waypoints(profile: Any) -> np.ndarray:
    for n in profile.nodes:
        w = {**profile.parameters, **n.parameters}.get('path.waypoints')
        if n.plugin in GUIDANCE_PLUGINS and w and w != [0.0]:
            return np.array(w, dtype=float).reshape(-1, 2)
    return np.zeros((0, 2))


def hull_radius(profile: Any) -> float:
    """Radius of the drawn hull outline [m], from the profile.

    The profile's ``hull_radius`` if it gives one, else the circle through the farthest
    azimuth (they sit on the rim of a round hull), else 0 (no outline).
    """
    p = profile.parameters
    if 'hull_radius' in p:
        return float(p['hull_radius'])
    positions = [p[f'azimuths.{n}.position'] for n in p.get('azimuth_names', ())
                 if f'azimuths.{n}.position' in p]
    return max((math.hypot(x, y) for x, y in positions), default=0.0)


def _dropout_windows(profile: Any) -> list[tuple[float, float]]:
    for n in profile.nodes:
        w = {**profile.parameters, **n.parameters}.get('dropout_windows')
        if n.plugin == 'sim_mocap' and w and w != [0.0]:
            return list(zip(w[::2], w[1::2]))
    return []


def _final_speed(t: np.ndarray, eta: np.ndarray) -> float:
    """Return the speed over ground over the last ``FINAL_SPEED_SPAN`` of the run [m/s].

    The distance made good in it over its length (0 for a run shorter than two samples).
    """
    if len(t) < 2:
        return 0.0
    i = min(int(np.searchsorted(t, t[-1] - FINAL_SPEED_SPAN + STAMP_TOL)), len(t) - 2)
    return float(np.linalg.norm(eta[-1, :2] - eta[i, :2]) / (t[-1] - t[i]))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2)))


Messages = dict[str, list[tuple[int, Any]]]  # read_bag's answer: {topic: [(time ns, msg)]}


def compute_metrics(bag: Path, spec: Any, profile: Any,
                    msgs: Messages | None = None) -> dict[str, Any]:
    """Compute the figures of a recorded run from its bag (see the module docstring).

    ``msgs``: the bag as ``read_bag`` returned it, when the caller has read it already.
    """
    msgs = read_bag(bag) if msgs is None else msgs
    t, eta = _series(msgs['/sim/odometry'])
    t0 = t[0]
    modes = _modes(msgs.get('/mode', []))
    changes = [(tm, m) for i, (tm, m) in enumerate(modes) if i and m != modes[i - 1][1]]
    out: dict[str, Any] = {'initial_mode': modes[0][1] if modes else None,
                           'modes': [(round(tm - t0, 2), m) for tm, m in changes],
                           'mode_changes': len(changes),
                           'final_speed_mps': round(_final_speed(t, eta), 4)}
    # Thrust saturation: allocation delivered less than the controller asked.
    asked = {_stamp(m): m.wrench for _, m in msgs.get('/force_command', [])}
    sat = [not math.isclose(_norm(m.wrench), _norm(asked[_stamp(m)]), rel_tol=1e-6,
                            abs_tol=1e-9)
           for _, m in msgs.get('/allocation/delivered', []) if _stamp(m) in asked]
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    ts = sorted(asked)
    sample = float(np.median(np.diff(ts))) if len(ts) > 1 else period
    out['thrust_saturation_s'] = round(sum(sat) * sample, 2)
    ref_t, ref = _references(msgs.get('/guidance/reference', []))
    if spec.kind == 'station_keeping':
        out.update(_station_keeping(t, eta, ref_t, ref, modes, spec, profile))
    elif spec.kind == 'path':
        out.update(_path(t, eta, modes, profile))
    if avoids(profile):
        out.update(avoidance_figures(msgs, profile, t, eta, WORLD_EPOCH_S,
                                     path=out if spec.kind == 'path' else None,
                                     cross_track=_guidance_cross_track(t, eta, modes, profile)))
    if sees(profile):
        out.update(vision_figures(msgs, profile, t, eta, WORLD_EPOCH_S))
    if has_failsafes(profile):
        out.update(failsafe_figures(msgs, profile, T0_NS))
    return out


def _guidance_cross_track(t: np.ndarray, eta: np.ndarray, modes: list[tuple[float, str]],
                          profile: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """Return (times, cross-track errors) over the guidance period, as the path figures do."""
    guided = _period(modes, 'guidance')
    wps = _waypoints(profile)
    if guided is None or len(wps) < 2:
        return None
    sel = (t >= guided[0] - STAMP_TOL) & (t < guided[1] - STAMP_TOL)
    if not sel.any():
        return None
    return t[sel], _cross_track(eta[sel, :2], wps)


def _station_keeping(t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray, ref: np.ndarray,
                     modes: list[tuple[float, str]], spec: Any,
                     profile: Any) -> dict[str, Any]:
    """Compute the station-keeping figures (see the module docstring)."""
    t0 = t[0]
    auto = _period(modes, 'automatic')
    if auto is None or not len(ref_t):
        return {'error': 'never in automatic mode'}
    start, end = auto
    sel = (t >= start - STAMP_TOL) & (t < end - STAMP_TOL)
    if not sel.any():
        return {'error': 'no odometry in the automatic period'}
    ta = t[sel]
    idx = np.clip(np.searchsorted(ref_t, ta, side='right') - 1, 0, len(ref_t) - 1)
    pos_err = np.linalg.norm(eta[sel, :2] - ref[idx, :2], axis=1)
    head_err = np.degrees(np.abs(ssa(eta[sel, 2] - ref[idx, 2])))
    out: dict[str, Any] = {
        'automatic_s': round(float((end if math.isfinite(end) else ta[-1]) - start), 2),
        'settle_time_s': spec.settle_time,
        'overall_position_error_rms_m': round(_rms(pos_err), 4),
        'overall_position_error_max_m': round(float(pos_err.max()), 4),
        'overall_heading_error_rms_deg': round(_rms(head_err), 3),
        'overall_heading_error_max_deg': round(float(head_err.max()), 3),
    }
    band_m, band_deg = spec.settle_band
    outside = np.nonzero((pos_err > band_m) | (head_err > band_deg))[0]
    if not len(outside):
        settle: float | None = 0.0
    elif outside[-1] + 1 < len(ta):
        settle = round(float(ta[outside[-1] + 1] - start), 2)
    else:
        settle = None
    out.update({'time_to_settle_s': settle, 'settled': settle is not None,
                'settled_in_time': settle is not None and settle <= spec.settle_time})
    windows = _dropout_windows(profile)
    if windows:  # error while the motion capture was lost and the second after it
        during = np.zeros(len(ta), dtype=bool)
        for a, b in windows:
            during |= (ta - t0 >= a - STAMP_TOL) & (ta - t0 < b + DROPOUT_AFTER - STAMP_TOL)
        if during.any():
            out['dropout_position_error_max_m'] = round(float(pos_err[during].max()), 4)
    window = ta - start >= spec.settle_time - STAMP_TOL
    if not window.any():
        out['error'] = (f'the evaluation window is empty: automatic lasted '
                        f'{ta[-1] - start:.2f} s, settle_time is {spec.settle_time} s')
        return out
    pe, he = pos_err[window], head_err[window]
    out.update({
        'window_s': [round(float(ta[window][0] - t0), 2), round(float(ta[window][-1] - t0), 2)],
        'position_error_rms_m': round(_rms(pe), 4),
        'position_error_max_m': round(float(pe.max()), 4),
        'heading_error_rms_deg': round(_rms(he), 3),
        'heading_error_max_deg': round(float(he.max()), 3),
    })
    return out


def _path(t: np.ndarray, eta: np.ndarray, modes: list[tuple[float, str]],
          profile: Any) -> dict[str, Any]:
    """Compute the path figures (see the module docstring)."""
    guided = _period(modes, 'guidance')
    wps = _waypoints(profile)
    if guided is None or len(wps) < 1:
        return {'error': 'never in guidance mode, or no path'}
    start, end = guided
    sel = (t >= start - STAMP_TOL) & (t < end - STAMP_TOL)
    if not sel.any():
        return {'error': 'no odometry in the guidance period'}
    ta, p = t[sel], eta[sel, :2]
    if len(wps) == 1:  # go to a waypoint: the path is the line from where guidance began
        wps = np.vstack((p[0], wps))
    d = _cross_track(p, wps)
    visits = _visits(p, wps)
    visited = len(visits) == len(wps)
    # Arrival: within ARRIVAL_RADIUS of the last waypoint, after visiting the one before it.
    after = visits[len(wps) - 2] if len(visits) >= len(wps) - 1 else len(p)
    reached = after + np.nonzero(np.linalg.norm(p[after:] - wps[-1], axis=1)
                                 < ARRIVAL_RADIUS)[0]
    arrived = len(reached) > 0
    followed = d[:reached[0] + 1] if arrived else d
    return {
        'cross_track_rms_m': round(_rms(followed), 4),
        'cross_track_max_m': round(float(d.max()), 4),
        'all_waypoints_visited': bool(visited),
        'path_time_s': round(float(ta[reached[0]] - start), 2) if arrived else None,
        'final_position_error_m': round(float(np.linalg.norm(p[-1] - wps[-1])), 4),
    }


def _norm(w: Any) -> float:
    return math.sqrt(w.force.x ** 2 + w.force.y ** 2 + w.torque.z ** 2)


# -- the picture ----------------------------------------------------------------------------
SIMULATOR_PLUGIN = 'vessel3dof_simulator'  # the node whose current and bias are injected
COURSE_MIN_SPEED = 0.02  # a course over ground is drawn only above this speed [m/s]
NO_DATA = dict(ha='center', va='center', fontsize=8, color='tab:gray')


def _velocities(msgs: list[tuple[int, Any]]) -> np.ndarray:
    """nu_d (n, 3) [m/s, m/s, rad/s] (body) of ``guidance/reference`` messages."""
    return np.array([convert.twist_to_nu3(m.points[0].velocities[0]) for _, m in msgs]) \
        if msgs else np.zeros((0, 3))


def speed_over_ground(t: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Speed over ground [m/s] at each sample, from the positions (central differences)."""
    if len(t) < 2:
        return np.zeros(len(t))
    return np.hypot(np.gradient(eta[:, 0], t), np.gradient(eta[:, 1], t))


def injected_disturbance(profile: Any, t: np.ndarray, psi: np.ndarray) -> np.ndarray | None:
    """Return the simulator's injected disturbance at each sample (None without one).

    The current and force bias, as the world-frame force [F_x east, F_y north, N]
    [N, N, N m] they put on the hull held still
    (``models.vessel3dof.disturbance_at_rest``: the simulator's own damping, the vessel's true
    heading ``psi`` and the current at time ``t`` [s]); None without a 3-DOF simulator.

    It is what the observer's bias estimate (world frame, no current in its model) converges to
    while the vessel holds station; while it moves, the estimate also takes up the model error.
    """
    sim = next((n for n in profile.nodes if n.plugin == SIMULATOR_PLUGIN), None)
    if sim is None:
        return None
    from enbarr_core.models.vessel3dof import current_at, disturbance_at_rest
    from enbarr_core.simulation.vessel3dof_simulator_node import (
        SPECS, Vessel3DofSimulatorSettings)
    given = {**profile.parameters, **sim.parameters}
    s = Vessel3DofSimulatorSettings.from_params({p.name: given.get(p.name, p.default)
                                                 for p in SPECS})
    V = np.array([current_at(ti, s.current, s.current_amplitude, s.current_period)
                  for ti in t]).reshape(-1, 2)
    return disturbance_at_rest(s.vessel, psi, V, s.bias)


def _compass_axis(ax: Any) -> None:
    ax.set_ylim(0.0, 360.0)
    ax.set_yticks(range(0, 361, 90), ['N 0', 'E 90', 'S 180', 'W 270', 'N 360'])


def plot_run(bag: Path, spec: Any, profile: Any, png: Path,
             msgs: Messages | None = None, verdict: dict[str, Any] | None = None) -> Path:
    """Draw the run for an engineer (see the panels below) into ``png`` and return it.

    Left: the path (north up) with the hull at intervals; for station keeping the position
    about the hold point at the scale of its error [cm] with the settle band; the targets
    and the verdict (``verdict``: ``targets.judge``'s answer). Right, against time: errors;
    compass heading with its reference (and, in guidance, the course reference from nu_d
    against the course over ground: line of sight steers by course); speed over ground against
    the commanded speed; the observer's bias estimate against the injected disturbance; each
    azimuth's commanded angle and thrust. ``msgs``: the bag as ``read_bag`` returned it, when
    the caller has read it already. An ROV's run has its own plot (``tools.rov_plot``).
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from enbarr_core.tools.rov_plot import is_rov, plot_rov_run

    msgs = read_bag(bag) if msgs is None else msgs
    if is_rov(profile):
        return plot_rov_run(msgs, profile, png, verdict)
    t, eta = _series(msgs['/sim/odometry'])
    t0 = t[0]
    ref_msgs = msgs.get('/guidance/reference', [])
    ref_t, ref = _references(ref_msgs)
    nu_d = _velocities(ref_msgs)
    modes = _modes(msgs.get('/mode', []))
    station = spec.kind == 'station_keeping'
    fig = plt.figure(figsize=(15, 19), layout='constrained')
    grid = fig.add_gridspec(6, 2, width_ratios=(1.0, 1.0))
    path_ax = fig.add_subplot(grid[0:3 if station else 4, 0])
    world = len(getattr(profile, 'world', ()))
    if world:
        draw_world(path_ax, plt, msgs, profile, t, eta, WORLD_EPOCH_S)
    _path_panel(path_ax, plt, t, eta, ref_t, ref, spec, profile)
    if world:  # at the scale of the run, not of the basin's walls
        wps = _waypoints(profile) if spec.kind == 'path' else np.zeros((0, 2))
        around = np.vstack((eta[:, :2], wps))
        lo, hi = around.min(axis=0) - WORLD_MARGIN, around.max(axis=0) + WORLD_MARGIN
        path_ax.set_xlim(lo[0], hi[0])
        path_ax.set_ylim(lo[1], hi[1])
        path_ax.set_aspect('equal', adjustable='box')
    if station:
        _hold_panel(fig.add_subplot(grid[3:5, 0]), plt, t, eta, ref_t, ref, modes, spec)
    _verdict_panel(fig.add_subplot(grid[5, 0] if station else grid[4:6, 0]), verdict)
    ax = fig.add_subplot(grid[0, 1])
    _errors_panel(ax, t, eta, ref_t, ref, modes, spec, profile)
    _heading_panel(fig.add_subplot(grid[1, 1], sharex=ax), t, eta, ref_t, ref, nu_d, modes)
    _speed_panel(fig.add_subplot(grid[2, 1], sharex=ax), t, eta, ref_t, nu_d, spec, profile)
    _bias_panel(fig.add_subplot(grid[3, 1], sharex=ax), t, eta, msgs, profile)
    cmds = msgs.get('/azimuth_commands', [])
    _azimuth_panels(fig.add_subplot(grid[4, 1], sharex=ax),
                    fig.add_subplot(grid[5, 1], sharex=ax), t0, cmds, profile)
    verdict_title(fig, profile.name, verdict)
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png


def verdict_title(fig: Any, name: str, verdict: dict[str, Any] | None) -> None:
    """Title a run's figure with its verdict (green PASS, red FAIL and what failed)."""
    if verdict is None:
        return
    failed = verdict['failed']
    fig.suptitle(f'{name}: ' + ('PASS, every target met' if not failed
                                else f'FAIL: {", ".join(failed)}'),
                 color='tab:green' if not failed else 'tab:red', fontsize=14,
                 fontweight='bold')


def _path_panel(ax: Any, plt: Any, t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray,
                ref: np.ndarray, spec: Any, profile: Any) -> None:
    wps = _waypoints(profile) if spec.kind == 'path' else np.zeros((0, 2))
    radius = hull_radius(profile)
    if len(wps):
        ax.plot(wps[:, 0], wps[:, 1], 'k--', lw=1, label='path')
    ax.plot(eta[:, 0], eta[:, 1], lw=1.2, label='vessel (truth)')
    if len(ref_t):  # NaN (line of sight: no position reference) leaves gaps
        ax.plot(ref[:, 0], ref[:, 1], lw=0.8, alpha=0.7, label='reference')
    step = max(1, len(t) // 12)
    for x, y, psi in eta[::step]:
        ax.add_patch(plt.Circle((x, y), radius, fill=False, lw=0.8, color='tab:gray'))
        ax.plot([x, x + radius * math.cos(psi)], [y, y + radius * math.sin(psi)],
                color='tab:red', lw=1)
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('east [m] (odom x)')
    ax.set_ylabel('north [m] (odom y)')
    ax.set_title(f'{profile.name}: path, north up; hull and bow (red) at intervals')
    ax.legend(loc='best', fontsize=8)
    ax.grid(True, alpha=0.3)


def _hold_panel(ax: Any, plt: Any, t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray,
                ref: np.ndarray, modes: list[tuple[float, str]], spec: Any) -> None:
    """Position about the hold point in force, over the automatic period, in centimetres."""
    ax.set_title('station keeping: position about the hold point, north up [cm]')
    ax.set_xlabel('east of the hold point [cm]')
    ax.set_ylabel('north of the hold point [cm]')
    band_cm = 100.0 * spec.settle_band[0]
    ax.add_patch(plt.Circle((0.0, 0.0), band_cm, fill=False, ls='--', color='tab:green',
                            label=f'settle band {band_cm:g} cm'))
    ax.plot([0.0], [0.0], 'k+', ms=12, label='hold point')
    auto = _period(modes, 'automatic')
    limit = 1.3 * band_cm
    if auto is not None and len(ref_t):
        sel = (t >= auto[0] - STAMP_TOL) & (t < auto[1] - STAMP_TOL)
        idx = np.clip(np.searchsorted(ref_t, t[sel], side='right') - 1, 0, len(ref_t) - 1)
        d = 100.0 * (eta[sel, :2] - ref[idx, :2])
        window = t[sel] - auto[0] >= spec.settle_time - STAMP_TOL
        ax.plot(d[~window, 0], d[~window, 1], lw=0.6, color='tab:gray', alpha=0.6,
                label=f'first {spec.settle_time:g} s (settling; may leave the frame)')
        ax.plot(d[window, 0], d[window, 1], lw=0.8, color='tab:blue',
                label='evaluation window')
        if window.any():
            limit = max(limit, 1.2 * float(np.abs(d[window]).max()))
    else:
        ax.text(0.5, 0.2, 'never in automatic mode', transform=ax.transAxes, **NO_DATA)
    ax.set_xlim(-limit, limit)
    ax.set_ylim(-limit, limit)
    ax.set_aspect('equal', adjustable='box')
    ax.legend(loc='upper right', fontsize=7)
    ax.grid(True, alpha=0.3)


def _verdict_panel(ax: Any, verdict: dict[str, Any] | None) -> None:
    from enbarr_core.tools.targets import describe
    ax.set_axis_off()
    ax.set_title('targets (scenario.targets) and the verdict')
    if verdict is None:
        ax.text(0.5, 0.5, 'not judged', transform=ax.transAxes, **NO_DATA)
        return
    lines = [('verdict: ' + verdict['verdict'].upper(),
              'tab:green' if verdict['verdict'] == 'pass' else 'tab:red')]
    if 'error' in verdict['failed']:
        lines.append(('the run reported an error (see the JSON line)', 'tab:red'))
    lines += [(describe(name, r), 'black' if r['pass'] else 'tab:red')
              for name, r in verdict['targets'].items()]
    for i, (text, color) in enumerate(lines):
        ax.text(0.0, 1.0 - i / max(len(lines), 8), text, transform=ax.transAxes, va='top',
                fontsize=9, family='monospace', color=color)


def _mode_lines(ax: Any, modes: list[tuple[float, str]], t0: float, label: bool) -> None:
    for tm, m in modes:
        ax.axvline(tm - t0, color='k', lw=0.6, ls=':')
        if label:
            ax.text(tm - t0, ax.get_ylim()[1], m, fontsize=7, rotation=90, va='top')


def _errors_panel(ax2: Any, t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray, ref: np.ndarray,
                  modes: list[tuple[float, str]], spec: Any, profile: Any) -> None:
    t0 = t[0]
    wps = _waypoints(profile) if spec.kind == 'path' else np.zeros((0, 2))
    if len(ref_t):
        idx = np.clip(np.searchsorted(ref_t, t, side='right') - 1, 0, len(ref_t) - 1)
        valid = t >= ref_t[0]
        ax2.plot(t[valid] - t0, np.linalg.norm(eta[valid, :2] - ref[idx[valid], :2], axis=1),
                 label='position error [m]')
        if len(wps) > 1:  # no position reference along the path: the distance to it instead
            ax2.plot(t[valid] - t0, _cross_track(eta[valid, :2], wps), lw=0.8,
                     color='tab:green', label='distance to the active leg [m]')
        ax2b = ax2.twinx()
        ax2b.plot(t[valid] - t0, compass_error_deg(eta[valid, 2], ref[idx[valid], 2]),
                  color='tab:orange', lw=0.8, label='heading error [deg], + clockwise')
        ax2b.set_ylabel('heading error [deg], + clockwise')
        ax2b.legend(loc='upper right', fontsize=7)
    _mode_lines(ax2, modes, t0, label=True)
    ax2.set_ylabel('position error [m]')
    ax2.legend(loc='upper left', fontsize=7)
    ax2.set_title('errors against the guidance reference')
    ax2.grid(True, alpha=0.3)


def _heading_panel(axh: Any, t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray,
                   ref: np.ndarray, nu_d: np.ndarray, modes: list[tuple[float, str]]) -> None:
    """Compass heading and its reference; in guidance, the course reference and the course.

    The course reference is the direction of the reference velocity nu_d in the world,
    R(psi) nu_d, with psi the vessel's true heading at the reference's stamp (the guidance
    law rotated it with the estimate's, a fraction of a degree away): in line of sight, the
    LOS course chi_d. The course over ground is drawn only above ``COURSE_MIN_SPEED``.
    """
    t0 = t[0]
    axh.plot(t - t0, compass_heading_deg(eta[:, 2]), '.', ms=1.5, label='heading (truth)')
    if len(ref_t):
        axh.plot(ref_t - t0, compass_heading_deg(ref[:, 2]), '.', ms=1.0, alpha=0.6,
                 label='heading reference')
    guided = _period(modes, 'guidance')
    if guided is not None and len(ref_t):
        on = (ref_t >= guided[0] - STAMP_TOL) & (ref_t < guided[1] - STAMP_TOL) \
            & (np.hypot(nu_d[:, 0], nu_d[:, 1]) > COURSE_MIN_SPEED)
        psi = np.interp(ref_t[on], t, np.unwrap(eta[:, 2]))
        chi_d = psi + np.arctan2(nu_d[on, 1], nu_d[on, 0])
        axh.plot(ref_t[on] - t0, compass_heading_deg(chi_d), '.', ms=1.0, color='tab:red',
                 label='course reference (R(psi) nu_d; LOS chi_d)')
        moving = speed_over_ground(t, eta) > COURSE_MIN_SPEED
        vx, vy = np.gradient(eta[:, 0], t), np.gradient(eta[:, 1], t)
        axh.plot(t[moving] - t0, compass_heading_deg(np.arctan2(vy, vx)[moving]), '.',
                 ms=1.0, color='tab:purple', alpha=0.6, label='course over ground (truth)')
    _compass_axis(axh)
    _mode_lines(axh, modes, t0, label=False)
    axh.set_ylabel('heading [deg] (compass)')
    axh.set_title('compass heading and course: 0 = north, clockwise')
    axh.legend(loc='upper right', fontsize=7, markerscale=6)
    axh.grid(True, alpha=0.3)


def _speed_panel(ax: Any, t: np.ndarray, eta: np.ndarray, ref_t: np.ndarray, nu_d: np.ndarray,
                 spec: Any, profile: Any) -> None:
    t0 = t[0]
    ax.plot(t - t0, speed_over_ground(t, eta), lw=0.9, label='speed over ground (truth)')
    if len(ref_t):
        ax.plot(ref_t - t0, np.hypot(nu_d[:, 0], nu_d[:, 1]), lw=0.9, color='tab:red',
                label='commanded: reference speed |nu_d|')
    speed = _guidance_speed(profile) if spec.kind == 'path' else None
    if speed is not None:
        ax.axhline(speed, color='k', lw=0.6, ls='--', label=f'path.speed {speed:g} m/s')
    ax.set_ylabel('speed [m/s]')
    ax.set_title('speed over ground against the commanded speed')
    ax.legend(loc='upper right', fontsize=7)
    ax.grid(True, alpha=0.3)


def _guidance_speed(profile: Any) -> float | None:
    for n in profile.nodes:
        if n.plugin in GUIDANCE_PLUGINS:
            speed = {**profile.parameters, **n.parameters}.get('path.speed')
            return None if speed is None else float(speed)
    return None


def _bias_panel(ax: Any, t: np.ndarray, eta: np.ndarray, msgs: Messages, profile: Any) -> None:
    t0 = t[0]
    ax.set_title('observer bias estimate (solid) against the injected disturbance on the '
                 'still hull (dashed), world frame', fontsize=10)
    ax.set_ylabel('force [N], moment [N m]')
    bias = msgs.get('/observer/bias', [])
    injected = injected_disturbance(profile, t, eta[:, 2])
    if not bias and injected is None:
        ax.text(0.5, 0.5, 'no observer bias and no 3-DOF simulator in this run',
                transform=ax.transAxes, **NO_DATA)
        return
    labels = ('east X [N]', 'north Y [N]', 'yaw N [N m], + counter-clockwise')
    colors = ('tab:blue', 'tab:orange', 'tab:green')
    if bias:
        tb = np.array([_stamp(m) for _, m in bias]) - t0
        b = np.array([convert.wrench_to_tau3(m.wrench) for _, m in bias])
        for i in range(3):
            ax.plot(tb, b[:, i], lw=0.9, color=colors[i], label=f'b_hat {labels[i]}')
    if injected is not None:
        for i in range(3):
            ax.plot(t - t0, injected[:, i], lw=0.9, ls='--', color=colors[i],
                    label=f'injected {labels[i]}')
    ax.legend(loc='upper right', fontsize=7, ncol=2)
    ax.grid(True, alpha=0.3)


def _azimuth_panels(axa: Any, axt: Any, t0: float, cmds: list[tuple[int, Any]],
                    profile: Any) -> None:
    """Draw each azimuth's commanded angle with its servo travel, and its thrust.

    Angles as people read them: degrees from ahead, + to starboard (clockwise seen from above,
    as a compass); the allocation's angle is counter-clockwise.
    """
    axa.set_title('azimuth angles (commanded): 0 = ahead, + to starboard (clockwise)')
    axa.set_ylabel('azimuth angle [deg]')
    axt.set_title('azimuth thrust (commanded)')
    axt.set_ylabel('thrust [N]')
    axt.set_xlabel('time [s]')
    if cmds:
        tc = np.array([_stamp(m) for _, m in cmds]) - t0
        thrust = np.array([list(m.effort) for _, m in cmds])
        angle = -np.degrees(np.array([list(m.position) for _, m in cmds]))
        p = profile.parameters
        for i, name in enumerate(cmds[0][1].name):
            line, = axa.plot(tc, angle[:, i], lw=0.9, label=name)
            axt.plot(tc, thrust[:, i], lw=0.8, label=name)
            for key in ('angle_min', 'angle_max'):
                if f'azimuths.{name}.{key}' in p:
                    axa.axhline(-math.degrees(p[f'azimuths.{name}.{key}']), lw=0.6, ls=':',
                                color=line.get_color())
        axa.legend(loc='upper right', fontsize=7, title='dotted: servo travel',
                   title_fontsize=7)
        axt.legend(loc='upper right', fontsize=7)
    else:
        for ax in (axa, axt):
            ax.text(0.5, 0.5, 'no azimuth_commands in this run', transform=ax.transAxes,
                    **NO_DATA)
    axa.grid(True, alpha=0.3)
    axt.grid(True, alpha=0.3)
