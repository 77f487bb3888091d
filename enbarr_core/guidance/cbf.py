"""Collision avoidance with control barrier functions at the guidance level (a safety filter).

After Solheim 2022 (Integration between lidar- and camera-based situational awareness and
control barrier functions for an autonomous surface vessel, NTNU; listed in the CS Saucer
manual), in the line of Thyri et al. 2020 (Reactive collision avoidance for ASVs using
control barrier functions, IEEE CCTA) and Ames et al. 2019 (Control barrier functions: theory
and applications, ECC): the guidance law's reference is passed through a quadratic program
that changes the desired velocity as little as it can while keeping the desired position
p_d out of every obstacle's safety zone. The controller then tracks the safe reference.
World ENU (odom), velocities in m/s, positions in m.

Barrier per obstacle i (a capsule: the points within r_o,i of the segment a_i-b_i, moving
with v_o,i), with c_i the point of the segment nearest p_d:

    B_i(p_d) = |p_d - c_i| - r_i,      r_i = r_o,i + r_vessel + r_safety + r_tracking
    n_i      = (p_d - c_i) / |p_d - c_i|      (the gradient of the distance to a convex set)

r_safety is the clearance that must hold between the hull (a circle of r_vessel about the
CO) and the obstacle; r_tracking is what the vessel may lag behind p_d (the controller's
tracking error): B_i >= 0 on p_d then keeps the TRUE hull r_safety clear of the obstacle as
long as |p - p_d| <= r_tracking. The CBF condition dB_i/dt >= -gamma B_i on p_d_dot = v
(the obstacle translating with v_o,i) is the linear constraint

    n_i^T (v - v_o,i) >= -gamma B_i.

Per step the safety filter solves (daqp, a dual active-set QP solver)

    v* = argmin |v - v_nom|^2   s.t.   n_i^T v >= n_i^T v_o,i - gamma B_i   (every obstacle)
                                       |a_k^T v| <= v_max cos(pi/16), a_k = [cos k pi/8,
                                       sin k pi/8], k = 0..7   (|v| <= v_max: a 16-gon inside)

and integrates p_d <- p_d + dt v*. Because the distance to a convex set is convex in p_d,
B_i(p_d + dt v) >= B_i + dt n_i^T (v - v_o,i) >= (1 - gamma dt) B_i: with gamma dt < 1 a
static or constant-velocity obstacle never enters the zone of the integrated p_d either.
An obstacle already inside (B_i < 0) is left at rate gamma |B_i|.

Nominal velocity from each law (:mod:`guidance.guidance`):

* a law with a position reference (HoldPose, GoToWaypoint: position_mask x, y True):
  v_nom = R(psi_d) nu_d + k_pull (p_ref - p_d), the reference's own world velocity plus a pull
  of p_d back to the reference position p_ref;
* LOS (x, y not fed back): v_nom = R(psi) nu_d (the LOS world velocity), the pull is toward
  the vessel's estimate p_hat (a leash: p_d never runs away from the vessel).

Identity: while v_nom satisfies every constraint and the filter is not engaged, the nominal
reference is returned unchanged (the same object), and p_d is the nominal position (or
p_hat for LOS). The filter engages when v_nom violates a constraint, starting from that
point with the velocity v* (so eta_d and nu_d are continuous); engaged, the reference is
(p_d, psi_d of the law), nu_d = [R^T v*, r_d of the law], every pose component fed
back (nu_d in the body frame the law used: R(psi_d) for a law with a position, R(psi) for
LOS, so that it is the same velocity as the nominal one at engagement). It releases, back to
the nominal, once v_nom is feasible again and p_d is within ``release_distance`` of the pull
target. A law that changes kind (LOS finishing into a hold of the last waypoint) engages the
filter from the last reference position and velocity, so its position step is taken at the
speed limit and within the constraints. The heading is always the law's: a course or a held
heading keeps being followed (the hull is taken as a circle and the vessel as fully
actuated: the heading does not change the distances). The feed-forward acceleration while
engaged is the finite difference of v*, low-pass filtered with ``accel_time`` (started from
the law's acceleration at engagement), so a new obstacle's jump in v* does not kick the
controller.

Passing (an addition to the filter above, ``pass_gain``; 0 turns it off): a CBF QP alone
stops p_d in front of an obstacle that lies across v_nom (its known local minimum), so the
speed lost to a binding barrier is given back along that barrier's tangent and the QP solved
again (:meth:`SafetyFilter._pass`); every constraint still holds.

An infeasible QP (moving obstacles closing in from all sides, faster than v_max) never
raises: the output is the safest command, zero velocity at the present p_d, with a reason.

Speed: obstacles are numpy rows (:func:`obstacle_rows`), their geometry a loop over floats,
and the QP is only solved when v_nom violates a constraint (then it is exactly its solution).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
import math
from typing import Protocol

import daqp
import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.checks import check_non_negative
from enbarr_core.guidance.guidance import Reference

Vector = NDArray[np.float64]

#: Columns of an obstacle row (:func:`obstacle_rows`).
COLUMNS = ('x', 'y', 'x2', 'y2', 'radius', 'vx', 'vy')
_SIDES = 16                                 # the speed limit's polygon
_DIRECTIONS = np.array([[math.cos(k * math.pi / 8), math.sin(k * math.pi / 8)]
                        for k in range(_SIDES // 2)])
_INSCRIBED = math.cos(math.pi / _SIDES)     # its apothem / circumradius
_INF = 1e30                                 # daqp's "no bound"
_H = np.eye(2)
_ALL = (True, True, True)


class ObstacleLike(Protocol):
    """What :func:`obstacle_rows` reads (``enbarr_interfaces.obstacles.Obstacle`` has it)."""

    @property
    def x(self) -> float:
        """First end (a circle: its centre) [m]."""

    @property
    def y(self) -> float:
        """First end [m]."""

    @property
    def end(self) -> tuple[float, float]:
        """The segment's second end (a circle: its centre) [m]."""

    @property
    def radius(self) -> float:
        """Extent about the segment [m]."""

    @property
    def vx(self) -> float:
        """Velocity [m/s]."""

    @property
    def vy(self) -> float:
        """Velocity [m/s]."""


def obstacle_rows(obstacles: Iterable[ObstacleLike], age: float = 0.0) -> Vector:
    """Rows [x, y, x2, y2, radius, vx, vy] of ``obstacles``, moved on by ``age`` [s].

    ``age`` is the time from the obstacles' stamp to the time of the estimate the filter
    runs on: each obstacle is carried along its velocity for that long (constant velocity).
    """
    rows = [(o.x, o.y, *o.end, o.radius, o.vx, o.vy) for o in obstacles]
    return moved(np.array(rows, dtype=float).reshape(-1, 7), age)


def moved(rows: Vector, age: float) -> Vector:
    """Return a copy of obstacle ``rows`` carried along their velocities for ``age`` [s]."""
    out = rows.copy()
    if age and len(out):
        out[:, 0:4] += age * np.tile(out[:, 5:7], 2)
    return out


@dataclass(frozen=True)
class CbfSettings:
    """Settings of :class:`SafetyFilter` (see the module docstring)."""

    safety_radius: float = 0.2      # clearance hull -> obstacle that must hold [m]
    vessel_radius: float = 0.0      # hull radius about the CO [m]
    tracking_margin: float = 0.2    # how far the vessel may lag p_d [m]
    gamma: float = 0.5              # barrier decay rate [1/s] (gamma dt < 1)
    max_speed: float = 0.3          # |v| limit of the desired position [m/s]
    pull_gain: float = 0.5          # k_pull [1/s]
    release_distance: float = 0.01  # engaged -> nominal within this of the pull target [m]
    accel_time: float = 0.5         # low-pass time constant of the feed-forward accel [s]
    pass_gain: float = 1.0          # tangential speed / speed lost at a blocking obstacle

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ('safety_radius', 'vessel_radius', 'tracking_margin', 'gamma',
                     'max_speed', 'pull_gain', 'release_distance', 'accel_time', 'pass_gain'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f'{name}: must be a finite number, got {value!r}')
        check_non_negative(self, ('safety_radius', 'vessel_radius', 'tracking_margin',
                                  'release_distance', 'accel_time', 'pass_gain'))
        for name in ('gamma', 'max_speed', 'pull_gain'):
            if getattr(self, name) <= 0.0:
                raise ValueError(f'{name}: must be > 0, got {getattr(self, name)!r}')

    @property
    def margin(self) -> float:
        """r_vessel + r_safety + r_tracking: what every obstacle's radius is grown by [m]."""
        return self.vessel_radius + self.safety_radius + self.tracking_margin

    @property
    def identity_speed(self) -> float:
        """The fastest nominal speed the speed limit lets through unchanged [m/s]."""
        return self.max_speed * _INSCRIBED


@dataclass(frozen=True, eq=False)
class CbfOutput:
    """One step of the filter: the reference to track and what the metrics need."""

    reference: Reference        # the nominal one itself when not engaged
    engaged: bool               # the reference differs from the nominal
    solved: bool                # a QP was solved this step
    active: int                 # obstacle constraints binding at the output velocity
    infeasible: bool            # no velocity met every constraint: zero velocity output
    min_barrier: float          # min_i B_i at the output p_d [m] (inf: no obstacle)
    reason: str = ''            # why the output is not the filter's solution ('' if it is)


@dataclass(frozen=True)
class QpResult:
    """The safe velocity and how it was found."""

    v: Vector                   # (2,) world velocity [m/s]
    feasible: bool
    solved: bool                # False: v_nom met every constraint, no QP needed
    binding: NDArray[np.bool_]  # per obstacle: its constraint holds with equality at v

    @property
    def active(self) -> int:
        """How many obstacle constraints bind at v."""
        return int(np.count_nonzero(self.binding))


def constraints(p: Vector, rows: Vector, settings: CbfSettings
                ) -> tuple[Vector, Vector, Vector]:
    """(n, b, B): normals n_i (k, 2), lower bounds b_i = n_i^T v_o,i - gamma B_i and B_i.

    The constraint of obstacle i is n_i^T v >= b_i (see the module docstring). A loop over
    Python floats: for the ten or so obstacles of a basin it is faster than numpy, whose
    per-call cost would be the whole cost (docs/benchmarks.md).
    """
    px, py = float(p[0]), float(p[1])
    margin, gamma = settings.margin, settings.gamma
    out = []
    for ax, ay, bx, by, r, vx, vy in rows.tolist():
        dx, dy, ex, ey = bx - ax, by - ay, px - ax, py - ay
        n2 = dx * dx + dy * dy
        s = (ex * dx + ey * dy) / n2 if n2 > 0.0 else 0.0   # c_i = a + s d, s in [0, 1]
        s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
        gx, gy = ex - s * dx, ey - s * dy                     # p - c_i
        dist = math.hypot(gx, gy)
        # p on the segment's axis: no gradient there; any unit vector is a valid choice (the
        # barrier is then far negative and the constraint pushes out that way).
        nx, ny = (gx / dist, gy / dist) if dist > 1e-12 else (1.0, 0.0)
        B = dist - r - margin
        out.append((nx, ny, nx * vx + ny * vy - gamma * B, B))
    a = np.array(out, dtype=float).reshape(-1, 4)
    return a[:, 0:2], a[:, 2], a[:, 3]


def solve_qp(v_nom: Vector, n: Vector, b: Vector, max_speed: float) -> QpResult:
    """Solve min |v - v_nom|^2 s.t. n v >= b and the speed polygon by daqp (module doc)."""
    limit = max_speed * _INSCRIBED
    k = len(b)
    vx, vy = float(v_nom[0]), float(v_nom[1])
    inside = math.hypot(vx, vy) <= limit or bool(np.all(np.abs(_DIRECTIONS @ v_nom) <= limit))
    if inside and (k == 0 or float((n[:, 0] * vx + n[:, 1] * vy - b).min()) >= 0.0):
        return QpResult(v_nom, True, False, np.zeros(k, dtype=bool))
    m = k + len(_DIRECTIONS)
    A = np.empty((m, 2))
    A[:k], A[k:] = n, _DIRECTIONS
    bu, bl = np.full(m, limit), np.full(m, -limit)
    bu[:k], bl[:k] = _INF, b
    x, _, exitflag, _ = daqp.solve(_H, -v_nom, A, bu, bl, np.zeros(m, dtype=np.int32))
    if exitflag != 1 or not np.all(np.isfinite(x)):
        return QpResult(np.zeros(2), False, True, np.zeros(k, dtype=bool))
    v = np.asarray(x, dtype=float)
    return QpResult(v, True, True, n @ v - b <= 1e-9)


def _rot2(psi: float) -> Vector:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s], [s, c]])


class SafetyFilter:
    """The guidance-level CBF safety filter (module docstring).

    Stateful: call :meth:`step` once per estimate; :meth:`reset` on a new law,
    :meth:`engage_at` to start from a pose.
    """

    def __init__(self, settings: CbfSettings) -> None:
        settings.validate()
        self.settings = settings
        self.engaged = False
        self.p_d = np.zeros(2)
        self.v = np.zeros(2)
        self.a_ff = np.zeros(2)
        self.side = 0             # passing side of this engagement: +1 starboard, -1 port
        self.infeasible_count = 0
        # The last output's position, world velocity and kind of law (a position reference
        # or LOS): a law that changes kind (LOS finishing into a hold) moves its position
        # reference at once, which the filter must not follow in one step.
        self._last: tuple[Vector, Vector, bool] | None = None

    def reset(self) -> None:
        """Forget p_d: the next step starts from the nominal reference."""
        self.engaged, self.side, self._last = False, 0, None

    def engage_at(self, p: Vector) -> None:
        """Start engaged at rest at ``p`` (e.g. the pose held while blind).

        The pull then brings p_d to the law's reference within the constraints.
        """
        self.engaged = True
        self.p_d = np.array(p[:2], dtype=float)
        self.v = np.zeros(2)
        self.a_ff = np.zeros(2)

    def step(self, eta_hat: Vector, nominal: Reference, rows: Vector, dt: float) -> CbfOutput:
        """Filter ``nominal``, the law's reference for ``eta_hat`` now.

        ``rows``: the obstacles at the estimate's time (:func:`obstacle_rows`); ``dt`` [s]
        since the previous step.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        s = self.settings
        own_position = nominal.position_mask[0] and nominal.position_mask[1]
        psi_d = float(nominal.eta_d[2])
        psi_v = psi_d if own_position else float(eta_hat[2])
        R = _rot2(psi_v)
        v_ff = R @ nominal.nu_d[:2]
        target = np.array(nominal.eta_d[:2] if own_position else eta_hat[:2], dtype=float)
        if not self.engaged and self._last is not None and self._last[2] != own_position:
            # The position reference jumps (LOS -> hold at the last waypoint): go on from
            # where the reference was, with its velocity, and let the pull take p_d there
            # within the constraints (the new target may lie in a zone, or behind one).
            self.engaged, self.side = True, 0
            self.p_d, self.v, self.a_ff = self._last[0], self._last[1], np.zeros(2)
        p = self.p_d + dt * self.v if self.engaged else target
        v_nom = v_ff + s.pull_gain * (target - p)
        n, b, B = constraints(p, rows, s)
        qp = solve_qp(v_nom, n, b, s.max_speed)
        if not qp.solved and (not self.engaged
                              or float(np.hypot(*(p - target))) <= s.release_distance):
            self.engaged, self.side = False, 0
            self._last = (target, v_ff, own_position)
            return CbfOutput(nominal, False, False, 0, False, _min(B))
        if qp.active and s.pass_gain > 0.0:
            qp = self._pass(qp, v_nom, n, b, B)
        reason = ''
        if not qp.feasible:
            self.infeasible_count += 1
            reason = 'infeasible: no velocity keeps every obstacle out; stopped'
        if not self.engaged:  # engaging: the feed-forward starts from the law's
            r_d, nu = float(nominal.nu_d[2]), nominal.nu_d
            self.a_ff = R @ (nominal.nu_d_dot[:2] + r_d * np.array((-nu[1], nu[0])))
            self.v = v_ff
        self.a_ff = self.a_ff + min(1.0, dt / s.accel_time if s.accel_time > 0.0 else 1.0) \
            * ((qp.v - self.v) / dt - self.a_ff)
        self.engaged, self.p_d, self.v = True, p, qp.v
        self._last = (p, qp.v, own_position)
        return CbfOutput(self._reference(psi_d, psi_v, nominal), True, qp.solved, qp.active,
                         not qp.feasible, _min(B), reason)

    def _pass(self, qp: QpResult, v_nom: Vector, n: Vector, b: Vector, B: Vector
              ) -> QpResult:
        """Slide along the blocking obstacle instead of stopping in front of it.

        The QP alone stops p_d where an obstacle lies across v_nom (the local minimum of a CBF
        safety filter). The speed lost there, |v_nom| - |v*|, times ``pass_gain``, is added
        along the tangent of the binding barrier with the smallest B (which keeps that
        constraint as tight as it was), and the QP is solved again from that velocity, so
        every constraint still holds. The side is chosen once per engagement: starboard
        (the obstacle passed on the port side) unless v_nom leans clearly to port; zero
        lost speed (just engaged) adds nothing, so the reference stays continuous.
        """
        lost = float(np.hypot(*v_nom)) - float(np.hypot(*qp.v))
        if lost <= 0.0:
            return qp
        i = int(np.argmin(np.where(qp.binding, B, np.inf)))
        t = np.array((-n[i, 1], n[i, 0]))   # starboard of a heading into the obstacle (-n)
        if self.side == 0:
            self.side = 1 if t @ v_nom >= -0.2 * float(np.hypot(*v_nom)) else -1
        again = solve_qp(qp.v + self.settings.pass_gain * lost * self.side * t, n, b,
                         self.settings.max_speed)
        if not again.feasible:
            return qp
        return QpResult(again.v, True, True, n @ again.v - b <= 1e-9)

    def _reference(self, psi_d: float, psi_v: float, nominal: Reference) -> Reference:
        """Build the engaged reference: p_d, the law's heading, v* in its body frame."""
        c, sn = math.cos(psi_v), math.sin(psi_v)
        vx, vy = self.v
        ax, ay = self.a_ff
        r_d = float(nominal.nu_d[2])
        # nu_d = R(psi_v)^T v; nu_d_dot = R^T a + r_d [[-s, c], [-c, -s]] v  (d/dt R^T)
        nu_d = (c * vx + sn * vy, -sn * vx + c * vy, r_d)
        nu_d_dot = (c * ax + sn * ay + r_d * (-sn * vx + c * vy),
                    -sn * ax + c * ay + r_d * (-c * vx - sn * vy), float(nominal.nu_d_dot[2]))
        return Reference(np.array((self.p_d[0], self.p_d[1], psi_d)), np.array(nu_d),
                         np.array(nu_d_dot), _ALL, nominal.cross_track, nominal.along_track,
                         nominal.segment, nominal.finished)


def _min(B: Vector) -> float:
    return float(B.min()) if len(B) else math.inf


def blind_reason(estimate_ns: int, obstacles_ns: int | None, measurement_age: float | None,
                 staleness: float) -> str | None:
    """Say why avoidance cannot see, or return None.

    No obstacle message yet, the latest one's stamp more than ``staleness`` [s] before the
    estimate's, or the observer without a pose for longer than that (``measurement_age``
    [s]; None: not heard).
    """
    if measurement_age is not None and measurement_age > staleness:
        return f'pose lost: no pose for {measurement_age:.2f} s (limit {staleness:g} s)'
    if obstacles_ns is None:
        return 'blind: no obstacles message yet'
    age = (estimate_ns - obstacles_ns) * 1e-9
    if age > staleness:
        return f'blind: obstacles {age:.2f} s old (limit {staleness:g} s)'
    return None
