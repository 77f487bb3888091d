"""The simulated world: obstacles in ``odom`` as deterministic functions of time (no ROS).

One model that every simulated sensor and the scenario metrics evaluate on their own, so that
the simulated lidar, the RPLidar emulator, the camera to come and the ground truth agree
without sharing any state: the pose of every obstacle is a pure function of the world time
``t`` [s].

Frame: ``odom`` (ENU, x east, y north [m]; REP-105), the frame the simulator's truth is in.

Shapes, each given at its pose at ``t = 0``:

- ``Circle``: a solid disc (a buoy, a moored boat approximated), centre and radius.
- ``Polygon``: a solid closed polygon (a pier, a hull): its inside is an obstacle.
- ``Walls``: a chain of segments, open or closed (basin walls, a quay, a single segment):
  lines without an inside; a vessel inside a closed chain of walls is in free water.

How it looks (the simulated camera): each obstacle stands on the water (z = 0) up to its
``height`` [m], in its ``colour`` (r, g, b, 0..255); without them, the defaults of its kind
(``DEFAULT_HEIGHT``, ``DEFAULT_COLOUR``: an orange buoy, a white hull, grey basin walls). The
lidar and the distances ignore both: they are 2D.

Motions, a translation of the whole shape (no rotation):

- ``Static``;
- ``ConstantVelocity``: ``p(t) = p(0) + v t``;
- ``Waypoints``: the shape's reference point (a circle's centre, a polygon's or a chain's
  first point) travels from where it is at ``t = 0`` through ``points`` at ``speed``
  [m/s], in straight legs; at the end it stops (``loop`` false) or goes back to its start
  and round again (``loop`` true). Before ``t = 0`` it waits at its start.

World time ``t``: seconds since the world's epoch; the nodes take it from their clock
(``EnbarrNode.world_time``: in a scenario, simulated seconds since the run began).

Costs: ``raycast`` intersects every ray with every circle and every segment as numpy arrays
(rays x circles, rays x segments), with no Python loop over rays; the only loop is over the
obstacles, to place them at ``t`` (``docs/benchmarks.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math
from typing import NamedTuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

Point = tuple[float, float]
FloatArray = NDArray[np.float64]

#: A ray hits a surface only beyond this distance [m]: a ray that starts on a surface (the
#: lidar on a wall) must not hit it at its origin through rounding.
RAY_EPSILON = 1e-9


# -- shapes --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Circle:
    """A solid disc: ``center`` (x, y) [m] in odom, ``radius`` [m] > 0."""

    center: Point
    radius: float

    @property
    def reference(self) -> Point:
        """The point a motion moves along its path: the centre."""
        return self.center

    def moved(self, dx: float, dy: float) -> Circle:
        """Return the disc translated by (dx, dy) [m]."""
        return Circle((self.center[0] + dx, self.center[1] + dy), self.radius)


@dataclass(frozen=True)
class Polygon:
    """A solid closed polygon: ``points`` (x, y) [m] in odom, at least 3, in either order."""

    points: tuple[Point, ...]

    @property
    def reference(self) -> Point:
        """The point a motion moves along its path: the first vertex."""
        return self.points[0]

    def moved(self, dx: float, dy: float) -> Polygon:
        """Return the polygon translated by (dx, dy) [m]."""
        return Polygon(tuple((x + dx, y + dy) for x, y in self.points))

    def segments(self) -> list[tuple[Point, Point]]:
        """Its edges, the last vertex joined to the first."""
        p = self.points
        return [(p[i], p[(i + 1) % len(p)]) for i in range(len(p))]


@dataclass(frozen=True)
class Walls:
    """Segments chained through ``points`` (x, y) [m] in odom, at least 2.

    ``closed``: the last point joined to the first. Lines without an inside (see the module
    docstring).
    """

    points: tuple[Point, ...]
    closed: bool = False

    @property
    def reference(self) -> Point:
        """The point a motion moves along its path: the first point."""
        return self.points[0]

    def moved(self, dx: float, dy: float) -> Walls:
        """Return the walls translated by (dx, dy) [m]."""
        return Walls(tuple((x + dx, y + dy) for x, y in self.points), self.closed)

    def segments(self) -> list[tuple[Point, Point]]:
        """Its segments, in order."""
        p = self.points
        pairs = [(p[i], p[i + 1]) for i in range(len(p) - 1)]
        if self.closed and len(p) > 2:
            pairs.append((p[-1], p[0]))
        return pairs


Shape = Union[Circle, Polygon, Walls]
Colour = tuple[int, int, int]  # r, g, b, 0..255

#: The height [m] above the water and the colour (r, g, b) of an obstacle that gives none, by
#: kind: a buoy, a hull or a pier, the basin's walls (what the simulated camera draws).
DEFAULT_HEIGHT: dict[type, float] = {Circle: 0.5, Polygon: 0.4, Walls: 1.0}
DEFAULT_COLOUR: dict[type, Colour] = {Circle: (255, 110, 0), Polygon: (225, 225, 220),
                                      Walls: (150, 150, 145)}


# -- motions -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Static:
    """Does not move."""

    def offset(self, t: float) -> Point:
        """Displacement [m] at ``t`` [s] from the pose at t = 0."""
        return 0.0, 0.0

    def velocity(self, t: float) -> Point:
        """Velocity [m/s] in odom at ``t`` [s]."""
        return 0.0, 0.0


@dataclass(frozen=True)
class ConstantVelocity:
    """``p(t) = p(0) + v t``: ``v`` (vx, vy) [m/s] in odom."""

    v: Point

    def offset(self, t: float) -> Point:
        """Displacement [m] at ``t`` [s] from the pose at t = 0."""
        return self.v[0] * t, self.v[1] * t

    def velocity(self, t: float) -> Point:
        """Velocity [m/s] in odom at ``t`` [s]."""
        return self.v


@dataclass(frozen=True)
class Waypoints:
    """Through ``path`` at ``speed`` [m/s], in straight legs.

    ``path[0]`` is the reference point at t = 0, the rest the waypoints [m] in odom;
    ``loop``: back to ``path[0]`` and round again, else stop at the last one. Legs of zero
    length are skipped. ``dwell`` [s]: stopped this long at the end of each leg (a mark held
    still at each place for a calibration), the last one's included when looping.
    """

    path: tuple[Point, ...]
    speed: float
    loop: bool = False
    dwell: float = 0.0
    _legs: tuple[tuple[float, float, float, float, float], ...] = field(
        init=False, repr=False, compare=False)  # (s0, x0, y0, ux, uy) of each leg
    _length: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = list(self.path) + ([self.path[0]] if self.loop else [])
        legs = []
        s = 0.0
        for (x0, y0), (x1, y1) in zip(pts[:-1], pts[1:]):
            d = math.hypot(x1 - x0, y1 - y0)
            if d > 0.0:
                legs.append((s, x0, y0, (x1 - x0) / d, (y1 - y0) / d))
                s += d
        object.__setattr__(self, '_legs', tuple(legs))
        object.__setattr__(self, '_length', s)

    @property
    def length(self) -> float:
        """Length of the path [m] (one round when looping)."""
        return self._length

    def _leg(self, t: float) -> tuple[float, float, float, float, float, bool]:
        """(s into the leg, x0, y0, ux, uy, moving) at ``t``."""
        if not self._legs or t <= 0.0:
            x0, y0 = self.path[0]
            ux, uy = (self._legs[0][3], self._legs[0][4]) if self._legs else (0.0, 0.0)
            return 0.0, x0, y0, ux, uy, bool(self._legs) and t == 0.0
        if self.dwell > 0.0:
            s, moving = self._along_with_dwell(t)
        else:
            s = self.speed * t
            moving = True
            if self.loop:
                s = math.fmod(s, self._length)
            elif s >= self._length:
                s, moving = self._length, False
        i = len(self._legs) - 1
        while i > 0 and self._legs[i][0] > s:
            i -= 1
        s0, x0, y0, ux, uy = self._legs[i]
        return s - s0, x0, y0, ux, uy, moving

    def _along_with_dwell(self, t: float) -> tuple[float, bool]:
        """(distance along the path [m], moving) at ``t`` > 0 with stops of ``dwell``."""
        ends = [leg[0] for leg in self._legs[1:]] + [self._length]
        if self.loop:
            t = math.fmod(t, self._length / self.speed + len(self._legs) * self.dwell)
        for (s0, *_), s1 in zip(self._legs, ends):
            travel = (s1 - s0) / self.speed
            if t < travel:
                return s0 + self.speed * t, True
            t -= travel
            if t < self.dwell:
                return s1, False
            t -= self.dwell
        return self._length, False

    def position(self, t: float) -> Point:
        """Where the reference point is at ``t`` [s]."""
        ds, x0, y0, ux, uy, _ = self._leg(t)
        return x0 + ux * ds, y0 + uy * ds

    def offset(self, t: float) -> Point:
        """Displacement [m] at ``t`` [s] from the pose at t = 0."""
        x, y = self.position(t)
        return x - self.path[0][0], y - self.path[0][1]

    def velocity(self, t: float) -> Point:
        """Velocity [m/s] in odom at ``t`` [s] (zero once stopped, and before t = 0)."""
        _, _, _, ux, uy, moving = self._leg(t)
        return (self.speed * ux, self.speed * uy) if moving else (0.0, 0.0)


Motion = Union[Static, ConstantVelocity, Waypoints]


@dataclass(frozen=True)
class Obstacle:
    """One named obstacle: its shape at t = 0, how it moves, and how it looks.

    ``height`` [m] above the water and ``colour`` (r, g, b): None takes its kind's default
    (``DEFAULT_HEIGHT``, ``DEFAULT_COLOUR``), so both are always set once built.
    """

    name: str
    shape: Shape
    motion: Motion = Static()
    height: float = None  # type: ignore[assignment]  # None: the kind's, set below
    colour: Colour = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.height is None:
            object.__setattr__(self, 'height', DEFAULT_HEIGHT[type(self.shape)])
        if self.colour is None:
            object.__setattr__(self, 'colour', DEFAULT_COLOUR[type(self.shape)])
        if not self.height > 0.0:
            raise ValueError(f'obstacle {self.name}: height must be > 0 m, got {self.height}')

    @property
    def moving(self) -> bool:
        """Whether it ever moves."""
        return not isinstance(self.motion, Static)

    def at(self, t: float) -> Shape:
        """Its shape placed at ``t`` [s]."""
        dx, dy = self.motion.offset(t)
        return self.shape if dx == 0.0 and dy == 0.0 else self.shape.moved(dx, dy)

    def velocity(self, t: float) -> Point:
        """Its velocity [m/s] in odom at ``t`` [s]."""
        return self.motion.velocity(t)


class RayHits(NamedTuple):
    """What each ray of a ``World.cast`` met.

    ``ranges``: distance [m] (inf: nothing); ``obstacle``: the index of the obstacle in
    ``World.obstacles`` (-1: nothing).
    """

    ranges: FloatArray
    obstacle: NDArray[np.int64]


# -- the world -----------------------------------------------------------------------------
class World:
    """Obstacles in odom (see the module docstring); immutable once built.

    The shapes are flattened into arrays once (circle centres and radii, segment end
    points, each with its obstacle's index), so placing them at ``t`` is one offset per
    obstacle added to those arrays.
    """

    def __init__(self, obstacles: Sequence[Obstacle] = ()) -> None:
        names = [o.name for o in obstacles]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f'obstacle names must be unique: {", ".join(dup)} repeated')
        self.obstacles: tuple[Obstacle, ...] = tuple(obstacles)
        centers, radii, c_owner = [], [], []
        seg_a, seg_b, s_owner = [], [], []
        solid = []
        for i, o in enumerate(self.obstacles):
            if isinstance(o.shape, Circle):
                centers.append(o.shape.center)
                radii.append(o.shape.radius)
                c_owner.append(i)
            else:
                for a, b in o.shape.segments():
                    seg_a.append(a)
                    seg_b.append(b)
                    s_owner.append(i)
            solid.append(not isinstance(o.shape, Walls))
        self._centers = np.array(centers, dtype=float).reshape(-1, 2)
        self._radii = np.array(radii, dtype=float)
        self._c_owner = np.array(c_owner, dtype=np.int64)
        self._seg_a = np.array(seg_a, dtype=float).reshape(-1, 2)
        self._seg_b = np.array(seg_b, dtype=float).reshape(-1, 2)
        self._s_owner = np.array(s_owner, dtype=np.int64)
        self._polygon = np.array([isinstance(o.shape, Polygon) for o in self.obstacles],
                                 dtype=bool)
        self._moving = [i for i, o in enumerate(self.obstacles) if o.moving]

    def __len__(self) -> int:
        return len(self.obstacles)

    def __bool__(self) -> bool:
        return bool(self.obstacles)

    def __repr__(self) -> str:
        return f'World({", ".join(self.names)})'

    @property
    def names(self) -> tuple[str, ...]:
        """The obstacles' names, in order (their index is their id)."""
        return tuple(o.name for o in self.obstacles)

    def index(self, name: str) -> int:
        """Return the index of obstacle ``name``; ``KeyError`` listing the names if none."""
        for i, o in enumerate(self.obstacles):
            if o.name == name:
                return i
        raise KeyError(f'no obstacle {name!r}; obstacles: {", ".join(self.names) or "none"}')

    # -- placing -----------------------------------------------------------------------------
    def offsets(self, t: float) -> FloatArray:
        """Displacement (N, 2) [m] of every obstacle at ``t`` [s] from its pose at t = 0."""
        off = np.zeros((len(self.obstacles), 2))
        for i in self._moving:
            off[i] = self.obstacles[i].motion.offset(t)
        return off

    def shapes_at(self, t: float) -> tuple[Shape, ...]:
        """Every obstacle's shape placed at ``t`` [s], in the order of ``obstacles``."""
        return tuple(o.at(t) for o in self.obstacles)

    def velocities(self, t: float) -> FloatArray:
        """Velocity (N, 2) [m/s] of every obstacle in odom at ``t`` [s]."""
        v = np.zeros((len(self.obstacles), 2))
        for i in self._moving:
            v[i] = self.obstacles[i].velocity(t)
        return v

    def velocity(self, name: str, t: float) -> Point:
        """Velocity [m/s] in odom of obstacle ``name`` at ``t`` [s]."""
        return self.obstacles[self.index(name)].velocity(t)

    def _placed(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        if not self._moving:
            return self._centers, self._seg_a, self._seg_b
        off = self.offsets(t)
        return (self._centers + off[self._c_owner], self._seg_a + off[self._s_owner],
                self._seg_b + off[self._s_owner])

    # -- rays --------------------------------------------------------------------------------
    def cast(self, origin_xy: ArrayLike, bearings_rad: ArrayLike, t: float = 0.0) -> RayHits:
        """Find the first surface along each ray, with the obstacles placed at ``t`` [s].

        Rays from ``origin_xy`` (x, y) [m] in odom, at the bearings [rad] in odom (CCW from
        +x). A ray from inside a solid meets its surface from within.
        """
        ox, oy = (float(v) for v in np.asarray(origin_xy, dtype=float).reshape(2))
        bearing = np.asarray(bearings_rad, dtype=float).reshape(-1)
        dx, dy = np.cos(bearing)[:, None], np.sin(bearing)[:, None]  # (R, 1)
        best = np.full(bearing.shape, np.inf)
        owner = np.full(bearing.shape, -1, dtype=np.int64)
        centers, seg_a, seg_b = self._placed(t)
        if len(centers):
            # |o + t d - c|^2 = r^2 with |d| = 1: t^2 + 2 b t + c0 = 0, b = (o - c).d
            ocx, ocy = ox - centers[:, 0], oy - centers[:, 1]  # (C,)
            b = ocx * dx + ocy * dy  # (R, C)
            c0 = ocx * ocx + ocy * ocy - self._radii * self._radii
            disc = b * b - c0
            root = np.sqrt(np.maximum(disc, 0.0))
            near, far = -b - root, -b + root
            hit = np.where(near > RAY_EPSILON, near, far)
            hit = np.where((disc >= 0.0) & (hit > RAY_EPSILON), hit, np.inf)
            self._keep_nearest(hit, self._c_owner, best, owner)
        if len(seg_a):
            # o + t d = a + u e: t = ((a - o) x e) / (d x e), u = ((a - o) x d) / (d x e)
            ex, ey = seg_b[:, 0] - seg_a[:, 0], seg_b[:, 1] - seg_a[:, 1]  # (S,)
            ax, ay = seg_a[:, 0] - ox, seg_a[:, 1] - oy
            denom = dx * ey - dy * ex  # (R, S)
            with np.errstate(divide='ignore', invalid='ignore'):
                tt = (ax * ey - ay * ex) / denom
                u = (ax * dy - ay * dx) / denom
            ok = (denom != 0.0) & (tt > RAY_EPSILON) & (u >= 0.0) & (u <= 1.0)
            self._keep_nearest(np.where(ok, tt, np.inf), self._s_owner, best, owner)
        return RayHits(best, owner)

    @staticmethod
    def _keep_nearest(hit: FloatArray, owners: NDArray[np.int64], best: FloatArray,
                      owner: NDArray[np.int64]) -> None:
        k = np.argmin(hit, axis=1)
        d = hit[np.arange(hit.shape[0]), k]
        nearer = d < best
        best[nearer] = d[nearer]
        owner[nearer] = owners[k[nearer]]

    def raycast(self, origin_xy: ArrayLike, bearings_world_rad: ArrayLike,
                t: float = 0.0) -> FloatArray:
        """Return the distance [m] to the first surface along each ray (inf: nothing).

        See ``cast``.
        """
        return self.cast(origin_xy, bearings_world_rad, t).ranges

    # -- distances ---------------------------------------------------------------------------
    def distance(self, point_xy: ArrayLike, t: float = 0.0) -> FloatArray:
        """Return the signed distance (N,) [m] from a point to each obstacle's surface.

        From ``point_xy`` (x, y) in odom, at ``t`` [s], in the order of ``obstacles``:
        negative inside a circle or a polygon; walls have no inside (never negative).
        """
        px, py = (float(v) for v in np.asarray(point_xy, dtype=float).reshape(2))
        out = np.full(len(self.obstacles), np.inf)
        centers, seg_a, seg_b = self._placed(t)
        if len(centers):
            d = np.hypot(px - centers[:, 0], py - centers[:, 1]) - self._radii
            np.minimum.at(out, self._c_owner, d)
        if len(seg_a):
            e = seg_b - seg_a
            w = np.array([px, py]) - seg_a
            ee = np.einsum('ij,ij->i', e, e)
            with np.errstate(divide='ignore', invalid='ignore'):
                u = np.clip(np.where(ee > 0.0, np.einsum('ij,ij->i', w, e) / ee, 0.0), 0, 1)
            d = np.hypot(w[:, 0] - u * e[:, 0], w[:, 1] - u * e[:, 1])
            np.minimum.at(out, self._s_owner, d)
            # inside a polygon (even-odd): an odd number of its edges cross the ray +x
            ya, yb = seg_a[:, 1], seg_b[:, 1]
            straddle = (ya > py) != (yb > py)
            with np.errstate(divide='ignore', invalid='ignore'):
                x_cross = seg_a[:, 0] + (py - ya) * e[:, 0] / (yb - ya)
            crossing = (straddle & (x_cross > px)).astype(np.int64)
            counts = np.zeros(len(self.obstacles), dtype=np.int64)
            np.add.at(counts, self._s_owner, crossing)
            inside = self._polygon & (counts % 2 == 1)
            out[inside] = -out[inside]
        return out

    def nearest(self, point_xy: ArrayLike, t: float = 0.0) -> tuple[str, float]:
        """Return the nearest obstacle's name and its signed distance [m] (``('', inf)``: none)."""
        d = self.distance(point_xy, t)
        if not len(d):
            return '', math.inf
        i = int(np.argmin(d))
        return self.obstacles[i].name, float(d[i])


#: The world of a profile without a ``world`` section: nothing in it.
EMPTY_WORLD = World()
