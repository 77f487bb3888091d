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

from dataclasses import dataclass
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
        band = np.searchsorted(np.asarray(self.limits), r, side='right')
        out: Vector = np.asarray(self.fractions)[band] * r
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


def scan_points(ranges: Vector, angle_min: float, angle_increment: float) -> ScanPoints:
    """Return the finite rays of a scan as points in its frame (REP-117 values dropped)."""
    ranges = np.asarray(ranges, dtype=float)
    index = np.flatnonzero(np.isfinite(ranges))
    r = ranges[index]
    theta = angle_min + index * angle_increment
    laser = np.empty((len(index), 2))
    laser[:, 0] = r * np.cos(theta)
    laser[:, 1] = r * np.sin(theta)
    return ScanPoints(index, r, laser, len(ranges), float(angle_increment))


def ray_offsets_ns(index: NDArray[np.intp], angle_min: float, angle_increment: float,
                   time_increment: float, scan_time: float, sweep: str) -> NDArray[np.int64]:
    """Return when each ray ``index`` was taken after the scan's stamp [ns].

    ``time_increment`` [s] when the scan gives it (REP: ray i at i * time_increment);
    otherwise as ``sweep`` says (:data:`SWEEPS`) over ``scan_time`` [s].
    """
    if time_increment != 0.0:
        t = index * (time_increment * 1e9)
    elif sweep == 'clockwise_from_zero' and scan_time > 0.0:
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
    """

    def __init__(self, capacity: int = 256) -> None:
        if capacity < 2:
            raise ValueError(f'capacity: {capacity} must be at least 2')
        self.capacity = capacity
        self._t = np.zeros(2 * capacity, dtype=np.int64)
        self._eta = np.zeros((2 * capacity, 3))   # x, y, psi unwrapped
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def clear(self) -> None:
        """Forget every pose."""
        self._n = 0

    def snapshot(self) -> PoseHistory:
        """Return a copy of the poses held (to read while this one takes new ones)."""
        out = PoseHistory(self.capacity)
        n = self._n
        out._t[:n] = self._t[:n]
        out._eta[:n] = self._eta[:n]
        out._n = n
        return out

    def add(self, stamp_ns: int, x: float, y: float, psi: float) -> bool:
        """Append a pose [m, m, rad] stamped ``stamp_ns``; False (ignored) when not newer."""
        n = self._n
        if n and stamp_ns <= self._t[n - 1]:
            return False
        if n == len(self._t):   # full: keep the newest ``capacity`` (amortised copy)
            keep = self.capacity
            self._t[:keep] = self._t[n - keep:n]
            self._eta[:keep] = self._eta[n - keep:n]
            n = keep
        if n:
            psi = float(self._eta[n - 1, 2]) + ssa(psi - float(self._eta[n - 1, 2]))
        self._t[n] = stamp_ns
        self._eta[n] = (x, y, psi)
        self._n = n + 1
        return True

    def at(self, stamps_ns: NDArray[np.int64], tolerance_ns: int) -> Vector | None:
        """Return the poses (N, 3) [m, m, rad] at ``stamps_ns``, or None when one is not posed.

        None when any time has no pose within ``tolerance_ns`` (see the class docstring).
        Within the tolerance beyond the first or last pose, that pose is held.
        """
        n = self._n
        if n == 0:
            return None
        t = self._t[:n]
        q = np.asarray(stamps_ns, dtype=np.int64)
        right = np.searchsorted(t, q).clip(0, n - 1)
        left = (right - 1).clip(0, n - 1)
        near = np.minimum(np.abs(q - t[left]), np.abs(t[right] - q))
        if len(q) and int(near.max()) > tolerance_ns:
            return None
        base = t[0]
        rel = (t - base).astype(float)
        qr = (q - base).astype(float)
        eta = self._eta[:n]
        out = np.empty((len(q), 3))
        for k in range(3):
            out[:, k] = np.interp(qr, rel, eta[:, k])
        return out


def to_world(points: Vector, eta: Vector) -> Vector:
    """Points (N, 2) in ``base_link`` -> world, each with its pose ``eta`` (N, 3) or (3,)."""
    eta = np.asarray(eta, dtype=float)
    c, s = np.cos(eta[..., 2]), np.sin(eta[..., 2])
    out = np.empty_like(points)
    out[:, 0] = eta[..., 0] + c * points[:, 0] - s * points[:, 1]
    out[:, 1] = eta[..., 1] + s * points[:, 0] + c * points[:, 1]
    return out
