"""Obstacles as the perception publishes them and the collision avoidance reads them.

Every obstacle is a *capsule* in the world frame (``odom``, ENU): the set of points within
``radius`` of the segment from ``(x, y)`` to ``(x2, y2)``. A buoy or a boat is a circle (the
two ends coincide); a basin wall or a pier is a segment (``radius`` its half thickness, or 0).
One shape for both keeps every consumer's distance the same formula
(:meth:`Obstacle.distance`).

On the wire (``obstacles``) it is a ``sensor_msgs/PointCloud2``: no custom message can be
built in a pip install, and a point cloud is self-describing (named, typed fields), has a
header, and a viewer draws it. One point per obstacle, fields in :data:`FIELDS` order, every
one ``FLOAT64`` except ``id``, ``kind`` and the stamp's two fields (``UINT32``);
``header.frame_id`` is the world frame and ``header.stamp`` the stamp of the scan (or image)
that produced the message. A reader finds the fields by name (:func:`from_cloud`), so fields
can be added later without breaking it. ``docs/interfaces.md`` ("Obstacles") documents the
encoding for other tools.

Two optional fields follow (:data:`CLASS_FIELDS`), written when an obstacle carries a class
(the fusion of camera detections with the lidar's obstacles, ``enbarr_core.vision.fusion``):
``class_id`` (``INT32``, an index into the detector's ``class_names``, -1 for none) and
``class_score`` (``FLOAT64``, 0..1). A message without them decodes with no class
(:data:`NO_CLASS`), and a reader that does not know them skips them: the lidar's messages and
the fused ones share one encoding, and the collision avoidance reads either.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import PointCloud2, PointField

from enbarr_interfaces.clouds import read_fields
from enbarr_interfaces.convert import NS_PER_S, ns_to_stamp, stamp_to_ns

CIRCLE = 0
SEGMENT = 1
KINDS = {CIRCLE: 'circle', SEGMENT: 'segment'}
#: ``class_id`` of an obstacle that no detection classified.
NO_CLASS = -1

#: (name, numpy type, PointField datatype, meaning) of each field, in wire order.
FIELDS: tuple[tuple[str, str, int, str], ...] = (
    ('id', '<u4', PointField.UINT32, 'track id, unique while the track lives'),
    ('kind', '<u4', PointField.UINT32, '0 circle, 1 segment'),
    ('stamp_sec', '<u4', PointField.UINT32,
     'stamp of the last measurement that updated this obstacle (builtin_interfaces/Time)'),
    ('stamp_nanosec', '<u4', PointField.UINT32, ''),
    ('x', '<f8', PointField.FLOAT64, 'centre (circle) or first end (segment) [m], odom'),
    ('y', '<f8', PointField.FLOAT64, ''),
    ('x2', '<f8', PointField.FLOAT64, 'second end [m] (a circle: equal to x, y)'),
    ('y2', '<f8', PointField.FLOAT64, ''),
    ('radius', '<f8', PointField.FLOAT64, 'extent around the segment [m]'),
    ('vx', '<f8', PointField.FLOAT64, 'velocity [m/s], odom (0 for a static segment)'),
    ('vy', '<f8', PointField.FLOAT64, ''),
    ('cov_xx', '<f8', PointField.FLOAT64, 'position covariance [m^2]'),
    ('cov_xy', '<f8', PointField.FLOAT64, ''),
    ('cov_yy', '<f8', PointField.FLOAT64, ''),
    ('cov_vxvx', '<f8', PointField.FLOAT64, 'velocity covariance [m^2/s^2]'),
    ('cov_vxvy', '<f8', PointField.FLOAT64, ''),
    ('cov_vyvy', '<f8', PointField.FLOAT64, ''),
)
#: The optional fields, after :data:`FIELDS` when written (see the module docstring).
CLASS_FIELDS: tuple[tuple[str, str, int, str], ...] = (
    ('class_id', '<i4', PointField.INT32, "index into the detector's class_names, -1 none"),
    ('class_score', '<f8', PointField.FLOAT64, 'confidence of the class 0..1'),
)
DTYPE = np.dtype([(name, np_type) for name, np_type, _, _ in FIELDS])
#: A point with the class fields.
CLASS_DTYPE = np.dtype([(name, np_type) for name, np_type, _, _ in FIELDS + CLASS_FIELDS])


def _point_fields(dtype: np.dtype[Any],
                  fields: tuple[tuple[str, str, int, str], ...]) -> tuple[PointField, ...]:
    offsets = {name: int(dtype.fields[name][1]) for name, *_ in fields}  # type: ignore[index]
    return tuple(PointField(name=name, offset=offsets[name], datatype=datatype, count=1)
                 for name, _, datatype, _ in fields)


#: The fields of every message, built once: a message's constructor checks each value, which
#: cost more than the rest of the encoding. The list is copied per message; its PointFields
#: are shared and must not be changed by a receiver.
_POINT_FIELDS = _point_fields(DTYPE, FIELDS)
_CLASS_POINT_FIELDS = _point_fields(CLASS_DTYPE, FIELDS + CLASS_FIELDS)
#: A point of DTYPE and of CLASS_DTYPE (packed, little-endian) for ``struct``: writing and
#: reading our own layout row by row costs less than numpy's structured arrays on a few rows.
_ROW = struct.Struct('<' + ''.join({'<u4': 'I', '<i4': 'i', '<f8': 'd'}[t]
                                   for _, t, _, _ in FIELDS))
_CLASS_ROW = struct.Struct(_ROW.format + ''.join({'<i4': 'i', '<f8': 'd'}[t]
                                                 for _, t, _, _ in CLASS_FIELDS))
assert _ROW.size == DTYPE.itemsize and _CLASS_ROW.size == CLASS_DTYPE.itemsize


@dataclass(frozen=True)
class Obstacle:
    """One obstacle (a capsule) in the world frame; see the module docstring."""

    id: int
    kind: int                 # CIRCLE or SEGMENT
    x: float
    y: float
    radius: float
    x2: float | None = None   # None: a circle (the second end is the first)
    y2: float | None = None
    vx: float = 0.0
    vy: float = 0.0
    position_cov: tuple[float, float, float] = (0.0, 0.0, 0.0)   # xx, xy, yy [m^2]
    velocity_cov: tuple[float, float, float] = (0.0, 0.0, 0.0)   # [m^2/s^2]
    stamp_ns: int = 0
    class_id: int = NO_CLASS  # what a camera detection said it is (NO_CLASS: not known)
    class_score: float = 0.0

    @property
    def end(self) -> tuple[float, float]:
        """The segment's second end (a circle's centre)."""
        return (self.x if self.x2 is None else self.x2, self.y if self.y2 is None else self.y2)

    def closest_point(self, px: float, py: float) -> tuple[float, float]:
        """Return the point of the obstacle's segment (its axis) nearest to ``(px, py)``."""
        return closest_on_segment(px, py, self.x, self.y, *self.end)

    def distance(self, px: float, py: float) -> float:
        """Distance [m] from ``(px, py)`` to the obstacle's surface (< 0 inside)."""
        cx, cy = self.closest_point(px, py)
        return math.hypot(px - cx, py - cy) - self.radius


def closest_on_segment(px: float, py: float, ax: float, ay: float, bx: float,
                       by: float) -> tuple[float, float]:
    """Return the point of the segment a-b nearest to p (a when the segment has no length)."""
    dx, dy = bx - ax, by - ay
    n2 = dx * dx + dy * dy
    if n2 <= 0.0:
        return ax, ay
    s = min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / n2))
    return ax + s * dx, ay + s * dy


def _row(o: Obstacle, classes: bool) -> tuple[Any, ...]:
    """Return the values of one point, in :data:`FIELDS` (+ :data:`CLASS_FIELDS`) order."""
    x2, y2 = o.end
    sec, nanosec = divmod(int(o.stamp_ns), NS_PER_S)
    row = (o.id, o.kind, sec, nanosec, o.x, o.y, x2, y2, o.radius, o.vx, o.vy,
           *o.position_cov, *o.velocity_cov)
    return row + (o.class_id, o.class_score) if classes else row


def to_array(obstacles: Sequence[Obstacle], classes: bool = False) -> NDArray[Any]:
    """Return the obstacles as a structured array of :data:`DTYPE` (one row each).

    ``classes``: of :data:`CLASS_DTYPE`, with the class fields.
    """
    out = np.zeros(len(obstacles), dtype=CLASS_DTYPE if classes else DTYPE)
    for i, o in enumerate(obstacles):
        out[i] = _row(o, classes)
    return out


def to_cloud(obstacles: Sequence[Obstacle], stamp_ns: int, frame_id: str,
             out: PointCloud2 | None = None, classes: bool | None = None) -> PointCloud2:
    """Encode ``obstacles`` as a ``PointCloud2`` stamped ``stamp_ns`` in ``frame_id``.

    ``classes``: write the class fields (None: when any obstacle has a class).
    """
    if classes is None:
        classes = any(o.class_id != NO_CLASS for o in obstacles)
    packer = _CLASS_ROW if classes else _ROW
    try:   # the same bytes as to_array(...).tobytes()
        data = b''.join([packer.pack(*_row(o, classes)) for o in obstacles])
    except struct.error as err:   # numpy refused these too (OverflowError)
        raise OverflowError(f'obstacles: a value does not fit its field: {err}') from None
    msg = out if out is not None else PointCloud2()
    ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = frame_id
    msg.height, msg.width = 1, len(obstacles)
    msg.fields = list(_CLASS_POINT_FIELDS if classes else _POINT_FIELDS)
    msg.is_bigendian = False
    msg.point_step = packer.size
    msg.row_step = packer.size * len(obstacles)
    msg.data = data
    msg.is_dense = True
    return msg


class ObstacleEncodingError(ValueError):
    """A point cloud that is not an obstacle message (names the field at fault)."""


def from_cloud(msg: PointCloud2) -> list[Obstacle]:
    """Decode an ``obstacles`` message; the fields are found by name and type.

    The class fields are read when present (both of them), else every obstacle has
    :data:`NO_CLASS`. Raises :class:`ObstacleEncodingError` naming what is missing or
    malformed.
    """
    rows = _own_rows(msg)
    if rows is None:
        have = {f.name for f in msg.fields}
        classes = all(name in have for name, *_ in CLASS_FIELDS)
        names = [name for name, *_ in (FIELDS + CLASS_FIELDS if classes else FIELDS)]
        # tolist(): each point as a tuple of Python numbers in ``names``' order (FIELDS, then
        # CLASS_FIELDS), in one call: indexing a structured row by name cost more than the rest.
        rows = read_fields(msg, names, 'obstacles', ObstacleEncodingError).tolist()
    else:
        classes = len(msg.fields) > len(FIELDS)
    out: list[Obstacle] = []
    for r in rows:
        (ident, kind, sec, nanosec, x, y, x2, y2, radius, vx, vy,
         cxx, cxy, cyy, cvxx, cvxy, cvyy) = r[:len(FIELDS)]
        if kind not in KINDS:
            raise ObstacleEncodingError(f'obstacles: point {len(out)} has kind {kind}')
        circle = kind == CIRCLE
        out.append(Obstacle(
            int(ident), int(kind), float(x), float(y), float(radius),
            None if circle else float(x2), None if circle else float(y2),
            float(vx), float(vy), (float(cxx), float(cxy), float(cyy)),
            (float(cvxx), float(cvxy), float(cvyy)), int(sec) * NS_PER_S + int(nanosec),
            int(r[-2]) if classes else NO_CLASS, float(r[-1]) if classes else 0.0))
    return out


def _own_rows(msg: PointCloud2) -> list[tuple[Any, ...]] | None:
    """Return the points of a message :func:`to_cloud` wrote in this process, or None.

    Its fields are then our own PointField objects (shared, never changed by a receiver: see
    ``_POINT_FIELDS``), so the layout is known and ``struct`` reads the rows; any other
    message (from DDS, or built elsewhere) goes through :func:`read_fields`' checks.
    """
    fields = msg.fields
    for own, packer in ((_POINT_FIELDS, _ROW), (_CLASS_POINT_FIELDS, _CLASS_ROW)):
        if len(fields) == len(own) and all(a is b for a, b in zip(fields, own)):
            n = int(msg.width) * int(msg.height)
            data = msg.data
            if (msg.is_bigendian or int(msg.point_step) != packer.size
                    or len(data) < n * packer.size):
                return None   # the general path says what is wrong
            return list(packer.iter_unpack(memoryview(data)[:n * packer.size]))
    return None


def cloud_stamp_ns(msg: PointCloud2) -> int:
    """Return the stamp of the measurement that produced the message [ns]."""
    return stamp_to_ns(msg.header.stamp)
