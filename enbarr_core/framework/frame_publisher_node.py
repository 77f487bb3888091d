"""The frame tree live on DDS: ``/tf_static`` (latched) and ``/tf``, as robot_state_publisher.

Where ``tf2_msgs`` can be imported (a full ROS 2 install, or a workspace that built it), the
node publishes the profile's static frames once on ``/tf_static`` when it starts (transient
local: RViz, Foxglove or a tf2 listener that joins later still gets them) and each dynamic
frame's pose on ``/tf`` as its estimate arrives (``framework.frame_sources``), with tf2's
topics and QoS (``enbarr_interfaces.topics.TF_*``). A pip install has no ``tf2_msgs`` (PyPI
carries no wheel of it): the node then says so once at INFO and does nothing else; bags still
carry both topics (the recorder writes them without the wheel).
"""

from __future__ import annotations

import functools
import importlib
from typing import Any

from geometry_msgs.msg import TransformStamped

from enbarr_interfaces import convert, topics

from enbarr_core.framework.frame_sources import pose_sources, PoseSource
from enbarr_core.framework.frames import StampedTransform
from enbarr_core.framework.node import EnbarrNode

#: The module whose ``TFMessage`` class this node needs.
TF2_MSGS = 'tf2_msgs.msg'


def tf_message_class() -> type | None:
    """Return ``tf2_msgs.msg.TFMessage``, or None where tf2_msgs is not installed."""
    try:
        cls: type = getattr(importlib.import_module(TF2_MSGS), 'TFMessage')
    except (ImportError, AttributeError):
        return None
    return cls


class FramePublisherNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'frames', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._sources: list[PoseSource] = pose_sources(self.frame_tree)
        self._cls = tf_message_class()
        self.published = 0          # /tf messages sent
        self._following = False     # subscribed to the pose sources (at the first start)
        if self._cls is None:
            return  # said at start: a node only built (bringup --check) says nothing
        self._static_pub = self.create_publisher(self._cls, topics.TF_STATIC_TOPIC,
                                                 topics.TF_STATIC_QOS)
        self._tf_pub = self.create_publisher(self._cls, topics.TF_TOPIC, topics.TF_QOS)

    @property
    def live(self) -> bool:
        """Whether the node publishes (tf2_msgs is importable)."""
        return self._cls is not None

    def start(self) -> None:
        """Publish ``/tf_static`` once and follow the pose sources."""
        super().start()
        if self._following:
            return
        self._following = True
        if self._cls is None:
            self.get_logger().info(
                'tf2_msgs is not installed (a pip install has none): /tf and /tf_static are '
                'not published live; recorded bags still hold them')
            return
        static = self.frame_tree.static_transforms(self.now_ns())
        if static:
            self._static_pub.publish(self._message(static))
        for source in self._sources:
            self.create_topic_subscription(source.spec, functools.partial(self._on_pose, source))

    def _on_pose(self, source: PoseSource, msg: Any) -> None:
        t = source.transform(msg)
        if t is not None:
            self._tf_pub.publish(self._message([t]))
            self.published += 1

    def _message(self, transforms: list[StampedTransform]) -> Any:
        """Build a ``tf2_msgs/TFMessage`` of ``transforms`` (the generated class)."""
        assert self._cls is not None
        out = self._cls()
        for s in transforms:
            ts = TransformStamped()
            convert.ns_to_stamp(s.stamp_ns, ts.header.stamp)
            ts.header.frame_id, ts.child_frame_id = s.parent, s.child
            tr = ts.transform.translation
            tr.x, tr.y, tr.z = s.transform.translation
            convert.set_quaternion(ts.transform.rotation, s.transform.rotation)
            out.transforms.append(ts)
        return out
