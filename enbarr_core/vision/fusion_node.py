"""Fusion node: the lidar's tracked obstacles with the classes of the camera's detections.

``obstacles`` + ``detections`` + ``camera/camera_info`` + ``observer/odometry`` ->
``obstacles/fused`` (the encoding of ``enbarr_interfaces.obstacles``, with its class fields),
so that the collision avoidance reads it unchanged (a profile remaps the guidance's
``obstacles`` to ``obstacles/fused``: ``params/saucer_fusion_sim.yaml``).

At each ``detections`` message the latest obstacles are projected into that image and paired
with its boxes (``enbarr_core.vision.fusion``): the vessel's pose at the image's stamp from
the last poses of ``observer/odometry`` (kept and interpolated as ``scan_obstacles`` does),
the camera's extrinsics from the profile's frame tree (``base_link`` -> the detections'
``header.frame_id``), its intrinsics (K, D, size) from the latest ``camera_info``. Each match
is a vote for its class on the obstacle's track id (``fusion.ClassMemory``).

At each ``obstacles`` message every obstacle is republished on ``obstacles/fused`` under the
scan's stamp, those whose track has votes with their class: the avoidance keeps the lidar's
rate and freshness, and loses nothing when the camera or the detector stops (the obstacles
then simply carry the classes they had). A detection matched to no obstacle is counted, never
made an obstacle (one camera gives no range).

A detections message is not matched (counted as stale) when there is no ``camera_info`` yet,
no obstacles message or one older than ``max_age`` before the image, no pose within
``pose_tolerance`` of the image's stamp, or a frame the tree does not have. ``/diagnostics``
(every second) counts them, the matches and unmatched detections; DEGRADED while detections
went unmatched as stale in the last second. Parameters (all live): see ``SPECS``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import threading
import time
from typing import Any

import numpy as np
from sensor_msgs.msg import CameraInfo, PointCloud2

from enbarr_core.framework.errors import FrameError
from enbarr_core.framework.health import DEGRADED, OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.perception.scan_geometry import PoseHistory
from enbarr_core.vision.fusion import Camera, ClassMemory, detected_boxes, fuse, FusionSettings
from enbarr_interfaces import convert, topics
from enbarr_interfaces.detections import DetectionEncodingError
from enbarr_interfaces.detections import from_cloud as detections_from_cloud
from enbarr_interfaces.obstacles import (
    cloud_stamp_ns, from_cloud, Obstacle, ObstacleEncodingError, to_cloud)

SPECS = [
    ParamSpec('object_height', 0.5, 'Height above the waterline of the cylinder each circle '
              'obstacle is projected as (the world default buoy: 0.5 m)', 'm', 0.01, 10.0),
    ParamSpec('min_iou', 0.1, 'Gate: least intersection over union of a projected box and a '
              'detection box to pair them', '', 0.01, 1.0),
    ParamSpec('min_depth', 0.1, 'An obstacle with a point nearer than this in front of the '
              'camera (or behind it) is not projected', 'm', 0.01, 10.0),
    ParamSpec('max_age', 0.5, 'Obstacles older than this before an image are not matched '
              'with it', 's', 0.01, 10.0),
    ParamSpec('pose_tolerance', 0.1, 'An image is posed only within this of a pose of '
              'observer/odometry', 's', 0.001, 5.0),
]


@dataclass(frozen=True)
class FusionNodeSettings:
    """Settings of ``FusionNode`` (see ``SPECS``)."""

    fusion: FusionSettings
    max_age_ns: int
    pose_tolerance_ns: int

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> FusionNodeSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        return cls(FusionSettings(object_height=v['object_height'], min_iou=v['min_iou'],
                                  min_depth=v['min_depth']),
                   round(v['max_age'] * 1e9), round(v['pose_tolerance'] * 1e9))


class FusionNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'fusion', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: FusionNodeSettings
        self.poses = PoseHistory()
        self.memory = ClassMemory()
        # Poses come on the control chain's thread, obstacles on the perception's (a link):
        # each only swaps a value under _lock; matching holds _match_lock (memory, counts).
        self._lock = threading.Lock()
        self._match_lock = threading.Lock()
        self._obstacles: tuple[list[Obstacle], int] | None = None
        self._camera: tuple[np.ndarray, np.ndarray, int, int] | None = None
        self._mounts: dict[str, np.ndarray] = {}
        self.bind_settings(SPECS, FusionNodeSettings.from_params, self._apply)
        self.counts = {'detections_msgs': 0, 'matched': 0, 'unmatched_detections': 0,
                       'no_camera_info': 0, 'no_obstacles': 0, 'stale_obstacles': 0,
                       'no_pose': 0, 'unknown_frame': 0, 'refused_msgs': 0,
                       'published': 0}
        self.last: dict[str, Any] = {'matched': 0, 'unmatched_detections': 0,
                                     'projected': 0, 'process_ms': 0.0}
        self._stale_reported = 0
        self._fused_pub = self.create_topic_publisher(topics.OBSTACLES_FUSED)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_odometry)
        self.create_topic_subscription(topics.OBSTACLES, self._on_obstacles)
        self.create_topic_subscription(topics.CAMERA_INFO, self._on_camera_info)
        self.create_topic_subscription(topics.DETECTIONS, self._on_detections)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: FusionNodeSettings) -> None:
        self.settings = settings

    # -- inputs -----------------------------------------------------------------------------
    def _on_odometry(self, msg: Any) -> None:
        eta = convert.pose_to_eta(msg.pose.pose)
        if not convert.all_finite(eta):
            return
        with self._lock:
            self.poses.add(convert.stamp_to_ns(msg.header.stamp), *eta.tolist())

    def _on_camera_info(self, msg: CameraInfo) -> None:
        k = np.asarray(msg.k, dtype=float).reshape(3, 3)
        d = np.asarray(msg.d, dtype=float)
        if k[0, 0] <= 0.0 or k[1, 1] <= 0.0 or msg.width == 0 or msg.height == 0:
            self.counts['refused_msgs'] += 1
            return
        self._camera = (k, d, int(msg.width), int(msg.height))

    def _on_obstacles(self, msg: PointCloud2) -> None:
        try:
            obstacles = from_cloud(msg)
        except ObstacleEncodingError as err:
            self.counts['refused_msgs'] += 1
            self.get_logger().warn(f'obstacles refused: {err}', throttle_duration_sec=5.0)
            return
        stamp_ns = cloud_stamp_ns(msg)
        with self._lock:
            self._obstacles = (obstacles, stamp_ns)
        with self._match_lock:
            self.memory.keep_only({o.id for o in obstacles})
            fused = [self._classed(o) for o in obstacles]
        self._fused_pub.publish(to_cloud(fused, stamp_ns, msg.header.frame_id or
                                         topics.WORLD_FRAME, classes=True))
        self.counts['published'] += 1

    def _classed(self, o: Obstacle) -> Obstacle:
        voted = self.memory.of(o.id)
        if voted is None:
            return o
        return Obstacle(o.id, o.kind, o.x, o.y, o.radius, o.x2, o.y2, o.vx, o.vy,
                        o.position_cov, o.velocity_cov, o.stamp_ns, voted[0], voted[1])

    def _optical_from_base(self, frame_id: str) -> np.ndarray | None:
        t = self._mounts.get(frame_id)
        if t is None:
            try:
                t = self.frame_tree.lookup(frame_id, topics.BODY_FRAME).matrix
            except FrameError as err:
                self.get_logger().error(f'detections in frame {frame_id!r}: {err}',
                                        throttle_duration_sec=5.0)
                return None
            self._mounts[frame_id] = t
        return t

    def _on_detections(self, msg: PointCloud2) -> None:
        self.counts['detections_msgs'] += 1
        try:
            rows = detections_from_cloud(msg)
        except DetectionEncodingError as err:
            self.counts['refused_msgs'] += 1
            self.get_logger().warn(f'detections refused: {err}', throttle_duration_sec=5.0)
            return
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        s = self.settings
        camera = self._camera
        with self._lock:
            latest = self._obstacles
            eta = self.poses.at(np.array([stamp_ns], dtype=np.int64), s.pose_tolerance_ns)
        if camera is None:
            self.counts['no_camera_info'] += 1
            return
        if latest is None:
            self.counts['no_obstacles'] += 1
            return
        obstacles, obstacles_ns = latest
        if abs(stamp_ns - obstacles_ns) > s.max_age_ns:
            self.counts['stale_obstacles'] += 1
            return
        if eta is None:
            self.counts['no_pose'] += 1
            return
        mount = self._optical_from_base(msg.header.frame_id)
        if mount is None:
            self.counts['unknown_frame'] += 1
            return
        start = time.thread_time()
        k, d, width, height = camera
        with self._match_lock:
            out = fuse(obstacles, eta[0], stamp_ns, Camera(k, d, width, height, mount),
                       detected_boxes(rows), s.fusion, self.memory)
        self.counts['matched'] += len(out.matches)
        self.counts['unmatched_detections'] += len(out.unmatched_detections)
        self.last = {'matched': len(out.matches),
                     'unmatched_detections': len(out.unmatched_detections),
                     'projected': len(out.projected),
                     'process_ms': round((time.thread_time() - start) * 1e3, 3)}

    # -- health -----------------------------------------------------------------------------
    def stale(self) -> int:
        """Return the detections messages not matched for want of an input, since the start."""
        c = self.counts
        return (c['no_camera_info'] + c['no_obstacles'] + c['stale_obstacles'] + c['no_pose']
                + c['unknown_frame'])

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``."""
        stale = self.stale()
        level, message = OK, 'ok'
        if stale > self._stale_reported:
            level = DEGRADED
            message = (f'{stale - self._stale_reported} detections message(s) not matched in '
                       'the last second: no camera_info, no recent obstacles, no pose near '
                       'the image stamp or an unknown frame')
        self._stale_reported = stale
        return level, message, {**self.counts, **{f'last_{k}': v for k, v in self.last.items()},
                                'tracks_classified': len(self.memory.votes)}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
