"""A lidar scan as points: in the lidar's frame, then in the world through the pose estimate.

Pure numpy, no ROS. A ``sensor_msgs/LaserScan`` holds ranges [m] of rays counter-clockwise
from ``angle_min`` in steps of ``angle_increment`` [rad], with REP-117's non-finite values
(-inf too close, +inf no return, NaN no sample); only finite ranges become points. Ray i was
measured ``i * time_increment`` [s] after the scan's stamp, so each ray is put in the world
with the pose of its own time (the vessel turns while the lidar does: at a yaw rate of
0.5 rad/s one revolution of 0.18 s turns a point at 5 m by 0.45 m). A scan whose
``time_increment`` is 0 does not say when each ray was taken; for it :data:`SWEEPS` names how
the lidar turns (:func:`ray_offsets_ns`).

World: ENU ``odom``; pose eta = [x, y, psi] of ``base_link`` (Fossen 2021, ch. 2, REP-105).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
import functools
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.kinematics import ssa

Vector = NDArray[np.float64]

#: How the rays of a scan without ``time_increment`` were taken over its ``scan_time``:
#: ``clockwise_from_zero``: from the lidar's 0 deg mark (bearing 0), turning clockwise, as the
#: RPLidar turns and the ``rplidar`` plugin publishes (``enbarr_plugins/lidar/rplidar.py``);
#: ``at_stamp``: all at the scan's stamp.
SWEEPS = ('clockwise_from_zero', 'at_stamp')


@functools.lru_cache(maxsize=32)
def _array(values: tuple[float, ...]) -> Vector:
    """Return ``values`` as an array, made once per tuple (read only: it is shared)."""
    out = np.array(values, dtype=float)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class RangeNoise:
    """Range noise of a lidar: one standard deviation as a fraction of the range, by band.

    ``fractions[k]`` holds for ranges below ``limits[k]`` (and at or above the limit before);
    the last fraction beyond the last limit. The RPLidar A1 of the CS Saucer (manual, Table
    1.1): ``limits=(3.0, 5.0)``, ``fractions=(0.01, 0.02, 0.025)``.
    """

    limits: tuple[float, ...]      # [m], increasing
    fractions: tuple[float, ...]   # one more than limits, each in [0, 1)

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the bands do not hold together."""
        if len(self.fractions) != len(self.limits) + 1:
            raise ValueError(f'fractions: {len(self.fractions)} given for '
                             f'{len(self.limits)} limits: one more fraction than limits')
        if any(b <= a for a, b in zip(self.limits, self.limits[1:])) or any(
                a <= 0.0 for a in self.limits):
            raise ValueError(f'limits: {list(self.limits)} must be positive and increasing')
        if any(not 0.0 <= f < 1.0 for f in self.fractions):
            raise ValueError(f'fractions: {list(self.fractions)} must be in [0, 1)')

    def sigma(self, r: Vector) -> Vector:
        """Return the range standard deviation [m] at ranges ``r`` [m]."""
        band = np.searchsorted(_array(self.limits), r, side='right')
        out: Vector = _array(self.fractions)[band] * r
        return out

    def sigma_at(self, r: float) -> float:
        """Return the range standard deviation [m] at one range ``r`` [m] (as :meth:`sigma`)."""
        band = 0
        for limit in self.limits:
            if limit <= r:
                band += 1
        return self.fractions[band] * r


@dataclass(frozen=True, eq=False)
class ScanPoints:
    """The finite rays of one scan, in ring order (arrays fresh per scan: ``eq=False``)."""

    index: NDArray[np.intp]   # (N,) ray index in the scan
    r: Vector                 # (N,) range [m]
    laser: Vector             # (N, 2) point in the lidar's frame [m]
    rays: int                 # number of rays of the scan
    angle_increment: float    # [rad]

    @property
    def full_circle(self) -> bool:
        """Whether the rays go all the way round (the last ray neighbours the first)."""
        return abs(self.rays * self.angle_increment - 2.0 * math.pi) < 0.5 * abs(
            self.angle_increment)


@functools.lru_cache(maxsize=8)
def _ray_directions(angle_min: float, angle_increment: float, rays: int) -> Vector:
    """Return the unit vector of every ray (rays, 2), made once per scan geometry (shared)."""
    theta = angle_min + np.arange(rays) * angle_increment
    out = np.column_stack((np.cos(theta), np.sin(theta)))
    out.flags.writeable = False
    return out


def scan_points(ranges: Vector, angle_min: float, angle_increment: float) -> ScanPoints:
    """Return the finite rays of a scan as points in its frame (REP-117 values dropped)."""
    ranges = np.asarray(ranges, dtype=float)
    index = np.flatnonzero(np.isfinite(ranges))
    r = ranges[index]
    # a lidar's rays keep their angles from scan to scan: their directions are kept too
    laser = _ray_directions(float(angle_min), float(angle_increment), len(ranges))[index]
    laser *= r[:, None]
    return ScanPoints(index, r, laser, len(ranges), float(angle_increment))


def all_at_stamp(time_increment: float, scan_time: float, sweep: str) -> bool:
    """Whether :func:`ray_offsets_ns` puts every ray of such a scan at its stamp."""
    return time_increment == 0.0 and not (sweep == 'clockwise_from_zero' and scan_time > 0.0)


def ray_offsets_ns(index: NDArray[np.intp], angle_min: float, angle_increment: float,
                   time_increment: float, scan_time: float, sweep: str) -> NDArray[np.int64]:
    """Return when each ray ``index`` was taken after the scan's stamp [ns].

    ``time_increment`` [s] when the scan gives it (REP: ray i at i * time_increment);
    otherwise as ``sweep`` says (:data:`SWEEPS`) over ``scan_time`` [s].
    """
    if time_increment != 0.0:
        t = index * (time_increment * 1e9)
    elif not all_at_stamp(time_increment, scan_time, sweep):
        bearing = angle_min + index * angle_increment
        t = np.mod(-bearing, 2.0 * math.pi) * (scan_time * 1e9 / (2.0 * math.pi))
    else:
        t = np.zeros(len(index))
    out: NDArray[np.int64] = np.rint(t).astype(np.int64)
    return out


class PoseHistory:
    """The last poses of ``base_link`` in the world, to pose rays at their own time.

    ``add`` takes the estimate as it arrives (stamps increasing; an older or equal stamp is
    refused and ``False`` returned); ``at`` interpolates linearly between the two poses around
    each time asked (the heading unwrapped, so across +-pi too). A time is posed only when a
    pose lies within ``tolerance`` of it: between poses further apart the vessel's path is
    not known well enough, and a scan older or newer than the history is not posed at all.

    The poses are kept as Python numbers (``add`` runs once per estimate, on the control
    chain's thread, where numpy's per-call cost would be the whole cost); ``at`` makes arrays
    of the few poses around the times asked.
    """

    def __init__(self, capacity: int = 256) -> None:
        if capacity < 2:
            raise ValueError(f'capacity: {capacity} must be at least 2')
        self.capacity = capacity
        self._t: list[int] = []
        self._eta: list[tuple[float, float, float]] = []   # x, y, psi unwrapped

    def __len__(self) -> int:
        return len(self._t)

    def clear(self) -> None:
        """Forget every pose."""
        self._t.clear()
        self._eta.clear()

    def snapshot(self) -> PoseHistory:
        """Return a copy of the poses held (to read while this one takes new ones)."""
        out = PoseHistory(self.capacity)
        out._t = self._t[:]
        out._eta = self._eta[:]
        return out

    def add(self, stamp_ns: int, x: float, y: float, psi: float) -> bool:
        """Append a pose [m, m, rad] stamped ``stamp_ns``; False (ignored) when not newer."""
        t = self._t
        if t and stamp_ns <= t[-1]:
            return False
        if len(t) == 2 * self.capacity:   # keep the newest ``capacity`` (amortised)
            del t[:self.capacity]
            del self._eta[:self.capacity]
        if t:
            last = self._eta[-1][2]
            psi = last + ssa(psi - last)
        t.append(int(stamp_ns))
        self._eta.append((float(x), float(y), float(psi)))
        return True

    def at(self, stamps_ns: NDArray[np.int64], tolerance_ns: int) -> Vector | None:
        """Return the poses (N, 3) [m, m, rad] at ``stamps_ns``, or None when one is not posed.

        None when any time has no pose within ``tolerance_ns`` (see the class docstring).
        Within the tolerance beyond the first or last pose, that pose is held.
        """
        if not self._t:
            return None
        q = np.asarray(stamps_ns, dtype=np.int64)
        if len(q) == 0:
            return np.empty((0, 3))
        if len(q) == 1:   # one time (a scan taken at its stamp, a camera frame): in floats
            pose = self._at_one(int(q[0]), tolerance_ns)
            return None if pose is None else np.array((pose,))
        # only the poses around the times asked: the one before the first, after the last
        lo = max(bisect.bisect_left(self._t, int(q.min())) - 1, 0)
        hi = min(bisect.bisect_right(self._t, int(q.max())) + 1, len(self._t))
        t = np.array(self._t[lo:hi], dtype=np.int64)
        n = len(t)
        right = np.minimum(np.searchsorted(t, q), n - 1)
        left = np.maximum(right - 1, 0)
        near = np.minimum(np.abs(q - t[left]), np.abs(t[right] - q))
        if int(near.max()) > tolerance_ns:
            return None
        base = t[0]
        rel = (t - base).astype(float)
        qr = (q - base).astype(float)
        eta = np.array(self._eta[lo:hi])
        out = np.empty((len(q), 3))
        for k in range(3):
            out[:, k] = np.interp(qr, rel, eta[:, k])
        return out

    def _at_one(self, stamp_ns: int, tolerance_ns: int) -> tuple[float, float, float] | None:
        """Return :meth:`at` of one time as floats (the same interpolation as np.interp)."""
        t = self._t
        n = len(t)
        right = min(bisect.bisect_left(t, stamp_ns), n - 1)
        left = max(right - 1, 0)
        if min(abs(stamp_ns - t[left]), abs(t[right] - stamp_ns)) > tolerance_ns:
            return None
        if stamp_ns <= t[0]:
            return self._eta[0]
        if stamp_ns >= t[-1]:
            return self._eta[-1]
        # np.interp's formula, on times relative to the first pose as at() has them
        base = t[0]
        x0, x1 = float(t[left] - base), float(t[right] - base)
        w = (float(stamp_ns - base) - x0) / (x1 - x0)
        return tuple(a + w * (b - a) for a, b in  # type: ignore[return-value]
                     zip(self._eta[left], self._eta[right]))


def to_world(points: Vector, eta: Vector) -> Vector:
    """Points (N, 2) in ``base_link`` -> world, each with its pose ``eta`` (N, 3) or (3,)."""
    eta = np.asarray(eta, dtype=float)
    c, s = np.cos(eta[..., 2]), np.sin(eta[..., 2])
    out = np.empty_like(points)
    out[:, 0] = eta[..., 0] + c * points[:, 0] - s * points[:, 1]
    out[:, 1] = eta[..., 1] + s * points[:, 0] + c * points[:, 1]
    return out
