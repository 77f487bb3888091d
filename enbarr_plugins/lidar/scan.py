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


def bin_revolution(angle_deg: np.ndarray, distance_mm: np.ndarray, bins: int) -> np.ndarray:
    """Ranges [m] of ``bins`` rays from -pi, counter-clockwise, in the lidar's own frame.

    The lidar's frame (``laser``): x along its 0 deg mark, z up from its base, so that its
    clockwise angles are counter-clockwise bearings with the sign turned (REP-103). Each
    return goes to the ray nearest its bearing; the nearest return of a ray wins; inf where
    none.
    """
    r = np.asarray(distance_mm, dtype=float) * 1e-3
    valid = r > 0.0
    inc = 2.0 * math.pi / bins
    phi = bearing(np.asarray(angle_deg, dtype=float)[valid])
    idx = np.rint((phi + math.pi) / inc).astype(np.int64) % bins
    ranges = np.full(bins, np.inf)
    np.minimum.at(ranges, idx, r[valid])
    return ranges


class RevolutionAssembler:
    """Collects samples between start flags; ``add`` returns finished revolutions.

    Samples before the first start flag are dropped (a partial revolution), as the SDK does.
    The protocol has no checksum, so a stream out of step can pass bogus samples with start
    flags: a start flag less than ``min_samples`` after the last one is ignored and counted
    (``false_starts``), samples at angles of 360 deg or more are dropped (``invalid``), and a
    revolution longer than ``max_samples`` (start flags lost) is dropped (``dropped``).
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
        self.invalid = 0
        self._stamp: int | None = None
        self._angles: list[np.ndarray] = []
        self._dists: list[np.ndarray] = []
        self._count = 0

    def add(self, start: np.ndarray, angle_deg: np.ndarray, distance_mm: np.ndarray,
            stamp_ns: int, period_ns: int = 0) -> list[RevolutionAssembler.Revolution]:
        """Take the samples of one read; the last was read at ``stamp_ns``.

        Sample k of m is taken ``(m - 1 - k) * period_ns`` earlier (the lidar's sample
        period), which dates a revolution's first sample within a read.
        """
        ok = angle_deg < 360.0
        if not ok.all():
            self.invalid += int((~ok).sum())
            start, angle_deg, distance_mm = start[ok], angle_deg[ok], distance_mm[ok]
        out = []
        pos = 0
        m = len(start)
        for k in np.flatnonzero(start):
            t = stamp_ns - (m - 1 - int(k)) * period_ns
            if self._stamp is not None:
                if self._count + (k - pos) < self.min_samples:
                    self.false_starts += 1
                    continue
                self._append(angle_deg[pos:k], distance_mm[pos:k])
                if self._stamp is not None:
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

