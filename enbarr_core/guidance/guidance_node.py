"""Guidance node: ``observer/odometry`` + ``mode`` -> ``guidance/reference``.

The guidance block of the manual's graph (observer -> guidance -> controller -> allocation).
It follows the operator mode the controller publishes (``mode``, latched): entering
automatic it holds the pose of the latest estimate (:class:`HoldPose`); entering guidance it
goes to the waypoint when ``path.waypoints`` holds one (:class:`GoToWaypoint`), else follows
the path with line of sight (:class:`LosPath`); in manual it publishes nothing. On every
estimate outside manual it publishes the reference for that estimate on
``guidance/reference``, stamped with the estimate's stamp and tagged with the mode it was
made for (see ``reference_to_msg``), so that the controller never tracks a reference made for
another mode. It announces on ``guidance/path_available`` (latched) whether it has a path,
which the controller needs to refuse guidance without one.

Another guidance law (say, one that avoids collisions) replaces this node with one
``plugin:`` line of the profile, as long as it speaks the same three topics.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from std_msgs.msg import Bool, String

from enbarr_interfaces import convert, topics

from enbarr_core.control.modes import Mode
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.guidance.guidance import GoToWaypoint, HoldPose, LosPath, Reference

SPECS = [
    ParamSpec('path.waypoints', [0.0], 'Guidance: x, y of one waypoint to go to, or x0, y0, '
              'x1, y1, ... of a path to follow (odom); [0.0]: none', 'm', -1e6, 1e6),
    ParamSpec('path.speed', 0.2, 'Reference speed along the path', 'm/s', 1e-3, 10.0),
    ParamSpec('path.accel', 0.05, 'Acceleration limit when going to a single waypoint',
              'm/s^2', 1e-4, 10.0),
    ParamSpec('path.lookahead', 0.5, 'Line-of-sight lookahead distance', 'm', 1e-3, 100.0),
    ParamSpec('path.acceptance_radius', 0.1, 'Waypoint acceptance radius', 'm', 1e-3, 100.0),
    ParamSpec('path.heading', 'fixed', 'Heading along the path: fixed (keep the heading held '
              'when guidance starts) or course (face the direction of travel)'),
]

#: The mode tags of a reference (``twist.covariance[MODE_INDEX]``).
MODE_CODE = {Mode.AUTOMATIC: 1.0, Mode.GUIDANCE: 2.0}
_MODE_OF_CODE = {code: mode for mode, code in MODE_CODE.items()}
_MASK_INDEX = (0, 7, 35)    # pose.covariance diagonal: x, y, yaw
_ACCEL_INDEX = (0, 1, 2)    # twist.covariance: nu_d_dot (u, v, r)
MODE_INDEX = 3              # twist.covariance: the mode the reference was made for


def reference_to_msg(ref: Reference, mode: Mode, header: Any) -> Odometry:
    """Build the ``guidance/reference`` message of ``ref`` for ``mode`` and ``header``.

    ``header`` is the header of the estimate the reference was made for.

    Odometry has no field for the desired acceleration, the feedback mask or the mode, and the
    interfaces stay standard types, so the (otherwise meaningless) covariances carry them:
    pose.covariance diagonal x, y, yaw [0, 7, 35] = 0 where that pose component is fed back,
    -1 where it is not (the DOF tracks nu_d only); twist.covariance[0:3] = nu_d_dot
    [m/s^2, m/s^2, rad/s^2]; twist.covariance[3] = the mode (1 automatic, 2 guidance).
    """
    out = Odometry()
    out.header = header
    out.child_frame_id = topics.BODY_FRAME
    convert.set_pose_eta(out.pose.pose, ref.eta_d)
    convert.set_twist_nu3(out.twist.twist, ref.nu_d)
    pose_cov = np.zeros(36)
    for i, used in zip(_MASK_INDEX, ref.position_mask):
        pose_cov[i] = 0.0 if used else -1.0
    twist_cov = np.zeros(36)
    twist_cov[list(_ACCEL_INDEX)] = ref.nu_d_dot
    twist_cov[MODE_INDEX] = MODE_CODE[mode]
    out.pose.covariance = pose_cov
    out.twist.covariance = twist_cov
    return out


def msg_to_reference(msg: Odometry) -> tuple[Reference, Mode | None]:
    """Read a ``guidance/reference`` message: the reference and the mode it was made for.

    The mode is ``None`` when the tag is missing or unknown.
    """
    pose_cov, twist_cov = msg.pose.covariance, msg.twist.covariance
    mask = tuple(bool(pose_cov[i] == 0.0) for i in _MASK_INDEX)
    ref = Reference(convert.pose_to_eta(msg.pose.pose), convert.twist_to_nu3(msg.twist.twist),
                    np.array([twist_cov[i] for i in _ACCEL_INDEX], dtype=float),
                    mask)  # type: ignore[arg-type]
    return ref, _MODE_OF_CODE.get(float(twist_cov[MODE_INDEX]))


@dataclass(frozen=True)
class GuidanceSettings:
    """Settings of ``GuidanceNode`` (see ``SPECS``)."""

    waypoints: tuple[tuple[float, float], ...]  # () none, one: go to it, more: a path [m]
    speed: float               # reference speed [m/s]
    accel: float               # acceleration limit to a single waypoint [m/s^2]
    lookahead: float           # line-of-sight lookahead [m]
    acceptance_radius: float   # waypoint acceptance radius [m]
    heading: str               # 'fixed' or 'course'

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> GuidanceSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if v['path.heading'] not in ('fixed', 'course'):  # checked with or without a path
            raise ValueError(f'path.heading: expected fixed or course, got '
                             f'{v["path.heading"]!r}')
        w = list(v['path.waypoints'])
        waypoints: list[tuple[float, float]] = []
        if w != [0.0]:
            if len(w) % 2 or len(w) < 2:
                raise ValueError('path.waypoints: expected x, y of a waypoint or x0, y0, x1, '
                                 'y1, ... of a path')
            waypoints = [(float(x), float(y)) for x, y in zip(w[::2], w[1::2])]
        s = cls(tuple(waypoints), v['path.speed'], v['path.accel'], v['path.lookahead'],
                v['path.acceptance_radius'], v['path.heading'])
        if len(waypoints) > 1:  # a path: check it now (a single waypoint is checked on use)
            try:
                s.path_law()
            except ValueError as err:
                raise ValueError(f'path: {err}') from err
        return s

    def path_law(self) -> LosPath:
        """Line-of-sight following of the path (two or more waypoints)."""
        return LosPath(self.waypoints, self.speed, self.lookahead, self.acceptance_radius,
                       heading=self.heading)


class GuidanceNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'guidance', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: GuidanceSettings
        self.mode = Mode.MANUAL
        self.law: HoldPose | GoToWaypoint | LosPath | None = None
        self.reference: Reference | None = None
        self.failures = 0
        self._eta: np.ndarray | None = None
        self._last_ns: int | None = None
        self._ref_pub = self.create_topic_publisher(topics.GUIDANCE_REFERENCE)
        self._path_pub = self.create_topic_publisher(topics.GUIDANCE_PATH_AVAILABLE)
        self.bind_settings(SPECS, GuidanceSettings.from_params, self._apply)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_estimate)
        self.create_topic_subscription(topics.MODE, self._on_mode)
        self.create_timer(1.0, self._report)

    def _apply(self, settings: GuidanceSettings) -> None:
        self.settings = settings
        self._path_pub.publish(Bool(data=bool(settings.waypoints)))

    def _on_mode(self, msg: String) -> None:
        try:
            mode = Mode(msg.data)
        except ValueError:
            self.get_logger().warn(f'unknown mode {msg.data!r} ignored')
            return
        if mode is self.mode:
            return
        self.mode, self.law = mode, None
        if mode is Mode.MANUAL:
            return
        if self._eta is None:
            self.failures += 1
            self.get_logger().error(f'{mode.value}: no estimate yet, no reference')
            return
        s = self.settings
        try:
            if mode is Mode.AUTOMATIC:
                self.law = HoldPose(self._eta)
            elif len(s.waypoints) == 1:  # go to the waypoint, heading held
                self.law = GoToWaypoint(self._eta, s.waypoints[0], s.speed, s.accel,
                                        arrival_radius=s.acceptance_radius)
            elif s.waypoints:
                self.law = s.path_law()
            else:
                self.failures += 1
                self.get_logger().error('guidance: no path configured, no reference')
        except ValueError as err:
            self.failures += 1
            self.get_logger().error(f'{mode.value}: {err}')

    def _on_estimate(self, msg: Odometry) -> None:
        t = convert.stamp_to_ns(msg.header.stamp)
        last, self._last_ns = self._last_ns, t
        self._eta = eta = convert.pose_to_eta(msg.pose.pose)
        if self.law is None or last is None or t <= last:
            return
        self.reference = ref = self.law.reference(eta, (t - last) * 1e-9)
        self._ref_pub.publish(reference_to_msg(ref, self.mode, msg.header))

    def _report(self) -> None:
        ref = self.reference
        cross_track = ref.cross_track if ref is not None else None
        self.publish_diagnostics(0 if self.failures == 0 else 1, self.mode.value, {
            'failures': self.failures, 'finished': ref is not None and ref.finished,
            'cross_track': 'none' if cross_track is None else cross_track})
