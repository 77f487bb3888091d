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
and the QP is only solved when v_nom violates a constraint (then it is exactly its solution):
in floats when the projection of v_nom on one violated barrier meets every constraint (the
usual case of one obstacle in the way), by daqp otherwise (:func:`_solve_qp`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import math
import threading
from typing import NamedTuple, Protocol

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
_DIRECTION_PAIRS = tuple((float(cx), float(cy)) for cx, cy in _DIRECTIONS)
_HALF = _SIDES // 2
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
    return moved(np.array(obstacle_lists(obstacles), dtype=float).reshape(-1, 7), age)


def obstacle_lists(obstacles: Iterable[ObstacleLike]) -> list[list[float]]:
    """Return the rows of :func:`obstacle_rows` (at age 0) as lists of floats for the step.

    Without the array: a caller that hands the step the same obstacles at every estimate
    converts them once per scan, and numpy's calls would be most of that conversion.
    """
    return [[float(o.x), float(o.y), *map(float, o.end), float(o.radius), float(o.vx),
             float(o.vy)] for o in obstacles]


def moved(rows: Vector, age: float) -> Vector:
    """Return a copy of obstacle ``rows`` carried along their velocities for ``age`` [s]."""
    out = rows.copy()
    if age and len(out):
        shift = age * out[:, 5:7]
        out[:, 0:2] += shift
        out[:, 2:4] += shift
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

    The constraint of obstacle i is n_i^T v >= b_i (see the module docstring).
    """
    out = _constraints(float(p[0]), float(p[1]), rows.tolist(), settings.margin,
                       settings.gamma)
    a = np.array(out, dtype=float).reshape(-1, 4)
    return a[:, 0:2], a[:, 2], a[:, 3]


def _constraints(px: float, py: float, rows: Sequence[Sequence[float]], margin: float,
                 gamma: float, age: float = 0.0) -> list[tuple[float, float, float, float]]:
    """:func:`constraints` as rows (nx, ny, b, B) of Python floats.

    A loop over floats: for the ten or so obstacles of a basin it is faster than numpy, whose
    per-call cost would be the whole cost (docs/benchmarks.md). ``age`` [s] carries each
    obstacle along its velocity first, as :func:`moved` does (the same float operations).
    """
    out = []
    for ax, ay, bx, by, r, vx, vy in rows:
        if age:
            sx, sy = age * vx, age * vy
            ax, ay, bx, by = ax + sx, ay + sy, bx + sx, by + sy
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
    return out


def solve_qp(v_nom: Vector, n: Vector, b: Vector, max_speed: float) -> QpResult:
    """Solve min |v - v_nom|^2 s.t. n v >= b and the speed polygon (module doc, :func:`_solve_qp`).

    The rows of ``n`` are unit normals, as :func:`constraints` gives them.
    """
    cons = [(float(nx), float(ny), float(bi), 0.0) for (nx, ny), bi in zip(n.tolist(),
                                                                             b.tolist())]
    a = _solve_qp(float(v_nom[0]), float(v_nom[1]), cons, max_speed)
    return QpResult(np.array((a.vx, a.vy)), a.feasible, a.solved,
                    np.array(a.binding, dtype=bool).reshape(len(cons)))


class _Answer(NamedTuple):
    """:class:`QpResult` in Python floats and bools, as the filter's step uses it."""

    vx: float
    vy: float
    feasible: bool
    solved: bool
    binding: tuple[bool, ...]

    @property
    def active(self) -> int:
        """How many obstacle constraints bind at v."""
        return sum(self.binding)


class _DaqpRows:
    """daqp's arrays for k obstacle rows, kept between solves (the speed polygon's rows stay).

    Building five small arrays per solve cost more than the solve (docs/benchmarks.md).
    """

    def __init__(self, k: int) -> None:
        self.k = k
        self.A = np.empty((k + _HALF, 2))
        self.A[k:] = _DIRECTIONS
        self.upper = np.full(k + _HALF, _INF)
        self.lower = np.empty(k + _HALF)
        self.sense = np.zeros(k + _HALF, dtype=np.int32)
        self.f = np.empty(2)
        self.limit = math.nan

    def solve(self, vx: float, vy: float, cons: Sequence[tuple[float, float, float, float]],
              limit: float) -> tuple[float, float, int]:
        """Return daqp's (vx, vy, exitflag) of the QP."""
        k = self.k
        if limit != self.limit:
            self.upper[k:] = limit
            self.lower[k:] = -limit
            self.limit = limit
        for j, (nx, ny, bi, _) in enumerate(cons):
            self.A[j, 0] = nx
            self.A[j, 1] = ny
            self.lower[j] = bi
        self.f[0] = -vx
        self.f[1] = -vy
        x, _, exitflag, _ = daqp.solve(_H, self.f, self.A, self.upper, self.lower, self.sense)
        return float(x[0]), float(x[1]), int(exitflag)


#: The kept arrays, per thread (two filters stepping on two threads never share them).
_DAQP = threading.local()


def _daqp_rows(k: int) -> _DaqpRows:
    """Return this thread's kept arrays for k obstacle rows (made on first use)."""
    kept: dict[int, _DaqpRows] | None = getattr(_DAQP, 'rows', None)
    if kept is None:
        kept = _DAQP.rows = {}
    rows = kept.get(k)
    if rows is None:
        rows = kept[k] = _DaqpRows(k)
    return rows


def _within(vx: float, vy: float, limit: float) -> bool:
    """Whether (vx, vy) lies in the speed polygon (the inscribed circle is tested first)."""
    return math.hypot(vx, vy) <= limit or all(abs(cx * vx + cy * vy) <= limit
                                              for cx, cy in _DIRECTION_PAIRS)


def _solve_qp(vx: float, vy: float, cons: Sequence[tuple[float, float, float, float]],
              max_speed: float) -> _Answer:
    """:func:`solve_qp` of v_nom = (vx, vy) and the rows (nx, ny, b, B) of _constraints.

    In floats, which most steps end with: the test of v_nom against every constraint, and,
    when v_nom is inside the speed polygon, the projections of v_nom on each violated
    barrier's half-plane, v_nom + (b_i - n_i^T v_nom) n_i: each is the optimum of the QP with
    that constraint alone, so one that meets every other constraint and the polygon too is the
    optimum of the whole QP (a relaxation's optimum that is feasible; the closed form of the
    single-constraint CBF QP, Ames et al. 2019, sec. III). Otherwise daqp solves it.
    """
    limit = max_speed * _INSCRIBED
    k = len(cons)
    if _within(vx, vy, limit):
        violated = [j for j, (nx, ny, bi, _) in enumerate(cons) if nx * vx + ny * vy < bi]
        if not violated:
            return _Answer(vx, vy, True, False, (False,) * k)
        for i in violated:
            nx, ny, bi, _ = cons[i]
            t = bi - (nx * vx + ny * vy)
            wx, wy = vx + t * nx, vy + t * ny
            if _within(wx, wy, limit) and all(cx * wx + cy * wy >= ci for j, (cx, cy, ci, _)
                                              in enumerate(cons) if j != i):
                return _Answer(wx, wy, True, True, tuple(
                    cx * wx + cy * wy - ci <= 1e-9 for cx, cy, ci, _ in cons))
    wx, wy, exitflag = _daqp_rows(k).solve(vx, vy, cons, limit)
    if exitflag != 1 or not (math.isfinite(wx) and math.isfinite(wy)):
        return _Answer(0.0, 0.0, False, True, (False,) * k)
    return _Answer(wx, wy, True, True, tuple(cx * wx + cy * wy - ci <= 1e-9
                                             for cx, cy, ci, _ in cons))


class SafetyFilter:
    """The guidance-level CBF safety filter (module docstring).

    Stateful: call :meth:`step` once per estimate; :meth:`reset` on a new law,
    :meth:`engage_at` to start from a pose.
    """

    def __init__(self, settings: CbfSettings) -> None:
        settings.validate()
        self.settings = settings
        self.engaged = False
        # p_d, its velocity v* and the feed-forward acceleration [world, m, m/s, m/s^2], as
        # Python floats: the step is a few dozen 2-vector operations, and a numpy call costs
        # more than the arithmetic of one.
        self.p_d: tuple[float, float] = (0.0, 0.0)
        self.v: tuple[float, float] = (0.0, 0.0)
        self.a_ff: tuple[float, float] = (0.0, 0.0)
        self.side = 0             # passing side of this engagement: +1 starboard, -1 port
        self.infeasible_count = 0
        # The last output's position, world velocity and kind of law (a position reference
        # or LOS): a law that changes kind (LOS finishing into a hold) moves its position
        # reference at once, which the filter must not follow in one step.
        self._last: tuple[tuple[float, float], tuple[float, float], bool] | None = None

    def reset(self) -> None:
        """Forget p_d: the next step starts from the nominal reference."""
        self.engaged, self.side, self._last = False, 0, None

    def engage_at(self, p: Vector) -> None:
        """Start engaged at rest at ``p`` (e.g. the pose held while blind).

        The pull then brings p_d to the law's reference within the constraints.
        """
        self.engaged = True
        self.p_d = (float(p[0]), float(p[1]))
        self.v = (0.0, 0.0)
        self.a_ff = (0.0, 0.0)

    def step(self, eta_hat: Vector, nominal: Reference,
             rows: Vector | Sequence[Sequence[float]], dt: float, age: float = 0.0) -> CbfOutput:
        """Filter ``nominal``, the law's reference for ``eta_hat`` now.

        ``rows``: the obstacles (:func:`obstacle_rows`, or its ``tolist()``, which a caller
        that steps many times on the same obstacles converts once), taken ``age`` [s] before
        the estimate's time: each is carried along its velocity for that long
        (:func:`moved`). ``dt`` [s] since the previous step.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        s = self.settings
        own_position = nominal.position_mask[0] and nominal.position_mask[1]
        # one conversion per array, then floats (each numpy index is a call of its own)
        eta_d = nominal.eta_d.tolist()
        psi_d = eta_d[2]
        source = eta_d if own_position else eta_hat.tolist()
        psi_v = psi_d if own_position else source[2]
        c, sn = math.cos(psi_v), math.sin(psi_v)
        u, w, r_d = nominal.nu_d.tolist()
        v_ff = (c * u - sn * w, sn * u + c * w)                  # R(psi_v) nu_d[:2]
        target = (source[0], source[1])
        if not self.engaged and self._last is not None and self._last[2] != own_position:
            # The position reference jumps (LOS -> hold at the last waypoint): go on from
            # where the reference was, with its velocity, and let the pull take p_d there
            # within the constraints (the new target may lie in a zone, or behind one).
            self.engaged, self.side = True, 0
            self.p_d, self.v, self.a_ff = self._last[0], self._last[1], (0.0, 0.0)
        if self.engaged:
            p = (self.p_d[0] + dt * self.v[0], self.p_d[1] + dt * self.v[1])
        else:
            p = target
        k = s.pull_gain
        v_nom = (v_ff[0] + k * (target[0] - p[0]), v_ff[1] + k * (target[1] - p[1]))
        cons = _constraints(p[0], p[1], rows.tolist() if isinstance(rows, np.ndarray) else rows,
                            s.margin, s.gamma, age)
        min_b = min((row[3] for row in cons), default=math.inf)
        qp = _solve_qp(v_nom[0], v_nom[1], cons, s.max_speed)
        if not qp.solved and (not self.engaged or math.hypot(p[0] - target[0], p[1] - target[1])
                              <= s.release_distance):
            self.engaged, self.side = False, 0
            self._last = (target, v_ff, own_position)
            return CbfOutput(nominal, False, False, 0, False, min_b)
        if qp.active and s.pass_gain > 0.0:
            qp = self._pass(qp, v_nom, cons)
        reason = ''
        if not qp.feasible:
            self.infeasible_count += 1
            reason = 'infeasible: no velocity keeps every obstacle out; stopped'
        if not self.engaged:  # engaging: the feed-forward starts from the law's
            a_x, a_y, _ = nominal.nu_d_dot.tolist()
            ax = a_x - r_d * w
            ay = a_y + r_d * u
            self.a_ff = (c * ax - sn * ay, sn * ax + c * ay)
            self.v = v_ff
        qv = (qp.vx, qp.vy)
        gain = min(1.0, dt / s.accel_time if s.accel_time > 0.0 else 1.0)
        self.a_ff = (self.a_ff[0] + gain * ((qv[0] - self.v[0]) / dt - self.a_ff[0]),
                     self.a_ff[1] + gain * ((qv[1] - self.v[1]) / dt - self.a_ff[1]))
        self.engaged, self.p_d, self.v = True, p, qv
        self._last = (p, qv, own_position)
        return CbfOutput(self._reference(psi_d, psi_v, r_d, nominal), True, qp.solved,
                         qp.active, not qp.feasible, min_b, reason)

    def _pass(self, qp: _Answer, v_nom: tuple[float, float],
              cons: list[tuple[float, float, float, float]]) -> _Answer:
        """Slide along the blocking obstacle instead of stopping in front of it.

        The QP alone stops p_d where an obstacle lies across v_nom (the local minimum of a CBF
        safety filter). The speed lost there, |v_nom| - |v*|, times ``pass_gain``, is added
        along the tangent of the binding barrier with the smallest B (which keeps that
        constraint as tight as it was), and the QP is solved again from that velocity, so
        every constraint still holds. The side is chosen once per engagement: starboard
        (the obstacle passed on the port side) unless v_nom leans clearly to port; zero
        lost speed (just engaged) adds nothing, so the reference stays continuous.
        """
        speed_nom = math.hypot(*v_nom)
        vx, vy = qp.vx, qp.vy
        lost = speed_nom - math.hypot(vx, vy)
        if lost <= 0.0:
            return qp
        i = min((row[3], j) for j, row in enumerate(cons) if qp.binding[j])[1]
        tx, ty = -cons[i][1], cons[i][0]   # starboard of a heading into the obstacle (-n)
        if self.side == 0:
            self.side = 1 if tx * v_nom[0] + ty * v_nom[1] >= -0.2 * speed_nom else -1
        push = self.settings.pass_gain * lost * self.side
        again = _solve_qp(vx + push * tx, vy + push * ty, cons, self.settings.max_speed)
        if not again.feasible:
            return qp
        binding = tuple(nx * again.vx + ny * again.vy - b <= 1e-9 for nx, ny, b, _ in cons)
        return _Answer(again.vx, again.vy, True, True, binding)

    def _reference(self, psi_d: float, psi_v: float, r_d: float,
                   nominal: Reference) -> Reference:
        """Build the engaged reference: p_d, the law's heading, v* in its body frame."""
        c, sn = math.cos(psi_v), math.sin(psi_v)
        vx, vy = self.v
        ax, ay = self.a_ff
        # nu_d = R(psi_v)^T v; nu_d_dot = R^T a + r_d [[-s, c], [-c, -s]] v  (d/dt R^T)
        nu_d = (c * vx + sn * vy, -sn * vx + c * vy, r_d)
        nu_d_dot = (c * ax + sn * ay + r_d * (-sn * vx + c * vy),
                    -sn * ax + c * ay + r_d * (-c * vx - sn * vy), float(nominal.nu_d_dot[2]))
        return Reference(np.array((self.p_d[0], self.p_d[1], psi_d)), np.array(nu_d),
                         np.array(nu_d_dot), _ALL, nominal.cross_track, nominal.along_track,
                         nominal.segment, nominal.finished)


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
