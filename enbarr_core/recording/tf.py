"""``tf2_msgs/msg/TFMessage`` for bags, serialized without the tf2_msgs wheel.

PyPI has no ``tf2_msgs``, but rosbags' Jazzy type store has its definition, so the recorder
writes ``/tf_static`` (the profile's static frames) and ``/tf`` (the pose estimate as
odom -> base_link) with the type store's CDR serializer. ``read_transforms`` reads them back
from a bag (tests, tools). Pure: no rclpy here.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
import functools
from typing import Any

from rosbags.typesys import get_typestore, Stores

from enbarr_core.framework.frames import StampedTransform, Transform

TF_MESSAGE = 'tf2_msgs/msg/TFMessage'


@functools.cache
def _typestore() -> Any:
    return get_typestore(Stores.ROS2_JAZZY)


def tf_message_cdr(transforms: Sequence[StampedTransform]) -> bytes:
    """Serialize a ``TFMessage`` holding ``transforms`` (CDR, as a bag stores it)."""
    ts = _typestore()
    t = ts.types
    Time, Header = t['builtin_interfaces/msg/Time'], t['std_msgs/msg/Header']
    Vector3, Quaternion = t['geometry_msgs/msg/Vector3'], t['geometry_msgs/msg/Quaternion']
    Tf, Stamped = t['geometry_msgs/msg/Transform'], t['geometry_msgs/msg/TransformStamped']
    msg = t[TF_MESSAGE](transforms=[
        Stamped(header=Header(stamp=Time(sec=s.stamp_ns // 1_000_000_000,
                                         nanosec=s.stamp_ns % 1_000_000_000),
                              frame_id=s.parent),
                child_frame_id=s.child,
                transform=Tf(translation=Vector3(*s.transform.translation),
                             rotation=Quaternion(*s.transform.rotation)))
        for s in transforms])
    return bytes(ts.serialize_cdr(msg, TF_MESSAGE))


def decode_transforms(data: bytes) -> list[StampedTransform]:
    """Decode the transforms of one serialized ``TFMessage``."""
    msg = _typestore().deserialize_cdr(data, TF_MESSAGE)
    return [StampedTransform(
        t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec, t.header.frame_id,
        t.child_frame_id,
        Transform((t.transform.translation.x, t.transform.translation.y,
                   t.transform.translation.z),
                  (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                   t.transform.rotation.w)))
        for t in msg.transforms]


def read_transforms(messages: Iterable[tuple[int, bytes]]) -> list[StampedTransform]:
    """Every transform of a bag topic's ``(log time, CDR)`` messages, in order."""
    return [s for _, data in messages for s in decode_transforms(data)]
