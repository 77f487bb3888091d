"""Where a dynamic frame's pose comes from: the contract topic its ``pose`` names.

The profile's tree (``framework.frames``) says ``base_link: {parent: odom, pose: TOPIC}``;
this module turns each message of TOPIC into the pose of the frame in its parent, for the
recorder (``/tf`` in bags) and the frame publisher (``/tf`` on DDS):

- ``nav_msgs/Odometry`` (the 3-DOF observer's ``observer/odometry``, a simulator's
  ``sim/odometry``): the pose of ``child_frame_id`` in ``header.frame_id``, taken as the
  frame's pose in its parent (through the tree's static path when the child is another frame).
- ``sensor_msgs/Imu`` (the ROV's attitude filter, ``imu/data``): the orientation of the IMU's
  frame in ``odom``, turned through the tree's static rotation into the frame's; there is no
  position estimate, so the translation is zero: ``odom -> base_link`` then shows the
  vehicle's attitude at the origin.

A message with a non-finite pose, or an ``Imu`` that carries no orientation
(``orientation_covariance[0] == -1``, REP-145), gives no transform.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Imu

from enbarr_interfaces import convert, topics
from enbarr_interfaces.topics import TopicSpec

from enbarr_core.framework.errors import ConfigurationError, FrameError
from enbarr_core.framework.frames import Frame, FrameTree, StampedTransform, Transform
from enbarr_core.framework.kinematics import quat_multiply

#: What a ``pose`` topic may carry.
POSE_TYPES = (Odometry, Imu)


@dataclass(frozen=True)
class PoseSource:
    """The topic that moves one dynamic frame, and how its messages become the frame's pose."""

    frame: Frame
    spec: TopicSpec
    tree: FrameTree

    @property
    def parent(self) -> str:
        """The frame the pose is in (the dynamic frame's parent)."""
        assert self.frame.parent is not None  # FrameTree refuses a dynamic root
        return self.frame.parent

    def transform(self, msg: Any) -> StampedTransform | None:
        """Return the frame's pose in its parent from one message; None if it has none."""
        stamp = convert.stamp_to_ns(msg.header.stamp)
        if isinstance(msg, Odometry):
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            pose = Transform((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))
            if not _finite(pose):
                return None
            child = msg.child_frame_id or self.frame.name
            if child != self.frame.name:
                pose = pose @ self._static(child)
        elif isinstance(msg, Imu):
            if msg.orientation_covariance[0] == -1.0:
                return None
            q = msg.orientation
            source = msg.header.frame_id or topics.IMU_FRAME
            rotation = np.array([q.x, q.y, q.z, q.w])
            if source != self.frame.name:
                rotation = quat_multiply(rotation, self._static(source).rotation)
            norm = float(np.linalg.norm(rotation))
            if not math.isfinite(norm) or norm < 0.5:
                return None
            x, y, z, w = (float(c) for c in rotation / norm)
            pose = Transform((0.0, 0.0, 0.0), (x, y, z, w))
        else:
            return None
        return StampedTransform(stamp, self.parent, self.frame.name, pose)

    def _static(self, frame: str) -> Transform:
        """T_frame_self: the static pose of the dynamic frame in ``frame`` (identity if unknown).

        A message naming a frame the tree lacks is taken as the dynamic frame itself: the
        contract's producers all name ``base_link`` or ``imu_link``, which the shipped trees
        have.
        """
        if frame not in self.tree:
            return Transform()
        try:
            return self.tree.lookup(frame, self.frame.name)
        except FrameError:
            return Transform()


def _finite(t: Transform) -> bool:
    return all(math.isfinite(v) for v in (*t.translation, *t.rotation)) and (
        abs(math.sqrt(sum(v * v for v in t.rotation)) - 1.0) < 1e-3)


def pose_sources(tree: FrameTree) -> list[PoseSource]:
    """Return the pose source of every dynamic frame of ``tree``.

    ``ConfigurationError`` naming the profile key when a ``pose`` is not a contract topic of
    type ``nav_msgs/Odometry`` or ``sensor_msgs/Imu``.
    """
    by_name = {spec.name: spec for spec in topics.ALL_TOPICS}
    out = []
    for f in tree.dynamic_frames():
        spec = by_name.get(f.pose.lstrip('/'))
        usable = sorted(s.name for s in topics.ALL_TOPICS if s.msg_type in POSE_TYPES)
        if spec is None or spec.msg_type not in POSE_TYPES:
            raise ConfigurationError(
                f'frames.{f.name}.pose: {f.pose!r} is not a pose topic of the contract; one '
                f'of: {", ".join(usable)}', parameter=f'frames.{f.name}.pose')
        out.append(PoseSource(f, spec, tree))
    return out
