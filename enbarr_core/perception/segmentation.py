"""Cutting a scan into clusters: the adaptive breakpoint detector, in ring order.

Borges and Aldon 2004 ("Line extraction in 2D range images for mobile robotics", J. Intell.
Robot. Syst. 40): two consecutive points of one surface are at most

    D_max = r_{n-1} sin(dphi) / sin(lambda - dphi) + 3 sigma_r

apart, where dphi is the angle between their rays, lambda the shallowest incidence at which a
surface still counts as one (a surface seen more obliquely is cut there), and sigma_r the range
noise at r_{n-1}. Points further apart start a new cluster. Rays without a finite range (REP-117:
no sample, no return, too close) are gaps: the points on either side are compared across the
gap's angle (a dark spot on a wall does not cut it), unless more than ``max_gap`` rays are
missing or the angle reaches lambda. A scan that goes all the way round joins its last cluster
to its first when the seam is no breakpoint (a buoy straight astern of a lidar whose rays
start at -pi).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_core.perception.scan_geometry import RangeNoise, ScanPoints

Vector = NDArray[np.float64]


@dataclass(frozen=True)
class BreakpointSettings:
    """Settings of :func:`clusters`."""

    lam: float          # lambda: the shallowest incidence of one surface [rad], (0, pi/2]
    max_gap: int        # rays without a finite range bridged between two points (>= 0)
    noise: RangeNoise   # sigma_r

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the settings do not hold together."""
        if not 0.0 < self.lam <= 0.5 * math.pi:
            raise ValueError(f'lam: {self.lam} rad must be in (0, pi/2]')
        if self.max_gap < 0:
            raise ValueError(f'max_gap: {self.max_gap} must be >= 0')
        self.noise.validate()


def breakpoint_distance(r_prev: Vector, dphi: Vector | float, lam: float,
                        sigma_r: Vector) -> Vector:
    """Return D_max [m] (module docstring); -1 where ``dphi`` >= lambda (always a break).

    ``dphi`` one angle for every pair (a float: no ray missing) or one per pair.
    """
    if isinstance(dphi, float):   # the usual scan: the two sines are numbers
        if not dphi < lam:
            return np.full(np.shape(r_prev), -1.0)
        one: Vector = r_prev * math.sin(dphi) / math.sin(lam - dphi) + 3.0 * sigma_r
        return one
    ok = dphi < lam
    if ok.all():   # no ray missing more than lambda: the common case, without the masks
        d: Vector = r_prev * np.sin(dphi) / np.sin(lam - dphi) + 3.0 * sigma_r
        return d
    out: Vector = np.full(np.shape(r_prev), -1.0)
    out[ok] = (r_prev[ok] * np.sin(dphi[ok]) / np.sin(lam - dphi[ok]) + 3.0 * sigma_r[ok])
    return out


def _breaks(r_prev: Vector, gap: NDArray[np.intp], d: Vector, increment: float,
            s: BreakpointSettings) -> NDArray[np.bool_]:
    """Whether each consecutive pair is a breakpoint; ``gap``: rays between them, + 1."""
    if int(gap.max()) == 1:   # no ray missing: one angle, and no gap exceeds max_gap
        within: NDArray[np.bool_] = d > breakpoint_distance(
            r_prev, float(abs(increment)), s.lam, s.noise.sigma(r_prev))
        return within
    dphi = gap.astype(np.float64) * abs(increment)
    dmax = breakpoint_distance(r_prev, dphi, s.lam, s.noise.sigma(r_prev))
    out = (gap > s.max_gap + 1) | (d > dmax)
    return out


def clusters(scan: ScanPoints, s: BreakpointSettings) -> list[NDArray[np.intp]]:
    """Return the clusters of ``scan`` as positions into its arrays, each in ring order."""
    n = len(scan.r)
    if n == 0:
        return []
    if n == 1:
        return [np.zeros(1, dtype=np.intp)]
    gap = scan.index[1:] - scan.index[:-1]
    step = scan.laser[1:] - scan.laser[:-1]
    d = np.hypot(step[:, 0], step[:, 1])
    cut = np.flatnonzero(_breaks(scan.r[:-1], gap, d, scan.angle_increment, s)) + 1
    # slices of one arange: np.split makes the same views at a higher cost per piece
    every = np.arange(n, dtype=np.intp)
    bounds = [0, *cut.tolist(), n]
    pieces = [every[a:b] for a, b in zip(bounds, bounds[1:])]
    if scan.full_circle and len(pieces) > 1:
        seam_gap = scan.rays - int(scan.index[-1]) + int(scan.index[0])
        (x0, y0), (x1, y1) = scan.laser[0].tolist(), scan.laser[-1].tolist()
        if not _break(float(scan.r[-1]), seam_gap, math.hypot(x0 - x1, y0 - y1),
                      scan.angle_increment, s):
            pieces[0] = np.concatenate((pieces[-1], pieces[0]))
            pieces.pop()
    return pieces


def _break(r_prev: float, gap: int, d: float, increment: float, s: BreakpointSettings) -> bool:
    """:func:`_breaks` for one pair, in floats (the seam of a full circle)."""
    dphi = gap * abs(increment)
    if gap > s.max_gap + 1 or not dphi < s.lam:
        return True
    return d > r_prev * math.sin(dphi) / math.sin(s.lam - dphi) + 3.0 * s.noise.sigma_at(r_prev)
