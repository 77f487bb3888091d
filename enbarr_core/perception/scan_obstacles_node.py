"""Scan obstacles node: the lidar scan in, tracked obstacles in the world out.

``scan`` + ``observer/odometry`` -> ``obstacles`` (``sensor_msgs/PointCloud2``, the encoding
of ``enbarr_interfaces.obstacles``) and ``obstacles/markers`` (``MarkerArray`` for a viewer).

Each scan's finite rays become points in its frame, then in ``base_link`` through the profile's
frame tree (``base_link`` -> the scan's ``header.frame_id``), then in ``odom`` with the pose
estimate at each ray's own time (the last poses of ``observer/odometry`` kept and interpolated;
``enbarr_core.perception.scan_geometry``): ``time_increment`` says it when the scan gives it;
a scan without it (the ``rplidar`` plugin's: its rays are binned) is read as ``sweep`` says,
by default as the RPLidar turns, clockwise from its 0 deg mark over ``scan_time``. The points
are cut into clusters (adaptive breakpoints, ``segmentation``), each cluster fitted with a
circle or segments (``fitting``) and the shapes tracked across scans (``tracking``);
``enbarr_core.perception.pipeline`` chains them.

Every scan that could be placed in the world is answered on ``obstacles`` with the confirmed
tracks, also when there are none (and on ``obstacles/markers`` while a viewer subscribes:
cylinders for circles, line strips for segments, a label with id and speed, deletions for the
tracks dropped since): ``header.stamp`` is the scan's stamp, so a consumer judges
freshness by it, and each obstacle carries the stamp of the last scan that measured it. A scan
that cannot be placed (no pose within ``pose_tolerance`` of one of its rays, or a frame the
tree does not have) is counted and answered with nothing: publishing the old tracks under its
stamp would tell the avoidance they were just seen. ``/diagnostics`` (every second) counts
scans, the scans without a pose or frame, scans older than the last one (refused: the filters
only go forward), clusters, tracks and confirmed tracks; DEGRADED while scans went unplaced in
the last second.

Parameters (all live; the tracks are kept when they change): see ``SPECS``. The range noise
defaults are the CS Saucer manual's figures for its RPLidar A1 (Table 1.1), read as one
standard deviation; another lidar sets its own in the profile.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
import threading
import time
from typing import Any

from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import Marker, MarkerArray

from enbarr_interfaces import convert, topics
from enbarr_interfaces.obstacles import CIRCLE, Obstacle, to_cloud

from enbarr_core.framework.errors import FrameError
from enbarr_core.framework.health import DEGRADED, OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec, validate_as_parameters
from enbarr_core.perception.fitting import FitSettings
from enbarr_core.perception.pipeline import LidarMount, PerceptionSettings, ScanObstacles
from enbarr_core.perception.scan_geometry import PoseHistory, RangeNoise
from enbarr_core.perception.segmentation import BreakpointSettings
from enbarr_core.perception.tracking import TrackerSettings

SPECS = [
    ParamSpec('breakpoint_lambda', math.radians(10.0), 'Adaptive breakpoint lambda: the '
              'shallowest incidence at which a surface is still one cluster (Borges and '
              'Aldon 2004)', 'rad', 0.01, 0.5 * math.pi),
    ParamSpec('max_gap_rays', 2, 'Rays without a finite range bridged inside one cluster',
              '', 0, 90),
    ParamSpec('range_noise_limits', [3.0, 5.0], 'Upper ranges of the range-noise bands but '
              'the last (CS Saucer manual, Table 1.1)', 'm', 0.01, 100.0),
    ParamSpec('range_noise_fractions', [0.01, 0.02, 0.025], 'Range noise (one standard '
              'deviation) as a fraction of the range, one per band (one more than the limits)',
              '', 0.0, 0.5),
    ParamSpec('min_cluster_points', 2, 'Clusters of fewer points are dropped (stray returns)',
              '', 1, 360),
    ParamSpec('min_radius', 0.05, 'Smallest circle fitted (a short arc is held to it)', 'm',
              0.001, 10.0),
    ParamSpec('max_radius', 1.0, 'Largest circle; a longer cluster is a wall (segments)', 'm',
              0.01, 50.0),
    ParamSpec('min_segment_length', 0.4, 'A cluster shorter than this is a circle', 'm', 0.01,
              50.0),
    ParamSpec('circle_ratio', 0.8, 'A cluster is a circle when its residual per degree of '
              "freedom is below this times the straight line's", '', 0.01, 10.0),
    ParamSpec('split_distance', 0.1, 'A corner further than this (plus 3 sigma of the range '
              'noise) from its chord splits a wall in two', 'm', 0.001, 10.0),
    ParamSpec('confirm_hits', 3, 'N: measurements before a track is published', '', 1, 100),
    ParamSpec('drop_misses', 5, 'M: scans in a row without a measurement before a track is '
              'dropped', '', 1, 1000),
    ParamSpec('gate', 9.21, 'Association gate: squared Mahalanobis distance (9.21: 99 % of a '
              '2-dof chi-square)', '', 0.1, 1000.0),
    ParamSpec('accel_noise', 0.2, 'Process noise of a circle track: white acceleration, one '
              'standard deviation', 'm/s^2', 1e-4, 100.0),
    ParamSpec('initial_speed_std', 1.0, 'Speed standard deviation of a new circle track',
              'm/s', 1e-3, 100.0),
    ParamSpec('radius_smoothing', 0.3, "Weight of a new radius in a track's smoothed radius",
              '', 0.001, 1.0),
    ParamSpec('segment_gate', 0.3, 'A segment extends a wall track within this of its line',
              'm', 0.001, 10.0),
    ParamSpec('segment_angle_gate', 0.2, 'A segment extends a wall track whose direction '
              'differs by less than this', 'rad', 0.001, 1.5707963267948966),
    ParamSpec('pose_tolerance', 0.1, 'A ray is placed in the world only within this of a pose '
              'of observer/odometry', 's', 0.001, 5.0),
    ParamSpec('sweep', 'clockwise_from_zero', 'When the rays of a scan without time_increment '
              'were taken over its scan_time: clockwise_from_zero (from bearing 0, turning '
              'clockwise: the RPLidar and the rplidar plugin) or at_stamp (all at the stamp)'),
]

_PARAMETER = {'lam': 'breakpoint_lambda', 'max_gap': 'max_gap_rays',
              'limits': 'range_noise_limits', 'fractions': 'range_noise_fractions',
              'pose_tolerance_ns': 'pose_tolerance'}
#: Height of a circle's marker, and of its label above the water [m] (drawing only).
MARKER_HEIGHT = 0.3
LINE_WIDTH = 0.05
LABELS = 'obstacle_labels'


@dataclass(frozen=True)
class ScanObstaclesSettings:
    """Settings of ``ScanObstaclesNode`` (see ``SPECS``)."""

    perception: PerceptionSettings

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> ScanObstaclesSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        s = PerceptionSettings(
            breakpoints=BreakpointSettings(
                lam=v['breakpoint_lambda'], max_gap=v['max_gap_rays'],
                noise=RangeNoise(tuple(v['range_noise_limits']),
                                 tuple(v['range_noise_fractions']))),
            min_cluster_points=v['min_cluster_points'],
            fit=FitSettings(min_radius=v['min_radius'], max_radius=v['max_radius'],
                            min_segment_length=v['min_segment_length'],
                            circle_ratio=v['circle_ratio'],
                            split_distance=v['split_distance']),
            tracker=TrackerSettings(
                confirm_hits=v['confirm_hits'], drop_misses=v['drop_misses'], gate=v['gate'],
                accel_noise=v['accel_noise'], initial_speed_std=v['initial_speed_std'],
                radius_smoothing=v['radius_smoothing'], segment_gate=v['segment_gate'],
                segment_angle_gate=v['segment_angle_gate']),
            pose_tolerance_ns=round(v['pose_tolerance'] * 1e9), sweep=v['sweep'])
        validate_as_parameters(s, _PARAMETER)
        return cls(s)


def markers(obstacles: Sequence[Obstacle], gone: Sequence[int], stamp_ns: int,
            frame_id: str) -> MarkerArray:
    """Draw ``obstacles`` (cylinders, line strips, labels) and delete the markers of ``gone``."""
    out = MarkerArray()
    stamp = convert.ns_to_stamp(stamp_ns)
    for o in obstacles:
        shape = Marker()
        shape.header.stamp = stamp
        shape.header.frame_id = frame_id
        shape.ns, shape.id, shape.action = 'obstacles', o.id, Marker.ADD
        shape.pose.orientation.w = 1.0
        if o.kind == CIRCLE:
            shape.type = Marker.CYLINDER
            shape.pose.position.x, shape.pose.position.y = o.x, o.y
            shape.pose.position.z = 0.5 * MARKER_HEIGHT
            shape.scale.x = shape.scale.y = max(2.0 * o.radius, 1e-3)
            shape.scale.z = MARKER_HEIGHT
            shape.color.r, shape.color.g, shape.color.b, shape.color.a = 1.0, 0.5, 0.0, 0.8
        else:
            shape.type = Marker.LINE_STRIP
            x2, y2 = o.end
            shape.points = [Point(x=o.x, y=o.y, z=0.0), Point(x=x2, y=y2, z=0.0)]
            shape.scale.x = max(2.0 * o.radius, LINE_WIDTH)
            shape.color.r, shape.color.g, shape.color.b, shape.color.a = 0.9, 0.1, 0.1, 1.0
        label = Marker()
        label.header = shape.header
        label.ns, label.id, label.action = LABELS, o.id, Marker.ADD
        label.type = Marker.TEXT_VIEW_FACING
        cx, cy = (0.5 * (o.x + o.end[0]), 0.5 * (o.y + o.end[1]))
        label.pose.position.x, label.pose.position.y = cx, cy
        label.pose.position.z = 1.5 * MARKER_HEIGHT
        label.pose.orientation.w = 1.0
        label.scale.z = 0.2
        label.color.r = label.color.g = label.color.b = label.color.a = 1.0
        label.text = f'{o.id} {math.hypot(o.vx, o.vy):.2f} m/s'
        out.markers += [shape, label]
    for i in gone:
        for ns in ('obstacles', LABELS):
            m = Marker()
            m.header.stamp = stamp
            m.header.frame_id = frame_id
            m.ns, m.id, m.action = ns, i, Marker.DELETE
            out.markers.append(m)
    return out


class ScanObstaclesNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'scan_obstacles', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: ScanObstaclesSettings
        self.pipeline: ScanObstacles | None = None
        self.poses = PoseHistory()
        # Poses arrive on the control chain's thread (a fast topic: the observer's publish
        # calls us), scans on the lidar's (also fast: the simulated lidar's simulator thread,
        # the RPLidar driver's reader thread; the executor's when the lidar is in another
        # process). The chain must never wait for a scan's processing: a pose only takes
        # _pose_lock, and a scan holds it only to copy them.
        self._pose_lock = threading.Lock()
        self._lock = threading.Lock()   # the pipeline: scans and parameter changes
        self._mounts: dict[str, LidarMount] = {}
        self._drawn: set[int] = set()
        self.bind_settings(SPECS, ScanObstaclesSettings.from_params, self._apply)
        self.scans = 0
        self.without_pose = 0
        self.unknown_frame = 0
        self.refused_poses = 0
        self.out_of_order = 0
        self.last_outcome: Any = None
        self.last_process_s = 0.0
        self._unplaced_reported = 0
        self._obstacles_pub = self.create_topic_publisher(topics.OBSTACLES)
        # A viewer's topic, never a link: a ROS publisher, whose subscriber count decides
        # whether markers are built at all.
        spec = topics.OBSTACLE_MARKERS
        self._markers_pub = self.create_publisher(spec.msg_type, spec.name, spec.qos)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_odometry)
        self.create_topic_subscription(topics.SCAN, self._on_scan)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: ScanObstaclesSettings) -> None:
        self.settings = settings
        with self._lock:
            if self.pipeline is None:
                self.pipeline = ScanObstacles(settings.perception)
            else:
                self.pipeline.settings = settings.perception

    def _on_odometry(self, msg: Odometry) -> None:
        # Floats, not an eta array: one call per estimate (50 Hz) for three numbers.
        pose = msg.pose.pose
        x, y, psi = pose.position.x, pose.position.y, convert.quaternion_to_yaw(pose.orientation)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(psi)):
            self.refused_poses += 1
            return
        with self._pose_lock:
            if not self.poses.add(convert.stamp_to_ns(msg.header.stamp), x, y, psi):
                self.refused_poses += 1

    def _mount(self, frame_id: str) -> LidarMount | None:
        mount = self._mounts.get(frame_id)
        if mount is None:
            try:
                t = self.frame_tree.lookup(topics.BODY_FRAME, frame_id)
            except FrameError as err:
                self.get_logger().error(f'scan in frame {frame_id!r}: {err}',
                                        throttle_duration_sec=5.0)
                return None
            mount = LidarMount(t.rotation_matrix, t.matrix[:3, 3].copy())
            self._mounts[frame_id] = mount
        return mount

    def _on_scan(self, msg: LaserScan) -> None:
        self.scans += 1
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        mount = self._mount(msg.header.frame_id)
        if mount is None:
            self.unknown_frame += 1
            return
        start = time.thread_time()
        with self._pose_lock:
            poses = self.poses.snapshot()
        with self._lock:
            assert self.pipeline is not None
            try:
                outcome = self.pipeline.process(
                    msg.ranges, msg.angle_min, msg.angle_increment, msg.time_increment,
                    stamp_ns, mount, poses, msg.scan_time)
            except ValueError as err:   # a scan older than the last one taken
                self.out_of_order += 1
                self.get_logger().warn(f'scan refused: {err}', throttle_duration_sec=5.0)
                return
        self.last_process_s = time.thread_time() - start
        self.last_outcome = outcome
        if not outcome.posed:
            self.without_pose += 1
            self.get_logger().warn(
                f'scan stamped {stamp_ns} ns has no pose of {topics.OBSERVER_ODOMETRY.name} '
                f'within {self.settings.perception.pose_tolerance_ns * 1e-9:g} s: not placed '
                'in the world', throttle_duration_sec=5.0)
            return
        obstacles = outcome.obstacles
        self._obstacles_pub.publish(to_cloud(obstacles, stamp_ns, topics.WORLD_FRAME))
        # Markers are for a person watching: building them costs more than the obstacles
        # (docs/benchmarks.md, perception), so only while a viewer subscribes.
        if self._markers_pub.get_subscription_count() == 0:
            self._drawn = set()
            return
        ids = {o.id for o in obstacles}
        gone = sorted(self._drawn - ids)
        self._drawn = ids
        self._markers_pub.publish(markers(obstacles, gone, stamp_ns, topics.WORLD_FRAME))

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``."""
        unplaced = self.without_pose + self.unknown_frame
        level, message = OK, 'ok'
        if unplaced > self._unplaced_reported:
            level = DEGRADED
            message = (f'{unplaced - self._unplaced_reported} scan(s) not placed in the world '
                       f'in the last second: no pose of {topics.OBSERVER_ODOMETRY.name} near '
                       'their stamp, or a frame the frame tree does not have')
        self._unplaced_reported = unplaced
        o = self.last_outcome
        tracker = self.pipeline.tracker if self.pipeline is not None else None
        return level, message, {
            'scans': self.scans, 'scans_without_pose': self.without_pose,
            'scans_unknown_frame': self.unknown_frame, 'scans_out_of_order': self.out_of_order,
            'refused_poses': self.refused_poses,
            'clusters': o.clusters if o else 0, 'circles': o.circles if o else 0,
            'segments': o.segments if o else 0,
            'tracks': (len(tracker.circles) + len(tracker.segments)) if tracker else 0,
            'confirmed': tracker.confirmed if tracker else 0,
            'process_ms': round(self.last_process_s * 1e3, 3)}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
