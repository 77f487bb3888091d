"""Obstacles tracked across scans: circles with a constant-velocity Kalman filter, segments static.

Pure numpy/scipy/filterpy, no ROS; positions in the world frame [m], times [ns].

Circles. Each track is a constant-velocity Kalman filter (filterpy ``KalmanFilter``), state
x = [px, py, vx, vy], the centre measured. Between scans the state is predicted with

    F = [[I, dt I], [0, I]],  Q = G G^T q^2,  G = [dt^2/2 I; dt I]

(white-noise acceleration of standard deviation q: Bar-Shalom, Li and Kirubarajan 2001,
"Estimation with applications to tracking and navigation", sec. 6.3.2). Measurements are
assigned to tracks by ``scipy.optimize.linear_sum_assignment`` on the squared Mahalanobis
distance d^2 = nu^T S^-1 nu (nu the innovation, S = H P H^T + R) with pairs beyond the gate
ruled out: the assignment that is best for all tracks together, where a greedy one (nearest
pair first) steals a track's measurement when two obstacles cross. An unassigned measurement
starts a tentative track; a track is *confirmed* after ``confirm_hits`` measurements, and
dropped (tentative or confirmed) after ``drop_misses`` scans in a row without one, so a single
spurious return never becomes an obstacle. The radius is smoothed (exponentially).

Segments (walls, piers) do not move: a measured segment extends the track it lies on (within
``segment_gate`` of its line, directions within ``segment_angle_gate``, overlapping or within
the gate of its ends): the line is averaged, the ends are the union's; several pieces of one
wall (cut by a buoy in front) extend one track. Tracks that grow into each other merge (the
older id stays). The same hits and misses confirm and drop them.

A short segment near a circle track is taken as that circle's seen *front* (a far buoy's
few points fit a line as well as a circle in one scan): it corrects the track's position and
stamp, but it is no hit and does not reset the misses. Only circles keep a circle track
alive, so fronts bridge a few scans of such flicker and never sustain a circle by
themselves: a circle that once fitted a buoy's short arc too large would otherwise slide
along the wall behind it, fed by the wall's short pieces, for as long as the wall is seen.

Each obstacle carries the stamp of the last scan that measured it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from enbarr_interfaces.obstacles import CIRCLE, closest_on_segment, Obstacle, SEGMENT

from enbarr_core.estimation.filterpy_kalman import KalmanFilter
from enbarr_core.perception.fitting import CircleFit, SegmentFit

Vector = NDArray[np.float64]
_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
#: Cost of a pair beyond the gate: never chosen over a feasible one, dropped after.
_RULED_OUT = 1e12


@dataclass(frozen=True)
class TrackerSettings:
    """Settings of :class:`Tracker`."""

    confirm_hits: int          # N: measurements before a track is published
    drop_misses: int           # M: scans in a row without a measurement before it is dropped
    gate: float                # squared Mahalanobis distance of an admissible pair
    accel_noise: float         # q: white-noise acceleration of a circle [m/s^2]
    initial_speed_std: float   # velocity standard deviation of a new track [m/s]
    radius_smoothing: float    # weight of a new radius, (0, 1]
    segment_gate: float        # distance of a segment from a track's line [m]
    segment_angle_gate: float  # direction difference of a segment and a track [rad]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the settings do not hold together."""
        if self.confirm_hits < 1:
            raise ValueError(f'confirm_hits: {self.confirm_hits} must be >= 1')
        if self.drop_misses < 1:
            raise ValueError(f'drop_misses: {self.drop_misses} must be >= 1')
        for name in ('gate', 'accel_noise', 'initial_speed_std', 'segment_gate',
                     'segment_angle_gate'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'{name}: {getattr(self, name)} must be > 0')
        if not 0.0 < self.radius_smoothing <= 1.0:
            raise ValueError(f'radius_smoothing: {self.radius_smoothing} must be in (0, 1]')


class CircleTrack:
    """One moving circle: its Kalman filter, smoothed radius, hits and misses."""

    def __init__(self, track_id: int, z: CircleFit, stamp_ns: int, speed_std: float) -> None:
        self.id = track_id
        self.kf = KalmanFilter(dim_x=4, dim_z=2)
        self.kf.x = np.array([[z.x], [z.y], [0.0], [0.0]])
        self.kf.P = np.diag([z.cov[0], z.cov[2], speed_std ** 2, speed_std ** 2])
        self.kf.P[0, 1] = self.kf.P[1, 0] = z.cov[1]
        self.kf.H = _H
        self.kf.inv = inverse_2x2   # S is 2x2: filterpy lets the inverse be chosen
        self.radius = z.radius
        self.hits = 1
        self.misses = 0
        self.stamp_ns = stamp_ns

    def predict(self, f: Vector, q: Vector) -> None:
        """Predict the state one step ahead with F = ``f`` and Q = ``q`` (:func:`motion`)."""
        self.kf.predict(F=f, Q=q)

    def innovation(self, z: CircleFit) -> float:
        """Squared Mahalanobis distance of measurement ``z`` from the prediction."""
        # In floats: every track meets every measurement of a scan, and two small arrays per
        # pair cost more than the arithmetic.
        (x,), (y,) = self.kf.x[:2].tolist()
        (p00, p01), (p10, p11) = self.kf.P[:2, :2].tolist()
        nu0, nu1 = z.x - x, z.y - y
        s00, s01, s10, s11 = p00 + z.cov[0], p01 + z.cov[1], p10 + z.cov[1], p11 + z.cov[2]
        det = s00 * s11 - s01 * s10
        if not det > 0.0:
            return math.inf
        # nu^T S^-1 nu with the 2x2 inverse written out
        return float((s11 * nu0 * nu0 - 2.0 * s01 * nu0 * nu1 + s00 * nu1 * nu1) / det)

    def update(self, z: CircleFit, stamp_ns: int, alpha: float, *, circle: bool = True) -> None:
        """Correct with ``z`` measured at ``stamp_ns``; smooth the radius with weight alpha.

        ``circle`` False: ``z`` is a seen front (:func:`front_of`), which corrects the state
        and the stamp but is no hit, and does not reset the misses (module docstring).
        """
        r = np.array([[z.cov[0], z.cov[1]], [z.cov[1], z.cov[2]]])
        self.kf.update(np.array([[z.x], [z.y]]), R=r)
        self.radius += alpha * (z.radius - self.radius)
        if circle:
            self.hits += 1
            self.misses = 0
        self.stamp_ns = stamp_ns

    def obstacle(self) -> Obstacle:
        """Return the track as an obstacle."""
        (x,), (y,), (vx,), (vy,) = self.kf.x.tolist()   # one conversion, not ten reads
        p = self.kf.P.tolist()
        return Obstacle(self.id, CIRCLE, x, y, float(self.radius), vx=vx, vy=vy,
                        position_cov=(p[0][0], p[0][1], p[1][1]),
                        velocity_cov=(p[2][2], p[2][3], p[3][3]), stamp_ns=self.stamp_ns)


class SegmentTrack:
    """One static segment: its ends [m], how well it is known, hits and misses.

    Plain floats: a scan compares every measured segment with every track, and numpy's
    per-call cost on two-element vectors is larger than the arithmetic.
    """

    def __init__(self, track_id: int, z: SegmentFit, stamp_ns: int) -> None:
        self.id = track_id
        self.a = (z.x1, z.y1)
        self.b = (z.x2, z.y2)
        self.var = z.rms * z.rms      # of a point's distance to the line [m^2]
        self.weight = 1.0             # measurements averaged into the line (capped)
        self.hits = 1
        self.misses = 0
        self.stamp_ns = stamp_ns

    def direction(self) -> tuple[float, float]:
        """Return the unit direction a -> b."""
        dx, dy = self.b[0] - self.a[0], self.b[1] - self.a[1]
        n = max(math.hypot(dx, dy), 1e-12)
        return dx / n, dy / n

    def match(self, a: tuple[float, float], b: tuple[float, float], gate: float,
              angle_gate: float, rms: float = 0.0) -> float | None:
        """How far (mean of both ends, [m]) the segment a-b lies from this line, or None.

        The gates widen with the noise (``rms`` [m] of the segment a-b, and the track's): a
        wall seen far and obliquely is a noisy line, and the direction of a short piece of it
        is known only to about atan(2 rms / length); each piece must still find its wall.
        """
        noise = 2.0 * (math.sqrt(self.var) + rms)
        gate += noise
        ux, uy = self.direction()
        dx, dy = b[0] - a[0], b[1] - a[1]
        length = math.hypot(dx, dy)
        if length > 0.0:
            cos = abs(dx * ux + dy * uy) / length
            if math.acos(min(1.0, cos)) > angle_gate + math.atan2(noise, length):
                return None
        ax, ay = a[0] - self.a[0], a[1] - self.a[1]
        bx, by = b[0] - self.a[0], b[1] - self.a[1]
        da, db = abs(ay * ux - ax * uy), abs(by * ux - bx * uy)   # distances to the line
        if max(da, db) > gate:
            return None
        span = (self.b[0] - self.a[0]) * ux + (self.b[1] - self.a[1]) * uy
        ta, tb = sorted((ax * ux + ay * uy, bx * ux + by * uy))
        if tb < -gate or ta > span + gate:
            return None   # on the line but beyond an end
        return 0.5 * (da + db)

    def extend(self, a: tuple[float, float], b: tuple[float, float], weight: float,
               rms: float, stamp_ns: int, cap: float = 10.0) -> None:
        """Average the segment a-b (of ``weight`` measurements) into the line, ends the union."""
        ux, uy = self.direction()
        vx, vy = b[0] - a[0], b[1] - a[1]
        n = max(math.hypot(vx, vy), 1e-12)
        vx, vy = vx / n, vy / n
        if vx * ux + vy * uy < 0.0:
            vx, vy = -vx, -vy
        w = self.weight / (self.weight + weight)
        ex, ey = w * ux + (1.0 - w) * vx, w * uy + (1.0 - w) * vy
        n = max(math.hypot(ex, ey), 1e-12)
        ex, ey = ex / n, ey / n
        cx = 0.5 * (w * (self.a[0] + self.b[0]) + (1.0 - w) * (a[0] + b[0]))
        cy = 0.5 * (w * (self.a[1] + self.b[1]) + (1.0 - w) * (a[1] + b[1]))
        t = [(p[0] - cx) * ex + (p[1] - cy) * ey for p in (self.a, self.b, a, b)]
        lo, hi = min(t), max(t)
        self.a, self.b = (cx + lo * ex, cy + lo * ey), (cx + hi * ex, cy + hi * ey)
        self.var = w * self.var + (1.0 - w) * rms * rms
        self.weight = min(self.weight + weight, cap)
        self.stamp_ns = max(self.stamp_ns, stamp_ns)

    def obstacle(self) -> Obstacle:
        """Return the track as an obstacle (no velocity: walls do not move)."""
        return Obstacle(self.id, SEGMENT, self.a[0], self.a[1], 0.0, self.b[0], self.b[1],
                        position_cov=(self.var, 0.0, self.var), stamp_ns=self.stamp_ns)


def inverse_2x2(s: Vector) -> Vector:
    """Return the inverse of the 2x2 matrix ``s``, written out.

    ``numpy.linalg.inv``'s checks cost more than the arithmetic; ``LinAlgError`` when it is
    singular, as numpy's.
    """
    (a, b), (c, d) = s.tolist()
    det = a * d - b * c
    if not (abs(det) > 0.0 and math.isfinite(det)):
        raise np.linalg.LinAlgError('Singular matrix')
    return np.array([[d / det, -b / det], [-c / det, a / det]])


def motion(dt: float, q: float) -> tuple[Vector, Vector]:
    """Return F and Q of the constant-velocity model over ``dt`` [s] (module docstring).

    Q = G G^T q^2 written out (G = [dt^2/2 I; dt I]): one array each, not numpy's products.
    """
    f = np.array([[1.0, 0.0, dt, 0.0], [0.0, 1.0, 0.0, dt], [0.0, 0.0, 1.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0]])
    q2 = q * q
    a, b, c = 0.25 * dt ** 4 * q2, 0.5 * dt ** 3 * q2, dt * dt * q2
    return f, np.array([[a, 0.0, b, 0.0], [0.0, a, 0.0, b], [b, 0.0, c, 0.0],
                        [0.0, b, 0.0, c]])


def front_of(z: SegmentFit, t: CircleTrack) -> CircleFit | None:
    """Segment ``z`` read as the visible front of circle track ``t``, or None when too long."""
    if z.length > 2.0 * t.radius + 3.0 * z.rms:
        return None
    (cx,), (cy,) = t.kf.x[:2].tolist()
    qx, qy = closest_on_segment(cx, cy, z.x1, z.y1, z.x2, z.y2)
    dx, dy = cx - qx, cy - qy
    d = math.hypot(dx, dy)
    if d <= 0.0:
        return None
    var = z.rms * z.rms + t.radius * t.radius
    return CircleFit(qx + t.radius * dx / d, qy + t.radius * dy / d, t.radius,
                     (var, 0.0, var), z.rms, fallback=True)


def assign(cost: Vector | Sequence[Sequence[float]], gate: float) -> list[tuple[int, int]]:
    """Return the (row, column) pairs of least total cost, pairs above ``gate`` ruled out.

    ``cost``: an array or a list of rows (the tracker's: a few tracks and measurements, read
    in floats; numpy and the solver only when a gate is contested).
    """
    rows = cost.tolist() if isinstance(cost, np.ndarray) else cost
    if not rows or not rows[0]:
        return []
    pairs = [(i, j) for i, row in enumerate(rows) for j, c in enumerate(row) if c <= gate]
    if len({i for i, _ in pairs}) == len(pairs) == len({j for _, j in pairs}):
        # Obstacles apart (the usual scan): no track has two measurements in its gate and no
        # measurement two tracks, so the best assignment takes every pair in a gate and the
        # solver has nothing to decide.
        return pairs
    a = np.array(rows, dtype=float)
    c = np.where(a <= gate, a, _RULED_OUT)
    r, k = linear_sum_assignment(c)
    return [(int(i), int(j)) for i, j in zip(r, k) if a[i, j] <= gate]


class Tracker:
    """Tracks of circles and segments across scans (module docstring)."""

    def __init__(self, settings: TrackerSettings) -> None:
        settings.validate()
        self.settings = settings
        self.circles: list[CircleTrack] = []
        self.segments: list[SegmentTrack] = []
        self._next_id = 1
        self._stamp_ns: int | None = None

    def _new_id(self) -> int:
        i = self._next_id
        self._next_id = self._next_id % 0xFFFFFFFF + 1   # UINT32 on the wire, never 0
        return i

    def reset(self) -> None:
        """Forget every track (the world frame moved: a new estimate)."""
        self.circles.clear()
        self.segments.clear()
        self._stamp_ns = None

    def update(self, circles: Sequence[CircleFit], segments: Sequence[SegmentFit],
               stamp_ns: int) -> None:
        """Take the shapes measured by the scan stamped ``stamp_ns``.

        A scan older than the last one taken is refused (``ValueError``): the filters only
        go forward in time.
        """
        s = self.settings
        if self._stamp_ns is not None:
            dt = (stamp_ns - self._stamp_ns) * 1e-9
            if dt < 0.0:
                raise ValueError(f'scan stamped {stamp_ns} ns is older than the last one '
                                 f'({self._stamp_ns} ns)')
            if dt > 0.0 and self.circles:
                f, q = motion(dt, s.accel_noise)   # the same for every track
                for t in self.circles:
                    t.predict(f, q)
        self._stamp_ns = stamp_ns
        # only a segment no longer than a tracked circle may be that circle's front
        widest = 2.0 * max((t.radius for t in self.circles), default=0.0)
        short = [z for z in segments if z.length <= widest + s.segment_gate]
        rest = self._update_circles(circles, short, stamp_ns)
        self._update_segments([z for z in segments if z not in short] + rest, stamp_ns)

    def _update_circles(self, measured: Sequence[CircleFit], short: Sequence[SegmentFit],
                        stamp_ns: int) -> list[SegmentFit]:
        """Assign circles (and short segments, as seen fronts of tracked circles) to tracks.

        Return the segments no circle track took.
        """
        s = self.settings
        # A short segment near a circle track is that circle's front: a far buoy's few noisy
        # points fit a line as well as a circle, and the classification of one scan must not
        # break a track. As a measurement of track i it is the centre one radius behind the
        # segment's point nearest the prediction, with the radius as its uncertainty.
        fronts = [[front_of(z, t) for z in short] for t in self.circles]
        cost = [[t.innovation(z) for z in measured]
                + [t.innovation(f) if f is not None else math.inf for f in row]
                for t, row in zip(self.circles, fronts)]
        pairs = assign(cost, s.gate)
        used = set()
        hit = set()
        for i, j in pairs:
            used.add(j)
            if j < len(measured):
                self.circles[i].update(measured[j], stamp_ns, s.radius_smoothing)
                hit.add(i)
            else:   # its radius was not measured, nor that it is a circle: a miss
                front = fronts[i][j - len(measured)]
                assert front is not None
                self.circles[i].update(front, stamp_ns, 0.0, circle=False)
        for i, t in enumerate(self.circles):
            if i not in hit:
                t.misses += 1
        self.circles = [t for t in self.circles if t.misses < s.drop_misses]
        for j, z in enumerate(measured):
            if j not in used:
                self.circles.append(CircleTrack(self._new_id(), z, stamp_ns,
                                                s.initial_speed_std))
        return [z for k, z in enumerate(short) if len(measured) + k not in used]

    def _update_segments(self, measured: Sequence[SegmentFit], stamp_ns: int) -> None:
        s = self.settings
        hit: set[int] = set()
        for z in measured:
            a, b = (z.x1, z.y1), (z.x2, z.y2)
            best, best_d = None, math.inf
            for t in self.segments:
                d = t.match(a, b, s.segment_gate, s.segment_angle_gate, z.rms)
                if d is not None and d < best_d:
                    best, best_d = t, d
            if best is None:
                self.segments.append(SegmentTrack(self._new_id(), z, stamp_ns))
                hit.add(self.segments[-1].id)
                continue
            best.extend(a, b, 1.0, z.rms, stamp_ns)
            if best.id not in hit:
                best.hits += 1
                best.misses = 0
                hit.add(best.id)
        for t in self.segments:
            if t.id not in hit:
                t.misses += 1
        self.segments = [t for t in self.segments if t.misses < s.drop_misses]
        self._merge_segments(hit)

    def _merge_segments(self, changed: set[int]) -> None:
        """Merge tracks that grew into each other (the older, lower id, stays).

        Only a track that changed this scan can have grown into another.
        """
        s = self.settings
        kept: list[SegmentTrack] = []
        for t in sorted(self.segments, key=lambda t: t.id):
            for k in kept:
                if ((t.id in changed or k.id in changed)
                        and k.match(t.a, t.b, s.segment_gate, s.segment_angle_gate,
                                   math.sqrt(t.var)) is not None):
                    k.extend(t.a, t.b, t.weight, math.sqrt(t.var), t.stamp_ns)
                    k.hits = max(k.hits, t.hits)
                    k.misses = min(k.misses, t.misses)
                    break
            else:
                kept.append(t)
        self.segments = kept

    def obstacles(self) -> list[Obstacle]:
        """Return the confirmed tracks as obstacles, circles first, by id."""
        n = self.settings.confirm_hits
        return ([t.obstacle() for t in self.circles if t.hits >= n]
                + [t.obstacle() for t in self.segments if t.hits >= n])

    @property
    def confirmed(self) -> int:
        """Return the number of confirmed tracks."""
        n = self.settings.confirm_hits
        return sum(t.hits >= n for t in self.circles) + sum(t.hits >= n for t in self.segments)
