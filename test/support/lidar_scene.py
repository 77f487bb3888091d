"""Synthetic lidar scans of a known layout, computed here and nowhere else.

Tests of the perception build their scans from geometry written in this file (ray-circle and
ray-segment intersections), not from the code under test or a simulator, with a seeded noise
of the CS Saucer manual's figures (Table 1.1, RPLidar A1: 360 samples per revolution, 0.15 to
12 m, range noise 1 % below 3 m, 2 % from 3 to 5 m, 2.5 % beyond), read as one standard
deviation. REP-117 values as the driver writes them: +inf no return, -inf too close.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

# The manual's figures, typed from Table 1.1 (not read from the code under test).
RAYS = 360
RANGE_MIN = 0.15
RANGE_MAX = 12.0
NOISE_LIMITS = (3.0, 5.0)
NOISE_FRACTIONS = (0.01, 0.02, 0.025)


@dataclass(frozen=True)
class Circle:
    x: float
    y: float
    r: float


@dataclass(frozen=True)
class Wall:
    x1: float
    y1: float
    x2: float
    y2: float


def noise_fraction(r: np.ndarray) -> np.ndarray:
    return np.where(r < 3.0, 0.01, np.where(r < 5.0, 0.02, 0.025))


def ray_circle(o: np.ndarray, d: np.ndarray, c: Circle) -> np.ndarray:
    """Distance along each unit ray d (N, 2) from o (N, 2) to circle c (inf: no hit)."""
    oc = o - (c.x, c.y)
    b = (d * oc).sum(axis=1)
    disc = b * b - ((oc * oc).sum(axis=1) - c.r * c.r)
    t = np.full(len(d), np.inf)
    hit = disc >= 0.0
    near = -b[hit] - np.sqrt(disc[hit])
    t[hit] = np.where(near > 0.0, near, np.inf)
    return t


def ray_wall(o: np.ndarray, d: np.ndarray, w: Wall) -> np.ndarray:
    """Distance along each ray to wall w: o + t d = a + s (b - a), 0 <= s <= 1, t > 0."""
    a = np.array([w.x1, w.y1])
    e = np.array([w.x2, w.y2]) - a
    den = d[:, 0] * e[1] - d[:, 1] * e[0]
    ao = a - o
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (ao[:, 0] * e[1] - ao[:, 1] * e[0]) / den
        s = (ao[:, 0] * d[:, 1] - ao[:, 1] * d[:, 0]) / den
    ok = (np.abs(den) > 1e-12) & (t > 0.0) & (s >= 0.0) & (s <= 1.0)
    return np.where(ok, t, np.inf)


def cast(x: float, y: float, psi: float, circles=(), walls=(), seed: int | None = 0,
         rays: int = RAYS, angle_min: float = -math.pi, noise: bool = True) -> np.ndarray:
    """Ranges of a lidar at (x, y) heading psi [rad] in the world, rays from angle_min CCW."""
    theta = angle_min + np.arange(rays) * (2.0 * math.pi / rays)
    d = np.column_stack((np.cos(theta + psi), np.sin(theta + psi)))
    o = np.tile([x, y], (rays, 1))
    t = np.full(rays, np.inf)
    for c in circles:
        t = np.minimum(t, ray_circle(o, d, c))
    for w in walls:
        t = np.minimum(t, ray_wall(o, d, w))
    if noise:
        rng = np.random.default_rng(seed)
        finite = np.isfinite(t)
        t[finite] *= 1.0 + noise_fraction(t[finite]) * rng.standard_normal(finite.sum())
    t[t > RANGE_MAX] = np.inf
    t[t < RANGE_MIN] = -np.inf
    return t
