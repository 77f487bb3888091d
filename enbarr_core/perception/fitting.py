"""Shapes fitted to a cluster of lidar points: circles (buoys, boats) and segments (walls).

No ROS; points (N, 2) [m] in the world, in ring order.

Circle: the algebraic fit of Kasa (1976) (x^2 + y^2 + D x + E y + F = 0 in least squares,
closed form) starts a geometric refinement, Levenberg-Marquardt on the distances
e_i = |p_i - c| - R (Chernov 2010, "Circular and linear regression", ch. 4), which corrects
Kasa's bias towards small circles on a short arc. A lidar sees only the near side of a
buoy, so a fit is kept only when its centre lies behind the visible arc (away from the
sensor); below ``min_radius`` the radius is held there and the centre refitted; a cluster of
one or two points, or a fit that fails, gets the honest *fallback*: radius half the chord
(at least ``min_radius``), centre behind the chord's middle, and a covariance as large as the
radius (the centre is not known better than that).

Segment: total least squares line (the principal axis of the points), endpoints the extreme
projections of the points. A cluster bent at a corner is cut where it is furthest from the
chord (split and merge, iterative end-point fit: Nguyen et al. 2005, "A comparison of line
extraction algorithms using 2D laser rangefinder"), so an L-shaped wall is two segments.

:func:`fit_cluster` decides: a cluster longer than a circle may be is segments; a short one a
circle; in between, a circle when its residual is clearly smaller than the line's (per degree
of freedom, ``circle_ratio``), else segments. Walls stay segments. A scan's clusters go
through :func:`fit_clusters`: the same decisions, but the lines, Kasa's circles, extents and
chord tests of all clusters come from one pass of sums (:func:`cluster_sums`), and a wall
straight within the split distance of its chord is not split.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

Vector = NDArray[np.float64]
#: The geometric circle fit stops when a step moves the circle less than this [m].
STEP_TOLERANCE = 1e-3


@dataclass(frozen=True)
class CircleFit:
    """A circle measured in one scan: centre [m], radius [m], centre covariance [m^2]."""

    x: float
    y: float
    radius: float
    cov: tuple[float, float, float]   # xx, xy, yy [m^2]
    rms: float                        # rms distance of the points to the circle [m]
    fallback: bool = False            # True: too few points or no fit; see the module doc


@dataclass(frozen=True)
class SegmentFit:
    """A segment measured in one scan: ends [m] and the rms distance of its points [m]."""

    x1: float
    y1: float
    x2: float
    y2: float
    rms: float
    points: int

    @property
    def length(self) -> float:
        """Return the length [m]."""
        return math.hypot(self.x2 - self.x1, self.y2 - self.y1)


@dataclass(frozen=True)
class FitSettings:
    """Settings of :func:`fit_cluster`."""

    min_radius: float          # smallest circle [m]
    max_radius: float          # largest circle [m]; a longer cluster is a wall
    min_segment_length: float  # a cluster shorter than this is a circle [m]
    circle_ratio: float        # circle if its residual < ratio * the line's (per dof)
    split_distance: float      # a corner further than this (+ 3 sigma) from the chord cuts [m]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the settings do not hold together."""
        if not 0.0 < self.min_radius <= self.max_radius:
            raise ValueError(f'min_radius: {self.min_radius} m must be > 0 and at most '
                             f'max_radius ({self.max_radius} m)')
        if not self.min_segment_length > 0.0:
            raise ValueError(f'min_segment_length: {self.min_segment_length} m must be > 0')
        if not self.circle_ratio > 0.0:
            raise ValueError(f'circle_ratio: {self.circle_ratio} must be > 0')
        if not self.split_distance > 0.0:
            raise ValueError(f'split_distance: {self.split_distance} m must be > 0')


# -- circles -------------------------------------------------------------------------------
def _solve(m: list[list[float]], v: list[float]) -> list[float] | None:
    """Solve m x = v for a 2x2 or 3x3 ``m`` (lists) by Cramer's rule; None when singular.

    Written out because ``numpy.linalg.solve`` costs more in its checks than the arithmetic
    of a 3x3 system, and a scan solves dozens (``docs/benchmarks.md``, perception).
    """
    if len(v) == 2:
        det = m[0][0] * m[1][1] - m[0][1] * m[1][0]
        if abs(det) < 1e-300 or not math.isfinite(det):
            return None
        return [(v[0] * m[1][1] - m[0][1] * v[1]) / det, (m[0][0] * v[1] - v[0] * m[1][0]) / det]
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = m
    c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if abs(det) < 1e-300 or not math.isfinite(det):
        return None
    return [(v[0] * c00 + a01 * (a12 * v[2] - v[1] * a22) + a02 * (v[1] * a21 - a11 * v[2])) / det,
            (a00 * (v[1] * a22 - a12 * v[2]) + v[0] * c01 + a02 * (a10 * v[2] - v[1] * a20)) / det,
            (a00 * (a11 * v[2] - v[1] * a21) + a01 * (v[1] * a20 - a10 * v[2]) + v[0] * c02) / det]


def kasa(points: Vector) -> tuple[float, float, float] | None:
    """Algebraic circle fit (Kasa): (cx, cy, R) [m], or None for collinear points.

    The normal equations are summed over Python floats: a buoy's cluster has a few dozen
    points, where numpy's cost per call is most of the cost (``docs/benchmarks.md``).
    """
    n = len(points)
    if n < 3:
        return None
    xs, ys = points[:, 0].tolist(), points[:, 1].tolist()
    mx, my = math.fsum(xs) / n, math.fsum(ys) / n   # centred: better conditioned
    sxx = sxy = syy = sxz = syz = sz = 0.0
    for x, y in zip(xs, ys):
        x -= mx
        y -= my
        z = x * x + y * y
        sxx += x * x
        sxy += x * y
        syy += y * y
        sxz += x * z
        syz += y * z
        sz += z
    return _kasa_solve(n, mx, my, sxx, sxy, syy, sxz, syz, sz)


def kasa_from_sums(n: int, ox: float, oy: float, sums: Sequence[float]
                   ) -> tuple[float, float, float] | None:
    """Return :func:`kasa`'s circle from the sums of its n points p - o about o = (ox, oy).

    ``sums``: of x, y, x^2, x y, y^2, x^3, x^2 y, x y^2, y^3 (:func:`cluster_sums`). The
    centred sums kasa takes follow from them (u = x - mean x, v = y - mean y):
    sum u^3 = S_xxx - 3 m_x S_xx + 2 n m_x^3 and its kin.
    """
    if n < 3:
        return None
    sx, sy, sxx, sxy, syy, sxxx, sxxy, sxyy, syyy = sums
    mx, my = sx / n, sy / n
    cxx, cxy, cyy = sxx - sx * mx, sxy - sx * my, syy - sy * my
    uuu = sxxx - 3.0 * mx * sxx + 2.0 * n * mx * mx * mx
    uuv = sxxy - 2.0 * mx * sxy - my * sxx + 2.0 * n * mx * mx * my
    uvv = sxyy - 2.0 * my * sxy - mx * syy + 2.0 * n * mx * my * my
    vvv = syyy - 3.0 * my * syy + 2.0 * n * my * my * my
    return _kasa_solve(n, ox + mx, oy + my, cxx, cxy, cyy, uuu + uvv, uuv + vvv, cxx + cyy)


def _kasa_solve(n: int, mx: float, my: float, sxx: float, sxy: float, syy: float, sxz: float,
                syz: float, sz: float) -> tuple[float, float, float] | None:
    """Kasa's circle from the sums about the mean (mx, my); z = x^2 + y^2 there."""
    # [x y 1] [D E F]^T = -(x^2 + y^2) in least squares; the centred sums of x and y are 0
    sol = _solve([[sxx, sxy, 0.0], [sxy, syy, 0.0], [0.0, 0.0, float(n)]], [-sxz, -syz, -sz])
    if sol is None:
        return None
    cx, cy = -0.5 * sol[0], -0.5 * sol[1]
    r2 = cx * cx + cy * cy - sol[2]
    if not r2 > 0.0 or not math.isfinite(r2):
        return None
    return cx + mx, cy + my, math.sqrt(r2)


def refine_circle(points: Vector, cx: float, cy: float, radius: float,
                  fixed_radius: bool = False, iterations: int = 8
                  ) -> tuple[float, float, float, list[list[float]], float] | None:
    """Geometric fit: minimise sum (|p_i - c| - R)^2 by Levenberg-Marquardt from a start.

    Return (cx, cy, R, J^T J, sum e_i^2) with J the Jacobian of the residuals at the solution
    (for the covariance), or None when a point sits on the centre. With ``fixed_radius`` only
    the centre moves. The residual e_i = |p_i - c| - R has the Jacobian row -[u_i, 1], u_i
    the unit vector from c to p_i: with U the rows [u_x; u_y; 1], J^T J = U U^T and
    J^T e = -U e, summed over Python floats like :func:`kasa`.
    """
    k = 2 if fixed_radius else 3
    xs, ys = points[:, 0].tolist(), points[:, 1].tolist()
    count = float(len(xs))
    sqrt = math.sqrt
    mu = 1e-6

    def normal(cx: float, cy: float, r: float
               ) -> tuple[float, list[list[float]], list[float]] | None:
        """Cost, J^T J and J^T e at the circle (cx, cy, r)."""
        cost = a00 = a01 = a02 = a11 = a12 = g0 = g1 = g2 = 0.0
        for x, y in zip(xs, ys):
            dx, dy = x - cx, y - cy
            d = sqrt(dx * dx + dy * dy)
            if not d > 1e-12:
                return None
            ux, uy, e = dx / d, dy / d, d - r
            cost += e * e
            a00 += ux * ux
            a01 += ux * uy
            a11 += uy * uy
            a02 += ux
            a12 += uy
            g0 -= ux * e
            g1 -= uy * e
            g2 -= e
        if k == 2:
            return cost, [[a00, a01], [a01, a11]], [g0, g1]
        return cost, [[a00, a01, a02], [a01, a11, a12], [a02, a12, count]], [g0, g1, g2]

    x = [cx, cy, radius]
    now = normal(cx, cy, radius)
    if now is None:
        return None
    cost, jtj, jte = now
    for _ in range(iterations):
        a = [row[:] for row in jtj]
        for i in range(k):
            a[i][i] *= 1.0 + mu
        step = _solve(a, [-g for g in jte])
        if step is None:
            return None
        trial = [x[i] + step[i] if i < k else x[i] for i in range(3)]
        new = normal(*trial)
        if new is not None and new[0] <= cost:
            x, (cost, jtj, jte) = trial, new
            mu *= 0.1
            if sum(d * d for d in step) < STEP_TOLERANCE ** 2:
                break
        else:
            mu *= 10.0
            if mu > 1e8:
                break
    return x[0], x[1], x[2], jtj, cost


def _behind(cx: float, cy: float, mean: tuple[float, float], sensor: tuple[float, float]
            ) -> bool:
    """Whether the centre lies beyond the points' ``mean``, seen from the ``sensor``."""
    (mx, my), (sx, sy) = mean, sensor
    return (cx - mx) * (mx - sx) + (cy - my) * (my - sy) > 0.0


def fallback_circle(points: Vector, sensor: Vector, sigma: float,
                    min_radius: float, max_radius: float) -> CircleFit:
    """Return the circle of what cannot be fitted (the fallback of the module docstring)."""
    # In floats but for the rms: 2-vectors, where a numpy call costs more than the arithmetic
    (x0, y0), (x1, y1) = points[0].tolist(), points[-1].tolist()
    half = 0.5 * math.hypot(x1 - x0, y1 - y0)
    radius = min(max(half, min_radius), max_radius)
    mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    sx, sy = sensor.tolist()
    ox, oy = mx - sx, my - sy
    norm = math.hypot(ox, oy)
    ux, uy = (ox / norm, oy / norm) if norm > 0.0 else (1.0, 0.0)
    behind = math.sqrt(max(radius * radius - half * half, 0.0))
    cx, cy = mx + behind * ux, my + behind * uy
    var = sigma * sigma + radius * radius
    e = np.hypot(points[:, 0] - cx, points[:, 1] - cy) - radius
    rms = math.sqrt(float(e @ e) / len(points))
    return CircleFit(cx, cy, radius, (var, 0.0, var), rms, fallback=True)


def _circle_cov(jtj: list[list[float]], e2: float, n: int,
                sigma: float) -> tuple[float, float, float]:
    """Return the centre's covariance: the top-left 2x2 of s^2 (J^T J)^-1.

    s is the larger of the residual's and the noise's; infinite when J^T J is singular.
    """
    k = len(jtj)
    s2 = max(e2 / (n - k) if n > k else 0.0, sigma * sigma)
    m = jtj
    if k == 2:
        det = m[0][0] * m[1][1] - m[0][1] * m[1][0]
        i00, i01, i11 = m[1][1], -m[0][1], m[0][0]
    else:
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = m
        c00 = a11 * a22 - a12 * a21
        det = a00 * c00 + a01 * (a12 * a20 - a10 * a22) + a02 * (a10 * a21 - a11 * a20)
        i00, i01, i11 = c00, a02 * a21 - a01 * a22, a00 * a22 - a02 * a20
    if not abs(det) > 1e-300:
        return (math.inf, 0.0, math.inf)
    return s2 * i00 / det, s2 * i01 / det, s2 * i11 / det


def fit_circle(points: Vector, sensor: Vector, sigma: float, min_radius: float,
               max_radius: float) -> CircleFit:
    """Fit a circle to ``points`` seen from ``sensor`` (2,) with range noise ``sigma`` [m]."""
    mx, my = (points.sum(axis=0) / len(points)).tolist()
    return _fit_circle(points, kasa(points) if len(points) >= 3 else None, (mx, my), sensor,
                       sigma, min_radius, max_radius)


def _fit_circle(points: Vector, start: tuple[float, float, float] | None,
                mean: tuple[float, float], sensor: Vector, sigma: float, min_radius: float,
                max_radius: float) -> CircleFit:
    """:func:`fit_circle` from Kasa's circle ``start`` and the points' ``mean``."""
    n = len(points)
    sx, sy = sensor.tolist()
    sxy = (sx, sy)
    if start is not None:
        fit = refine_circle(points, *start)
        if fit is not None:
            cx, cy, radius, jtj, e2 = fit
            if radius < min_radius and _behind(cx, cy, mean, sxy):
                pass   # too small: refit below with the radius held at the minimum
            elif min_radius <= radius <= max_radius and _behind(cx, cy, mean, sxy):
                return CircleFit(cx, cy, radius, _circle_cov(jtj, e2, n, sigma),
                                 math.sqrt(e2 / n))
            else:
                return fallback_circle(points, sensor, sigma, min_radius, max_radius)
    if n >= 3:
        # Short arcs and tiny buoys: the radius held at its minimum, the centre fitted
        # behind the points (started there, so it stays on the far side).
        guess = fallback_circle(points, sensor, sigma, min_radius, min_radius)
        held = refine_circle(points, guess.x, guess.y, min_radius, fixed_radius=True)
        if held is not None and _behind(held[0], held[1], mean, sxy):
            cx, cy, _, jtj, e2 = held
            # The radius was assumed, not measured: the centre is not known better than it.
            xx, xy, yy = _circle_cov(jtj, e2, n, sigma)
            r2 = min_radius * min_radius
            return CircleFit(cx, cy, min_radius, (xx + r2, xy, yy + r2), math.sqrt(e2 / n))
    return fallback_circle(points, sensor, sigma, min_radius, max_radius)


# -- segments ------------------------------------------------------------------------------
def fit_line(points: Vector) -> tuple[tuple[float, float], tuple[float, float], float]:
    """Total least squares line: (a point on it, unit direction, sum of squared distances).

    From the points' sums about the first point (:func:`line_from_sums`), two numpy calls: a
    scan fits several lines to clusters of tens of points, where each numpy call costs more
    than its arithmetic.
    """
    o = points[0]
    p = points - o
    sx, sy = p.sum(axis=0).tolist()
    (sxx, sxy), (_, syy) = (p.T @ p).tolist()
    ox, oy = o.tolist()
    return line_from_sums(len(points), ox, oy, sx, sy, sxx, sxy, syy)


def line_from_sums(n: int, ox: float, oy: float, sx: float, sy: float, sxx: float,
                   sxy: float, syy: float
                   ) -> tuple[tuple[float, float], tuple[float, float], float]:
    """Return the total least squares line of :func:`fit_line` from its points' sums.

    The sums are over the n points p - o about a point o = (``ox``, ``oy``) (a cluster's first:
    small numbers, so the centred scatter below loses no digits): of x, y, x^2, x y, y^2. The
    line runs through the mean along the principal axis of the centred scatter C; its sum of
    squared distances is n^T C n with n the line's normal.
    """
    mx, my = sx / n, sy / n
    cxx, cxy, cyy = sxx - sx * mx, sxy - sx * my, syy - sy * my     # centred scatter
    theta = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)                   # the principal axis
    c, s = math.cos(theta), math.sin(theta)
    ss = s * s * cxx - 2.0 * s * c * cxy + c * c * cyy
    return (ox + mx, oy + my), (c, s), max(ss, 0.0)


def fit_segment(points: Vector) -> SegmentFit:
    """Fit a segment: the TLS line, ends the extreme projections of the points."""
    (mx, my), (c, s), ss = fit_line(points)
    t = points @ np.array((c, s))
    base = mx * c + my * s        # the projection of the line's point
    lo, hi = float(t.min()) - base, float(t.max()) - base
    return SegmentFit(mx + lo * c, my + lo * s, mx + hi * c, my + hi * s,
                      math.sqrt(ss / len(points)), len(points))


def split(points: Vector, threshold: float, min_points: int = 2) -> list[tuple[int, int]]:
    """Split and merge: ranges [start, end) of ``points`` that are each straight.

    A range is cut at its point furthest from its chord when that is more than
    ``threshold`` [m] away (the corner belongs to both sides, so they meet); neighbours
    whose union is straight within ``threshold`` merge again.
    """
    out: list[tuple[int, int]] = []
    todo = [(0, len(points))]
    while todo:
        start, end = todo.pop()
        if end - start < 2 * min_points - 1:
            out.append((start, end))
            continue
        (ax, ay), (bx, by) = points[start].tolist(), points[end - 1].tolist()
        dx, dy = bx - ax, by - ay
        norm = math.hypot(dx, dy)
        if norm > 0.0:   # |(p - a) x (b - a)| / |b - a|, the distance from the chord
            dist = np.abs(points[start:end] @ np.array((dy, -dx)) - (ax * dy - ay * dx))
            dist /= norm
        else:
            dist = np.hypot(points[start:end, 0] - ax, points[start:end, 1] - ay)
        k = int(np.argmax(dist))
        if (dist[k] > threshold and k + 1 >= min_points and end - start - k >= min_points):
            todo += [(start + k, end), (start, start + k + 1)]
        else:
            out.append((start, end))
    out.sort()
    merged = [out[0]]
    for start, end in out[1:]:
        s0, _ = merged[-1]
        union = points[s0:end]
        (mx, my), (c, s), _ = fit_line(union)
        side = union @ np.array((-s, c))    # signed distance from the line, plus a constant
        offset = -s * mx + c * my
        if max(float(side.max()) - offset, offset - float(side.min())) <= threshold:
            merged[-1] = (s0, end)
        else:
            merged.append((start, end))
    return merged


def fit_cluster(points: Vector, sensor: Vector, sigma: float,
                s: FitSettings) -> list[CircleFit | SegmentFit]:
    """Circle or segments for one cluster (module docstring); ``sigma`` the range noise [m]."""
    n = len(points)
    (x0, y0), (x1, y1) = points[0].tolist(), points[-1].tolist()
    extent = math.hypot(x1 - x0, y1 - y0)
    if n >= 3:
        (lx, ly), (hx, hy) = points.min(axis=0).tolist(), points.max(axis=0).tolist()
        extent = max(extent, hx - lx, hy - ly)
    if extent > 2.0 * s.max_radius:
        return _segments(points, sigma, s)
    circle = fit_circle(points, sensor, sigma, s.min_radius, s.max_radius)
    if n < 4 or extent < s.min_segment_length:
        return [circle]
    _, _, line_ss = fit_line(points)
    line_s2 = line_ss / (n - 2)
    circle_s2 = n * circle.rms * circle.rms / (n - 3)
    if not circle.fallback and circle_s2 < s.circle_ratio ** 2 * line_s2:
        return [circle]
    return _segments(points, sigma, s)


def _segments(points: Vector, sigma: float, s: FitSettings) -> list[CircleFit | SegmentFit]:
    ranges = split(points, s.split_distance + 3.0 * sigma)
    return [fit_segment(points[a:b]) for a, b in ranges if b - a >= 2]


# -- every cluster of a scan at once ---------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ClusterSums:
    """Sums over the points of every cluster of a scan, from one pass over all of them.

    The clusters lie one after the other in one array of points (ring order within each);
    cluster k holds ``count[k]`` points from ``start[k]``. The sums are about its first point
    (``origin[k]``), as :func:`line_from_sums` takes them. Arrays fresh per scan: ``eq=False``.
    """

    start: NDArray[np.intp]   # (K,) position of each cluster's first point
    count: NDArray[np.intp]   # (K,) points in each cluster
    origin: Vector            # (K, 2) each cluster's first point [m]
    last: Vector              # (K, 2) each cluster's last point minus its first [m]
    sums: Vector              # (K, 9) of x, y, x^2, x y, y^2, x^3, x^2 y, x y^2, y^3
    low: Vector               # (K, 2) the smallest x and y of each cluster [m]
    high: Vector              # (K, 2) the largest x and y of each cluster [m]
    chord: Vector             # (K,) largest distance of a point from its cluster's chord [m]


def cluster_sums(points: Vector, start: NDArray[np.intp]) -> ClusterSums:
    """Sum every cluster of ``points`` (N, 2) at once; cluster k runs from ``start[k]``.

    ``start`` begins with 0 and increases strictly (no empty cluster). ``chord`` is the
    distance from the line through a cluster's first and last point (split and merge's first
    test), infinite where those two points coincide (no chord: :func:`split` decides).
    """
    count = np.empty_like(start)   # np.diff's wrapper costs more than this subtraction
    count[:-1] = start[1:] - start[:-1]
    count[-1] = len(points) - start[-1]
    origin = points[start]
    rel = points - np.repeat(origin, count, axis=0)
    x, y = rel[:, 0], rel[:, 1]
    xx, xy, yy = x * x, x * y, y * y
    sums = np.add.reduceat(np.stack((x, y, xx, xy, yy, xx * x, xx * y, xy * y, yy * y)), start,
                           axis=1).T
    last = rel[start + count - 1]
    # |(p - a) x (b - a)|, the chord's length times the distance from it
    lx, ly = np.repeat(last, count, axis=0).T
    cross = np.maximum.reduceat(np.abs(x * ly - y * lx), start)
    norm = np.hypot(last[:, 0], last[:, 1])
    with np.errstate(divide='ignore', invalid='ignore'):
        chord = np.where(norm > 0.0, cross / norm, math.inf)
    return ClusterSums(start, count, origin, last, sums, np.minimum.reduceat(points, start),
                       np.maximum.reduceat(points, start), chord)


def fit_clusters(points: Vector, start: NDArray[np.intp], sensors: Vector,
                 sigmas: Sequence[float], s: FitSettings) -> list[CircleFit | SegmentFit]:
    """Return the shapes of :func:`fit_cluster` for every cluster of a scan, from one sum pass.

    ``points``, ``start`` as :func:`cluster_sums`; ``sensors`` (K, 2) and ``sigmas`` (K) each
    cluster's as :func:`fit_cluster` takes them. The same decisions on the same numbers, but
    the lines, extents and straightness of all clusters come from :class:`ClusterSums` (a few
    numpy calls per scan, not a dozen per cluster): a wall the chord test finds straight is
    one segment without :func:`split`; only a bent one, and circles, are fitted one by one.
    """
    c = cluster_sums(points, start)
    count = c.count.tolist()
    sums = c.sums.tolist()
    lines = [line_from_sums(n, ox, oy, *row[:5]) for n, (ox, oy), row
             in zip(count, c.origin.tolist(), sums)]
    # every cluster's points projected on its own line, the ends of a straight segment
    along = np.array([d for _, d, _ in lines]).repeat(count, axis=0)
    rel = points - np.repeat(c.origin, count, axis=0)
    t = rel[:, 0] * along[:, 0] + rel[:, 1] * along[:, 1]
    t_lo, t_hi = np.minimum.reduceat(t, start).tolist(), np.maximum.reduceat(t, start).tolist()
    shapes: list[CircleFit | SegmentFit] = []
    rows = zip(count, start.tolist(), c.origin.tolist(), c.last.tolist(), c.low.tolist(),
               c.high.tolist(), c.chord.tolist(), lines, t_lo, t_hi, sigmas)
    for k, (n, a, (ox, oy), (lx, ly), (xlo, ylo), (xhi, yhi), chord, line, lo, hi,
            sigma) in enumerate(rows):
        extent = math.hypot(lx, ly)
        if n >= 3:
            extent = max(extent, xhi - xlo, yhi - ylo)
        if extent <= 2.0 * s.max_radius:
            row = sums[k]
            mean = (ox + row[0] / n, oy + row[1] / n)
            circle = _fit_circle(points[a:a + n], kasa_from_sums(n, ox, oy, row), mean,
                                 sensors[k], sigma, s.min_radius, s.max_radius)
            if n < 4 or extent < s.min_segment_length:
                shapes.append(circle)
                continue
            line_s2 = line[2] / (n - 2)
            circle_s2 = n * circle.rms * circle.rms / (n - 3)
            if not circle.fallback and circle_s2 < s.circle_ratio ** 2 * line_s2:
                shapes.append(circle)
                continue
        if n >= 3 and not chord <= s.split_distance + 3.0 * sigma:
            shapes += _segments(points[a:a + n], sigma, s)   # bent: split and merge
        elif n >= 2:
            # straight (split would keep it whole): the segment of fit_segment, from the sums
            (mx, my), (dx, dy), ss = line
            base = (mx - ox) * dx + (my - oy) * dy
            lo, hi = lo - base, hi - base
            shapes.append(SegmentFit(mx + lo * dx, my + lo * dy, mx + hi * dx, my + hi * dy,
                                     math.sqrt(ss / n), n))
    return shapes
