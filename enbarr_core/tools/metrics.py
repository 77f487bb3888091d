"""Figures and a picture of a recorded DP run (``enbarr scenario``), from the bag alone.

The figures: errors after settling, cross-track error, time to settle, thrust saturation
time. The picture draws the hull outline from the profile's geometry (``hull_radius``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from enbarr_interfaces import convert

from enbarr_core.framework.kinematics import ssa
from enbarr_core.recording.bag import read_bag

GUIDANCE_PLUGINS = ('guidance',)  # nodes whose path.waypoints is the path to follow


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


def _first(modes: list[tuple[float, str]], mode: str) -> float | None:
    return next((t for t, m in modes if m == mode), None)


def _segment_distance(p: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Distance of each point of ``p`` (n, 2) to the polyline ``waypoints`` (k, 2)."""
    best = np.full(len(p), np.inf)
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        ab = b - a
        s = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - (a + s[:, None] * ab), axis=1))
    return best


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


def compute_metrics(bag: Path, spec: Any, profile: Any) -> dict[str, Any]:
    """Compute the figures of a recorded run from its bag (see the module docstring)."""
    msgs = read_bag(bag)
    t, eta = _series(msgs['/sim/odometry'])
    t0 = t[0]
    modes = _modes(msgs.get('/mode', []))
    out: dict[str, Any] = {'modes': [(round(tm - t0, 2), m) for tm, m in modes]}
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
        start = _first(modes, 'automatic')
        if start is None or not len(ref_t):
            out['error'] = 'never in automatic mode'
            return out
        sel = t >= start
        idx = np.clip(np.searchsorted(ref_t, t[sel], side='right') - 1, 0, len(ref_t) - 1)
        pos_err = np.linalg.norm(eta[sel, :2] - ref[idx, :2], axis=1)
        head_err = np.degrees(np.abs(ssa(eta[sel, 2] - ref[idx, 2])))
        band_m, band_deg = spec.settle_band
        outside = np.nonzero((pos_err > band_m) | (head_err > band_deg))[0]
        settled_i = 0 if not len(outside) else outside[-1] + 1
        if settled_i >= len(pos_err):
            out.update({'settled': False, 'time_to_settle_s': None})
            return out
        pe, he = pos_err[settled_i:], head_err[settled_i:]
        windows = _dropout_windows(profile)
        if windows:  # error while the motion capture was lost and the second after it
            ts = t[sel] - t0
            during = np.zeros(len(ts), dtype=bool)
            for a, b in windows:
                during |= (ts >= a) & (ts < b + 1.0)
            if during.any():
                out['dropout_position_error_max_m'] = round(float(pos_err[during].max()), 4)
        out.update({
            'settled': True,
            'time_to_settle_s': round(float(t[sel][settled_i] - start), 2),
            'position_error_rms_m': round(float(np.sqrt(np.mean(pe ** 2))), 4),
            'position_error_max_m': round(float(pe.max()), 4),
            'heading_error_rms_deg': round(float(np.sqrt(np.mean(he ** 2))), 3),
            'heading_error_max_deg': round(float(he.max()), 3),
        })
    else:
        start = _first(modes, 'guidance')
        wps = _waypoints(profile)
        if start is None or len(wps) < 1:
            out['error'] = 'never in guidance mode, or no path'
            return out
        end = next((tm for tm, m in modes if tm > start and m != 'guidance'), t[-1])
        sel = (t >= start) & (t <= end)
        if len(wps) == 1:  # go to a waypoint: the path is the line from where guidance began
            wps = np.vstack((eta[sel][0, :2], wps))
        d = _segment_distance(eta[sel, :2], wps)
        p = eta[sel, :2]
        visited = all(np.min(np.linalg.norm(p - w, axis=1)) < 0.25 for w in wps)
        # Arrival: first time within 0.1 m of the last waypoint after passing the one before.
        before = np.nonzero(np.linalg.norm(p - wps[-2], axis=1) < 0.25)[0]
        after = before[0] if len(before) else len(p)
        reached = after + np.nonzero(np.linalg.norm(p[after:] - wps[-1], axis=1) < 0.1)[0]
        out.update({
            'cross_track_rms_m': round(float(np.sqrt(np.mean(d ** 2))), 4),
            'cross_track_max_m': round(float(d.max()), 4),
            'all_waypoints_visited': bool(visited),
            'path_time_s': round(float(t[sel][reached[0]] - start), 2) if (
                visited and len(reached)) else None,
        })
    return out


def _norm(w: Any) -> float:
    return math.sqrt(w.force.x ** 2 + w.force.y ** 2 + w.torque.z ** 2)


def plot_run(bag: Path, spec: Any, profile: Any, png: Path) -> Path:
    """Path in the NE plane with the vessel outline at intervals, errors and thrust."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    msgs = read_bag(bag)
    t, eta = _series(msgs['/sim/odometry'])
    t0 = t[0]
    fig = plt.figure(figsize=(12, 7), layout='constrained')
    grid = fig.add_gridspec(2, 2, width_ratios=(1.1, 1.0))
    ax = fig.add_subplot(grid[:, 0])
    wps = _waypoints(profile) if spec.kind == 'path' else np.zeros((0, 2))
    radius = hull_radius(profile)
    if len(wps):
        ax.plot(wps[:, 0], wps[:, 1], 'k--', lw=1, label='path')
    ax.plot(eta[:, 0], eta[:, 1], lw=1.2, label='vessel (truth)')
    ref_t, ref = _references(msgs.get('/guidance/reference', []))
    if len(ref_t):  # NaN (line of sight: no position reference) leaves gaps
        ax.plot(ref[:, 0], ref[:, 1], lw=0.8, alpha=0.7, label='reference')
    step = max(1, len(t) // 12)
    for x, y, psi in eta[::step]:
        ax.add_patch(plt.Circle((x, y), radius, fill=False, lw=0.8, color='tab:gray'))
        ax.plot([x, x + radius * math.cos(psi)], [y, y + radius * math.sin(psi)],
                color='tab:red', lw=1)
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_xlabel('east [m]')
    ax.set_ylabel('north [m]')
    ax.set_title(f'{profile.name}: path in the NE plane, hull outline at intervals')
    ax.legend(loc='best', fontsize=8)
    ax.grid(True, alpha=0.3)
    ax2 = fig.add_subplot(grid[0, 1])
    if len(ref_t):
        idx = np.clip(np.searchsorted(ref_t, t, side='right') - 1, 0, len(ref_t) - 1)
        valid = t >= ref_t[0]
        ax2.plot(t[valid] - t0, np.linalg.norm(eta[valid, :2] - ref[idx[valid], :2], axis=1),
                 label='position error [m]')
        if len(wps) > 1:  # no position reference along the path: the distance to it instead
            ax2.plot(t[valid] - t0, _segment_distance(eta[valid, :2], wps), lw=0.8,
                     color='tab:green', label='distance to the path [m]')
        ax2b = ax2.twinx()
        ax2b.plot(t[valid] - t0, np.degrees(ssa(eta[valid, 2] - ref[idx[valid], 2])),
                  color='tab:orange', lw=0.8, label='heading error [deg]')
        ax2b.set_ylabel('heading error [deg]')
        ax2b.legend(loc='upper right', fontsize=7)
    for tm, m in _modes(msgs.get('/mode', [])):
        ax2.axvline(tm - t0, color='k', lw=0.6, ls=':')
        ax2.text(tm - t0, ax2.get_ylim()[1], m, fontsize=7, rotation=90, va='top')
    ax2.set_ylabel('position error [m]')
    ax2.legend(loc='upper left', fontsize=7)
    ax2.set_title('errors against the guidance reference')
    ax2.grid(True, alpha=0.3)
    ax3 = fig.add_subplot(grid[1, 1], sharex=ax2)
    cmds = msgs.get('/azimuth_commands', [])
    if cmds:
        tc = np.array([_stamp(m) for _, m in cmds]) - t0
        thrust = np.array([list(m.effort) for _, m in cmds])
        for i, name in enumerate(cmds[0][1].name):
            ax3.plot(tc, thrust[:, i], lw=0.8, label=name)
        ax3.legend(fontsize=7)
    ax3.set_xlabel('time [s]')
    ax3.set_ylabel('thrust [N]')
    ax3.set_title('azimuth thrust')
    ax3.grid(True, alpha=0.3)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
