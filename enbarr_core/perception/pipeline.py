"""From one lidar scan to tracked obstacles: points, clusters, shapes, tracks.

Pure (no ROS): the node (``scan_obstacles_node``) hands the scan's arrays, the lidar's pose
on the vessel and the history of the vessel's pose; this returns the confirmed obstacles in the
world frame. Each step is its own module: ``scan_geometry`` (points, posing), ``segmentation``
(adaptive breakpoints), ``fitting`` (circle or segments), ``tracking`` (Kalman filters,
assignment).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import functools
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_interfaces.obstacles import Obstacle

from enbarr_core.perception.fitting import CircleFit, fit_clusters, FitSettings, SegmentFit
from enbarr_core.perception.scan_geometry import (all_at_stamp, PoseHistory, ray_offsets_ns,
                                                  scan_points, SWEEPS, to_world)
from enbarr_core.perception.segmentation import BreakpointSettings, clusters
from enbarr_core.perception.tracking import Tracker, TrackerSettings

Vector = NDArray[np.float64]


@dataclass(frozen=True)
class PerceptionSettings:
    """Everything the pipeline is tuned by (see each step's module)."""

    breakpoints: BreakpointSettings
    min_cluster_points: int     # a cluster of fewer points is dropped (a stray return)
    fit: FitSettings
    tracker: TrackerSettings
    pose_tolerance_ns: int      # a ray is posed only within this of a pose [ns]
    sweep: str                  # scans without time_increment: scan_geometry.SWEEPS

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the settings do not hold together."""
        self.breakpoints.validate()
        if self.min_cluster_points < 1:
            raise ValueError(f'min_cluster_points: {self.min_cluster_points} must be >= 1')
        self.fit.validate()
        self.tracker.validate()
        if self.pose_tolerance_ns <= 0:
            raise ValueError(f'pose_tolerance_ns: {self.pose_tolerance_ns} must be > 0')
        if self.sweep not in SWEEPS:
            raise ValueError(f'sweep: {self.sweep!r} is not one of {", ".join(SWEEPS)}')


@dataclass(frozen=True)
class ScanOutcome:
    """What one scan gave: the confirmed obstacles and the counts behind them."""

    obstacles: list[Obstacle]
    posed: bool       # False: no pose near the scan's stamp, nothing was measured
    points: int       # finite rays
    clusters: int     # clusters kept (at least min_cluster_points)
    circles: int      # circles measured
    segments: int     # segments measured


@dataclass(frozen=True, eq=False)
class LidarMount:
    """Where the lidar sits in ``base_link``: p_base = R p_laser + t, projected on the plane."""

    rotation: Vector      # (3, 3)
    translation: Vector   # (3,)

    def to_base(self, laser: Vector) -> Vector:
        """Points (N, 2) in the lidar's plane -> (N, 2) in ``base_link``'s plane [m]."""
        out: Vector = laser @ self.rotation[:2, :2].T + self.translation[:2]
        return out

    def to_world(self, laser: Vector, eta: Sequence[float]) -> Vector:
        """Points (N, 2) in the lidar's plane -> the world, all with one pose ``eta`` [x, y, psi].

        :func:`to_world` of :meth:`to_base` composed into one affine map: p_w = A p + b with
        A = R(psi) M and b = R(psi) t + (x, y) (M, t: the mount's plane part).
        """
        x, y, psi = eta
        c, s = math.cos(psi), math.sin(psi)
        (m00, m01), (m10, m11) = self.rotation[:2, :2].tolist()
        a = np.array(((c * m00 - s * m10, c * m01 - s * m11),
                      (s * m00 + c * m10, s * m01 + c * m11)))
        out: Vector = laser @ a.T + self.origin(x, y, psi)
        return out

    @functools.cached_property
    def _plane_translation(self) -> tuple[float, float]:
        tx, ty = self.translation[:2].tolist()
        return tx, ty

    def origin(self, x: float, y: float, psi: float) -> tuple[float, float]:
        """Return where the lidar is in the world [m] with ``base_link`` at (x, y, psi)."""
        tx, ty = self._plane_translation
        c, s = math.cos(psi), math.sin(psi)
        return x + c * tx - s * ty, y + s * tx + c * ty


class ScanObstacles:
    """The pipeline, with its tracks between scans. ``settings`` may be swapped live."""

    def __init__(self, settings: PerceptionSettings) -> None:
        settings.validate()
        self._settings = settings
        self.tracker = Tracker(settings.tracker)

    @property
    def settings(self) -> PerceptionSettings:
        """Return the settings in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: PerceptionSettings) -> None:
        settings.validate()
        self._settings = settings
        self.tracker.settings = settings.tracker   # the tracks are kept

    def measure(self, ranges: Vector, angle_min: float, angle_increment: float,
                time_increment: float, stamp_ns: int, mount: LidarMount,
                poses: PoseHistory, scan_time: float = 0.0
                ) -> tuple[list[CircleFit | SegmentFit], int, int] | None:
        """Return the shapes one scan measures in the world, with counts of points and clusters.

        None when the scan cannot be posed (no pose within the tolerance of one of its rays).
        """
        s = self._settings
        scan = scan_points(ranges, angle_min, angle_increment)
        if len(scan.r) == 0 or all_at_stamp(time_increment, scan_time, s.sweep):
            ray_times = np.array([stamp_ns], dtype=np.int64)
        else:
            offsets = ray_offsets_ns(scan.index, angle_min, angle_increment, time_increment,
                                     scan_time, s.sweep)
            # every ray at the stamp (no time_increment, at_stamp): one pose serves them all
            ray_times = stamp_ns + (offsets if offsets.any() else offsets[:1])
        eta = poses.at(ray_times, s.pose_tolerance_ns)
        if eta is None:
            return None
        if len(scan.r) == 0:
            return [], 0, 0
        if len(eta) == 1:   # every ray at one pose: the mount and the pose are one transform
            world = mount.to_world(scan.laser, eta[0].tolist())
        else:
            world = to_world(mount.to_base(scan.laser), eta)
        pieces = [c for c in clusters(scan, s.breakpoints) if len(c) >= s.min_cluster_points]
        if not pieces:
            return [], len(scan.r), 0
        # Where the lidar was and its range noise, at each kept cluster's middle ray only: in
        # floats, the few clusters of a scan cost less than arrays over all its rays.
        noise = s.breakpoints.noise
        last = len(eta) - 1
        mids = [int(c[len(c) // 2]) for c in pieces]
        # one read of the poses and ranges at the middle rays (an index each costs a call)
        poses_at = eta[[min(m, last) for m in mids]].tolist()
        ranges_at = scan.r[mids].tolist()
        sensors, sigmas, start, n = [], [], [], 0
        for c, (x, y, psi), r in zip(pieces, poses_at, ranges_at):
            sensors.append(mount.origin(x, y, psi))
            sigmas.append(noise.sigma_at(r))
            start.append(n)
            n += len(c)
        # the clusters one after the other (ring order within each) for one pass of sums
        ordered = world[pieces[0] if len(pieces) == 1 else np.concatenate(pieces)]
        shapes = fit_clusters(ordered, np.array(start, dtype=np.intp), np.array(sensors),
                              sigmas, s.fit)
        return shapes, len(scan.r), len(pieces)

    def process(self, ranges: Vector, angle_min: float, angle_increment: float,
                time_increment: float, stamp_ns: int, mount: LidarMount,
                poses: PoseHistory, scan_time: float = 0.0) -> ScanOutcome:
        """Measure one scan (``measure``) and update the tracks; the confirmed obstacles.

        A scan that cannot be posed changes no track (its obstacles are the last ones).
        """
        measured = self.measure(ranges, angle_min, angle_increment, time_increment, stamp_ns,
                                mount, poses, scan_time)
        if measured is None:
            return ScanOutcome(self.tracker.obstacles(), False, 0, 0, 0, 0)
        shapes, points, kept = measured
        circles = [z for z in shapes if isinstance(z, CircleFit)]
        segments = [z for z in shapes if isinstance(z, SegmentFit)]
        self.tracker.update(circles, segments, stamp_ns)
        return ScanOutcome(self.tracker.obstacles(), True, points, kept, len(circles),
                           len(segments))
