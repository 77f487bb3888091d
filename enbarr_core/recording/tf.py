"""``tf2_msgs/msg/TFMessage`` for bags, serialized without the tf2_msgs wheel.

PyPI has no ``tf2_msgs``, but the message is simple and rosbags' Jazzy type store has its
definition (for the schema in the bag and for reading back), so the recorder writes
``/tf_static`` (the profile's static frames) and ``/tf`` (the pose estimate as odom ->
base_link) with a small packer of its own. ``read_transforms`` reads them back from a bag
(tests, tools) with the type store. Pure: no rclpy here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
import functools
import struct
from typing import Any, TYPE_CHECKING

from rosbags.typesys import get_typestore, Stores

from enbarr_core.framework.frames import StampedTransform, Transform

if TYPE_CHECKING:
    from enbarr_core.framework.frame_sources import PoseSource

TF_MESSAGE = 'tf2_msgs/msg/TFMessage'


@functools.cache
def _typestore() -> Any:
    return get_typestore(Stores.ROS2_JAZZY)


def tf_message_cdr(transforms: Sequence[StampedTransform]) -> bytes:
    """Serialize a ``TFMessage`` holding ``transforms`` (CDR, as a bag stores it).

    Packed here with ``struct`` (cheaper than building a rosbags message and serializing it, and
    ``/tf`` comes at the estimate's rate: docs/benchmarks.md): little-endian CDR, each primitive
    aligned to its size from the end of the 4-byte encapsulation header, strings as a uint32 length
    counting the NUL. The tests check it against rosbags' serializer.
    """
    out = bytearray(_HEADER)
    out += _U32.pack(len(transforms))
    for s in transforms:
        _align(out, 4)
        sec, nanosec = divmod(s.stamp_ns, 1_000_000_000)
        out += _STAMP.pack(sec, nanosec)
        for name in (s.parent, s.child):
            _align(out, 4)
            raw = name.encode()
            out += _U32.pack(len(raw) + 1)
            out += raw
            out += b'\0'
        _align(out, 8)
        out += _POSE.pack(*s.transform.translation, *s.transform.rotation)
    return bytes(out)


def pose_encoder(source: PoseSource) -> Callable[[Any], bytes | None]:
    """Return ``msg -> TFMessage CDR`` of one pose source (None when a message gives no pose)."""
    def encode(msg: Any) -> bytes | None:
        try:
            t = source.transform(msg)
            return None if t is None else tf_message_cdr([t])
        except Exception:  # noqa: BLE001 - a malformed estimate gives no transform, no stop
            return None
    return encode


_HEADER = b'\x00\x01\x00\x00'  # CDR little endian, no options
_U32 = struct.Struct('<I')
_STAMP = struct.Struct('<iI')
_POSE = struct.Struct('<7d')


def _align(out: bytearray, size: int) -> None:
    out += b'\0' * (-(len(out) - len(_HEADER)) % size)


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
