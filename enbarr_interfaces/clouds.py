"""Structured data in a ``sensor_msgs/PointCloud2``: the reading every such encoding shares.

``obstacles`` and ``detections`` carry one point per item with named fields (no custom message
builds in a pip install). A reader finds the fields by name, whatever their order, offsets and
numeric type, so that a writer may add fields later; this module is that reader.
"""

from __future__ import annotations

from collections.abc import Sequence
import functools
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import PointCloud2, PointField

#: ``sensor_msgs/PointField`` datatype -> numpy type (little-endian).
NUMPY_OF = {PointField.UINT32: '<u4', PointField.FLOAT64: '<f8', PointField.FLOAT32: '<f4',
            PointField.INT32: '<i4', PointField.UINT8: 'u1', PointField.INT8: 'i1',
            PointField.UINT16: '<u2', PointField.INT16: '<i2'}


def read_fields(msg: PointCloud2, names: Sequence[str], what: str,
                error: type[ValueError]) -> NDArray[Any]:
    """Return the points of ``msg`` as a structured array of the fields ``names``.

    Each field is found by name and read in its own type (one element, little-endian). Raises
    ``error`` with a message that starts with ``what`` and names what is missing or malformed.
    """
    if msg.is_bigendian:
        raise error(f'{what}: big-endian point clouds are not read')
    have = {f.name: f for f in msg.fields}
    missing = [name for name in names if name not in have]
    if missing:
        raise error(f'{what}: missing field(s) {", ".join(missing)}')
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    data = bytes(msg.data)
    if len(data) < n * step:
        raise error(f'{what}: {len(data)} bytes of data for {n} points of {step} bytes')
    formats, offsets = [], []
    for name in names:
        f = have[name]
        np_type = NUMPY_OF.get(f.datatype)
        if np_type is None or f.count != 1:
            raise error(f'{what}: field {name!r} has datatype {f.datatype} x {f.count}')
        if f.offset + np.dtype(np_type).itemsize > step:
            raise error(f'{what}: field {name!r} at offset {f.offset} does not fit a point of '
                        f'{step} bytes')
        formats.append(np_type)
        offsets.append(f.offset)
    view = _view(tuple(names), tuple(formats), tuple(offsets), step)
    return np.frombuffer(data[:n * step], dtype=view)


@functools.lru_cache(maxsize=64)
def _view(names: tuple[str, ...], formats: tuple[str, ...], offsets: tuple[int, ...],
          step: int) -> np.dtype[Any]:
    # One layout per writer: building the structured dtype cost more than reading the points
    # of an obstacles message, read once per scan by every subscriber.
    return np.dtype({'names': list(names), 'formats': list(formats), 'offsets': list(offsets),
                     'itemsize': step})
