"""Objects found in a camera image, as the detector publishes them.

On the wire (``detections``) a ``sensor_msgs/PointCloud2``, for the reasons of
``enbarr_interfaces.obstacles`` (no custom message in a pip install, and vision_msgs has no
PyPI wheel): self-describing named fields, a header. One point per detection, ``height`` 1,
little-endian, fields in :data:`FIELDS` order; a reader finds them by name
(:func:`from_cloud`). ``header.stamp`` and ``header.frame_id`` are the image's (its stamp,
its optical frame), so a consumer pairs the boxes with that image and its ``camera_info``.
A frame with nothing in it is answered with an empty cloud (``width`` 0): "seen, nothing
there" differs from "not seen". ``class_id`` indexes the detector node's ``class_names``
parameter. Boxes are in the image's pixels, x right and y down, corners at pixel edges (a
box of the top-left pixel alone is 0, 0, 1, 1). ``docs/interfaces.md`` ("Detections")
documents the encoding for other tools.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import PointCloud2, PointField

from enbarr_interfaces.clouds import read_fields
from enbarr_interfaces.convert import ns_to_stamp

#: (name, numpy type, PointField datatype, meaning) of each field, in wire order.
FIELDS: tuple[tuple[str, str, int, str], ...] = (
    ('class_id', '<u4', PointField.UINT32, "index into the detector's class_names"),
    ('score', '<f4', PointField.FLOAT32, 'confidence 0..1 (classical back end: solidity)'),
    ('x_min', '<f4', PointField.FLOAT32, 'left edge of the box [px]'),
    ('y_min', '<f4', PointField.FLOAT32, 'top edge [px]'),
    ('x_max', '<f4', PointField.FLOAT32, 'right edge [px]'),
    ('y_max', '<f4', PointField.FLOAT32, 'bottom edge [px]'),
)
DTYPE = np.dtype([(name, np_type) for name, np_type, _, _ in FIELDS])
_OFFSETS = {name: int(DTYPE.fields[name][1]) for name, *_ in FIELDS}  # type: ignore[index]
#: Built once, shared by every message (a PointField's constructor checks each value); a
#: receiver must not change them.
_POINT_FIELDS = tuple(PointField(name=name, offset=_OFFSETS[name], datatype=datatype, count=1)
                      for name, _, datatype, _ in FIELDS)


class DetectionEncodingError(ValueError):
    """A point cloud that is not a detections message (names the field at fault)."""


def to_cloud(rows: Sequence[tuple[int, float, float, float, float, float]], stamp_ns: int,
             frame_id: str, out: PointCloud2 | None = None) -> PointCloud2:
    """Encode ``(class_id, score, x_min, y_min, x_max, y_max)`` rows, stamped as the image."""
    data = np.array([tuple(r) for r in rows], dtype=DTYPE)
    msg = out if out is not None else PointCloud2()
    ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = frame_id
    msg.height, msg.width = 1, len(data)
    msg.fields = list(_POINT_FIELDS)
    msg.is_bigendian = False
    msg.point_step = DTYPE.itemsize
    msg.row_step = DTYPE.itemsize * len(data)
    msg.data = data.tobytes()
    msg.is_dense = True
    return msg


def from_cloud(msg: PointCloud2) -> NDArray[Any]:
    """Decode a ``detections`` message into a structured array of :data:`DTYPE`.

    Fields are found by name; any numeric type is read. Raises
    :class:`DetectionEncodingError` naming what is missing or malformed.
    """
    names = [name for name, *_ in FIELDS]
    return read_fields(msg, names, 'detections', DetectionEncodingError).astype(DTYPE)
