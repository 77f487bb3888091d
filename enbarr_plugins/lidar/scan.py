"""One lidar revolution: its samples collected, then binned into the rays of a ``LaserScan``.

Pure numpy, no ROS: the driver calls it with what the protocol decoder cut.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


def bearing(angle_deg: np.ndarray) -> np.ndarray:
    """Return the bearings [rad] in the lidar's frame of its clockwise angles [deg].

    Counter-clockwise about the lidar's z from its 0 deg mark, in [-pi, pi).
    """
    theta = np.radians(np.asarray(angle_deg, dtype=float))
    return (math.pi - theta) % (2.0 * math.pi) - math.pi


def bin_revolution(angle_deg: np.ndarray, distance_mm: np.ndarray, bins: int,
                   range_min: float, range_max: float) -> np.ndarray:
    """Ranges [m] of ``bins`` rays from -pi, counter-clockwise, in the lidar's own frame.

    The lidar's frame (``laser``): x along its 0 deg mark, z up from its base, so that its
    clockwise angles are counter-clockwise bearings with the sign turned (REP-103). Each
    sample goes to the ray nearest its bearing. What a ray holds follows REP-117
    ("Informational Distance Measurements"): the nearest return within
    [``range_min``, ``range_max``] [m]; else -inf if a return came too close to measure;
    else +inf if nothing returned (distance 0, the protocol's invalid measurement, read as
    no return as the ROS drivers do) or only beyond ``range_max``; NaN where no sample
    fell (or only erroneous ones, NaN distances). A return outside the range is never
    the nearest.
    """
    r = np.asarray(distance_mm, dtype=float) * 1e-3
    inc = 2.0 * math.pi / bins
    idx = np.rint((bearing(angle_deg) + math.pi) / inc).astype(np.int64) % bins
    valid = (r >= range_min) & (r <= range_max)
    too_close = (r > 0.0) & (r < range_min)
    no_return = (r == 0.0) | (r > range_max)
    ranges = np.full(bins, np.inf)
    np.minimum.at(ranges, idx[valid], r[valid])
    measured = np.zeros(bins, dtype=bool)
    measured[idx[valid]] = True
    close = np.zeros(bins, dtype=bool)
    close[idx[too_close]] = True
    empty = np.ones(bins, dtype=bool)
    empty[idx[valid | too_close | no_return]] = False
    ranges[~measured & close] = -np.inf
    ranges[empty] = np.nan
    return ranges


class RevolutionAssembler:
    """Collects samples into revolutions; ``add`` returns the finished ones.

    The lidar turns one way: within a revolution the angles increase, and a new revolution
    begins where the angle falls back (the 360 -> 0 deg wrap), which is where the lidar sets
    the start flag (the protocol document: a new 360 deg scan). A start flag elsewhere is
    no start (a stream out of step passed a bogus one; counted in ``false_starts``); a wrap
    without one still is (its sample was lost; ``missed_starts``). So the angles of every
    revolution increase, and a revolution is never split in two.

    Samples before the first start are dropped (a partial revolution), as the SDK does;
    samples at angles of 360 deg or more are dropped (``invalid``); a revolution of fewer
    than ``min_samples`` samples (most of it lost) or more than ``max_samples`` is dropped
    (``dropped``).
    """

    class Revolution(NamedTuple):
        """One revolution: its start stamp [ns], duration [s], angles [deg], distances."""

        stamp_ns: int
        duration: float
        angle_deg: np.ndarray
        distance_mm: np.ndarray

    def __init__(self, min_samples: int = 50, max_samples: int = 8000) -> None:
        self.min_samples = min_samples
        self.max_samples = max_samples
        self.dropped = 0
        self.false_starts = 0
        self.missed_starts = 0
        self.invalid = 0
        self._stamp: int | None = None
        self._last = math.nan          # angle of the last sample [deg], nan: none yet
        self._angles: list[np.ndarray] = []
        self._dists: list[np.ndarray] = []
        self._count = 0

    def add(self, start: np.ndarray, angle_deg: np.ndarray, distance_mm: np.ndarray,
            stamp_ns: int, period_ns: int = 0) -> list[RevolutionAssembler.Revolution]:
        """Take the samples of one read; the last was read at ``stamp_ns``.

        Sample k of m is taken ``(m - 1 - k) * period_ns`` earlier (the lidar's sample
        period), which dates a revolution's first sample within a read.
        """
        start = np.asarray(start, dtype=bool)
        angle_deg = np.asarray(angle_deg, dtype=float)
        distance_mm = np.asarray(distance_mm, dtype=float)
        ok = angle_deg < 360.0
        if not ok.all():
            self.invalid += int((~ok).sum())
            start, angle_deg, distance_mm = start[ok], angle_deg[ok], distance_mm[ok]
        m = len(angle_deg)
        if not m:
            return []
        before = np.empty(m)
        before[0] = self._last
        before[1:] = angle_deg[:-1]
        wrap = angle_deg <= before            # False against nan: the very first sample
        first = np.isnan(before)
        begins = wrap | (first & start)       # a stream starts: its start flag counts
        self.false_starts += int((start & ~begins).sum())
        self.missed_starts += int((wrap & ~start).sum())
        self._last = float(angle_deg[-1])
        out = []
        pos = 0
        for k in np.flatnonzero(begins):
            t = stamp_ns - (m - 1 - int(k)) * period_ns
            if self._stamp is not None:
                self._append(angle_deg[pos:k], distance_mm[pos:k])
                if self._count < self.min_samples:
                    self.dropped += 1
                else:
                    out.append(self.Revolution(
                        self._stamp, max(0.0, (t - self._stamp) * 1e-9),
                        np.concatenate(self._angles), np.concatenate(self._dists)))
            self._stamp = t
            self._angles, self._dists, self._count = [], [], 0
            pos = int(k)
        if self._stamp is not None:
            self._append(angle_deg[pos:], distance_mm[pos:])
        return out

    def reset(self) -> None:
        """Forget the revolution in progress (a new stream starts); the counters stay."""
        self._stamp = None
        self._last = math.nan
        self._angles, self._dists, self._count = [], [], 0

    def _append(self, a: np.ndarray, d: np.ndarray) -> None:
        if not len(a):
            return
        self._angles.append(a)
        self._dists.append(d)
        self._count += len(a)
        if self._count > self.max_samples:
            self.dropped += 1
            self._stamp = None
            self._angles, self._dists, self._count = [], [], 0
