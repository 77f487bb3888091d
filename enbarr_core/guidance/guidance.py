"""Guidance laws of a 3-DOF surface vessel: references for :mod:`dp_control`.

Fossen 2021 (Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed.), ch. 12
(guidance systems: reference trajectories, lookahead-based line-of-sight path following).
World ENU (x east, y north), headings and courses CCW from east, body velocities FLU.

Each law is stateful and has ``reference(eta_hat, dt) -> Reference``: the clock advances by
``dt`` [s] (time since the previous call) and the reference for now is returned.

* :class:`HoldPose`: station keeping at a fixed pose.
* :class:`GoToWaypoint`: a reference point moving from the start pose to the waypoint on the
  straight line, with a trapezoidal speed profile (speed and acceleration limits, heading
  turned in step with the position and within its own rate limits), then holding it.
* :class:`LosPath`: lookahead-based LOS path following through waypoints, then holding the last.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.kinematics import ssa
from enbarr_core.framework.checks import floats

Vector = NDArray[np.float64]

_ALL = (True, True, True)
_HEADING_ONLY = (False, False, True)


@dataclass(frozen=True, eq=False)
class Reference:
    """What the DP controller tracks. Arrays are fresh per call (``eq=False``)."""

    eta_d: Vector        # (3,) desired pose [x, y, psi] world ENU [m, m, rad]
    nu_d: Vector         # (3,) desired body velocity [u, v, r] [m/s, m/s, rad/s]
    nu_d_dot: Vector     # (3,) desired body acceleration [m/s^2, m/s^2, rad/s^2]
    # Pose-error components (x, y, psi) fed back. Where False, eta_d is no reference: NaN as
    # read from ``guidance/reference``; LosPath puts the closest point on the path there, for
    # tests and logs only (the message carries NaN, the controller never reads it).
    position_mask: tuple[bool, bool, bool] = _ALL
    cross_track: float | None = None   # signed distance from the path, + left of it [m]
    along_track: float | None = None   # distance along the active segment [m]
    segment: int | None = None         # active segment index k (p_k -> p_k+1)
    finished: bool = False             # the goal has been reached (now holding)


def _check_dt(dt: float) -> None:
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ValueError(f'dt must be finite and > 0, got {dt!r}')


def _pose(value: ArrayLike, what: str) -> tuple[float, float, float]:
    """``value`` as a pose [x, y, psi] of 3 finite floats (``ValueError`` naming ``what``)."""
    return floats(what, value, 3)

def _positive(value: float, what: str, *, zero_ok: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{what}: must be a number, got {value!r}') from exc
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not zero_ok):
        raise ValueError(f'{what}: must be finite and {">= 0" if zero_ok else "> 0"}, '
                         f'got {value!r}')
    return v


def _hold(x: float, y: float, psi: float, *, cross_track: float | None = None,
          along_track: float | None = None, segment: int | None = None,
          finished: bool = False) -> Reference:
    return Reference(np.array((x, y, psi)), np.zeros(3), np.zeros(3), _ALL, cross_track,
                     along_track, segment, finished)


class HoldPose:
    """Station keeping: eta_d = eta, nu_d = 0, every pose component fed back."""

    def __init__(self, eta: ArrayLike) -> None:
        x, y, psi = _pose(eta, 'eta')
        self.eta = (x, y, float(ssa(psi)))

    def reference(self, eta_hat: ArrayLike, dt: float) -> Reference:
        """Advance the clock by ``dt`` [s] and return the reference for ``eta_hat`` now."""
        _check_dt(dt)
        return _hold(*self.eta, finished=True)


def trapezoid(t: float, v_max: float, a_max: float) -> tuple[float, float, float]:
    """Trapezoidal profile from 0 to 1: (s, s_dot, s_ddot) at time t [s].

    |s_dot| <= v_max, |s_ddot| <= a_max; a triangle when 1 is too short to reach v_max.
    """
    vp = min(v_max, math.sqrt(a_max))       # peak: reached after half the way if triangle
    ta = vp / a_max                          # acceleration time
    tc = (1.0 - vp * ta) / vp                # cruise time (distance 1 - 2 * vp ta / 2)
    if t <= 0.0:
        return 0.0, 0.0, 0.0
    if t < ta:
        return 0.5 * a_max * t * t, a_max * t, a_max
    if t < ta + tc:
        return 0.5 * vp * ta + vp * (t - ta), vp, 0.0
    tr = 2.0 * ta + tc - t                   # time to go
    if tr > 0.0:
        return 1.0 - 0.5 * a_max * tr * tr, a_max * tr, -a_max
    return 1.0, 0.0, 0.0


class GoToWaypoint:
    """Move the reference point along the straight line start -> waypoint, then hold it.

    One trapezoidal profile s(t) in [0, 1] drives eta_d = eta_0 + s [dx, dy, dpsi]; its limits
    are the tightest of speed / L, accel / L, yaw_rate / |dpsi|, yaw_accel / |dpsi|, so the
    position and the heading arrive together and none of the limits is exceeded. Without a
    waypoint heading the start heading is held. nu_d = R(psi_d)^T eta_d_dot (the body velocity
    of the desired vessel), r_d = s_dot dpsi. ``finished`` once the profile has ended and the
    vessel is within ``arrival_radius`` of the waypoint.
    """

    def __init__(self, start_eta: ArrayLike, waypoint: Sequence[float], speed: float,
                 accel: float, *, yaw_rate: float = 0.2, yaw_accel: float = 0.2,
                 arrival_radius: float = 0.1) -> None:
        x0, y0, psi0 = _pose(start_eta, 'start_eta')
        try:
            wp = [float(w) for w in waypoint]
        except (TypeError, ValueError) as exc:
            raise ValueError(f'waypoint: must be (x, y) or (x, y, psi), got {waypoint!r}') \
                from exc
        if len(wp) not in (2, 3) or not all(math.isfinite(w) for w in wp):
            raise ValueError(f'waypoint: must be 2 or 3 finite numbers, got {waypoint!r}')
        self.speed = _positive(speed, 'speed')
        self.accel = _positive(accel, 'accel')
        self.yaw_rate = _positive(yaw_rate, 'yaw_rate')
        self.yaw_accel = _positive(yaw_accel, 'yaw_accel')
        self.arrival_radius = _positive(arrival_radius, 'arrival_radius')
        psi0 = float(ssa(psi0))
        self.start = (x0, y0, psi0)
        self.goal = (wp[0], wp[1], float(ssa(wp[2])) if len(wp) == 3 else psi0)
        self.delta = (wp[0] - x0, wp[1] - y0, float(ssa(self.goal[2] - psi0)))
        self.length = math.hypot(self.delta[0], self.delta[1])
        dpsi = abs(self.delta[2])
        v_s = min(self.speed / self.length if self.length > 0.0 else math.inf,
                  self.yaw_rate / dpsi if dpsi > 0.0 else math.inf)
        a_s = min(self.accel / self.length if self.length > 0.0 else math.inf,
                  self.yaw_accel / dpsi if dpsi > 0.0 else math.inf)
        self._v_s, self._a_s = v_s, a_s
        if math.isinf(v_s):  # already there
            self.duration = 0.0
        else:
            vp = min(v_s, math.sqrt(a_s))
            self.duration = vp / a_s + 1.0 / vp   # 2 t_a + t_c
        self.t = 0.0
        self.finished = False

    def reference(self, eta_hat: ArrayLike, dt: float) -> Reference:
        """Advance the clock by ``dt`` [s] and return the reference for ``eta_hat`` now."""
        _check_dt(dt)
        x, y, _ = _pose(eta_hat, 'eta_hat')
        self.t += dt
        if self.t >= self.duration:
            s, sd, sdd = 1.0, 0.0, 0.0
        else:
            s, sd, sdd = trapezoid(self.t, self._v_s, self._a_s)
        (x0, y0, psi0), (dx, dy, dpsi) = self.start, self.delta
        psi_d = float(ssa(psi0 + s * dpsi))
        c, sn = math.cos(psi_d), math.sin(psi_d)
        xd, yd = sd * dx, sd * dy           # eta_d_dot (world)
        xdd, ydd = sdd * dx, sdd * dy       # eta_d_ddot (world)
        r_d = sd * dpsi
        # nu_d = R(psi_d)^T eta_d_dot
        # nu_d_dot = R^T eta_d_ddot + r_d [[-s, c], [-c, -s]] eta_d_dot  (d/dt R^T)
        nu_d = (c * xd + sn * yd, -sn * xd + c * yd, r_d)
        nu_d_dot = (c * xdd + sn * ydd + r_d * (-sn * xd + c * yd),
                    -sn * xdd + c * ydd + r_d * (-c * xd - sn * yd),
                    sdd * dpsi)
        if self.length > 0.0:
            ca, sa = dx / self.length, dy / self.length
            along = (x - x0) * ca + (y - y0) * sa
            cross = -(x - x0) * sa + (y - y0) * ca
        else:
            along, cross = 0.0, 0.0
        if s >= 1.0 and math.hypot(x - self.goal[0], y - self.goal[1]) <= self.arrival_radius:
            self.finished = True
        return Reference(np.array((x0 + s * dx, y0 + s * dy, psi_d)), np.array(nu_d),
                         np.array(nu_d_dot), _ALL, cross, along, 0, self.finished)


class LosPath:
    """Lookahead-based line-of-sight path following through waypoints (Fossen 2021, ch. 12).

    For the active segment p_k -> p_k+1 with path angle pi_p = atan2(dy, dx):

        s     =  (x - x_k) cos pi_p + (y - y_k) sin pi_p    along-track [m]
        e     = -(x - x_k) sin pi_p + (y - y_k) cos pi_p    cross-track [m], + left of the path
        chi_d = pi_p - atan(e / Delta)                      desired course (left -> steer right)
        nu_d  = [R(psi)^T U [cos chi_d, sin chi_d], r_d]

    With the course tracked, e_dot = U sin(chi_d - pi_p) = -U e / sqrt(Delta^2 + e^2): e -> 0.
    heading='course': psi_d = chi_d and r_d = chi_d_dot = U Delta e / (Delta^2 + e^2)^(3/2)
    (the ideal-kinematics rate, noise free); heading='fixed': psi_d = fixed_heading (default:
    the heading at the first call), r_d = 0. The pose error is used for the heading only
    (position_mask = [False, False, True]); eta_d's position is the closest point on the path.

    The next segment becomes active within ``acceptance_radius`` of p_k+1 or once past it
    (s >= segment length). After the last waypoint: hold it (all of the pose fed back; heading
    the last path angle, or the fixed heading), ``finished`` = True.
    """

    def __init__(self, waypoints: Sequence[Sequence[float]], speed: float, lookahead: float,
                 acceptance_radius: float, heading: str = 'course',
                 fixed_heading: float | None = None) -> None:
        try:
            wps = np.array(waypoints, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'waypoints: must be a list of (x, y), got {waypoints!r}') from exc
        if wps.ndim != 2 or wps.shape[1] != 2 or wps.shape[0] < 2:
            raise ValueError(f'waypoints: need at least 2 points (x, y), got shape {wps.shape}')
        if not np.isfinite(wps).all():
            raise ValueError('waypoints: must be finite')
        lengths = np.hypot(*np.diff(wps, axis=0).T)
        if (lengths <= 0.0).any():
            k = int(np.argmin(lengths))
            raise ValueError(f'waypoints: points {k} and {k + 1} coincide (zero-length segment)')
        self.speed = _positive(speed, 'speed')
        self.lookahead = _positive(lookahead, 'lookahead')
        self.acceptance_radius = _positive(acceptance_radius, 'acceptance_radius', zero_ok=True)
        if heading not in ('course', 'fixed'):
            raise ValueError(f"heading: must be 'course' or 'fixed', got {heading!r}")
        if fixed_heading is not None:
            if heading != 'fixed':
                raise ValueError("fixed_heading: only with heading='fixed'")
            if not math.isfinite(float(fixed_heading)):
                raise ValueError(f'fixed_heading: must be finite, got {fixed_heading!r}')
        self.heading = heading
        self.fixed_heading = None if fixed_heading is None else float(ssa(float(fixed_heading)))
        self.waypoints = [(float(p[0]), float(p[1])) for p in wps]
        # Per segment: start point, unit direction, length, path angle.
        self._segments = [(p[0], p[1], (q[0] - p[0]) / n, (q[1] - p[1]) / n, n,
                           math.atan2(q[1] - p[1], q[0] - p[0]))
                          for p, q, n in zip(self.waypoints, self.waypoints[1:], lengths)]
        self.segment = 0
        self.cross_track = 0.0
        self.along_track = 0.0
        self.finished = False

    def reference(self, eta_hat: ArrayLike, dt: float) -> Reference:
        """Advance the clock by ``dt`` [s] and return the reference for ``eta_hat`` now."""
        _check_dt(dt)
        x, y, psi = _pose(eta_hat, 'eta_hat')
        fixed = self.fixed_heading  # None only with heading 'course' (from here on)
        if fixed is None and self.heading == 'fixed':
            fixed = self.fixed_heading = float(ssa(psi))
        segments = self._segments
        while True:
            xk, yk, ca, sa, length, pi_p = segments[self.segment]
            s = (x - xk) * ca + (y - yk) * sa
            e = -(x - xk) * sa + (y - yk) * ca
            if self.finished:
                break
            xe, ye = xk + length * ca, yk + length * sa
            if s >= length or math.hypot(x - xe, y - ye) <= self.acceptance_radius:
                if self.segment + 1 < len(segments):
                    self.segment += 1
                    continue
                self.finished = True
            break
        self.cross_track, self.along_track = e, s
        if self.finished:
            xe, ye = self.waypoints[-1]
            psi_hold = pi_p if fixed is None else fixed
            return _hold(xe, ye, psi_hold, cross_track=e, along_track=s,
                         segment=self.segment, finished=True)

        U, delta = self.speed, self.lookahead
        chi_d = pi_p - math.atan(e / delta)
        cc, sc = math.cos(chi_d), math.sin(chi_d)
        vx, vy = U * cc, U * sc                       # desired world velocity
        if fixed is None:                             # heading 'course'
            psi_d = float(ssa(chi_d))
            r_d = U * delta * e / (delta * delta + e * e) ** 1.5  # chi_d_dot
        else:
            psi_d, r_d = fixed, 0.0
        chi_dot = U * delta * e / (delta * delta + e * e) ** 1.5
        ax, ay = -chi_dot * vy, chi_dot * vx          # d/dt of the world velocity
        c, sn = math.cos(psi), math.sin(psi)
        # nu_d = R(psi)^T v; nu_d_dot = R^T v_dot + r_d [[-s, c], [-c, -s]] v  (r ~ r_d)
        nu_d = (c * vx + sn * vy, -sn * vx + c * vy, r_d)
        nu_d_dot = (c * ax + sn * ay + r_d * (-sn * vx + c * vy),
                    -sn * ax + c * ay + r_d * (-c * vx - sn * vy), 0.0)
        eta_d = (xk + s * ca, yk + s * sa, psi_d)     # closest point on the path
        return Reference(np.array(eta_d), np.array(nu_d), np.array(nu_d_dot), _HEADING_ONLY,
                         e, s, self.segment, False)
