"""Camera calibration files in the ROS camera_info YAML format.

The layout ``camera_calibration_parsers`` writes and reads (ros-perception/image_common,
camera_calibration_parsers/src/parse_yml.cpp) and the ``cameracalibrator`` saves::

    image_width: 640
    image_height: 480
    camera_name: narrow_stereo
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, t1, t2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [...]}
    projection_matrix: {rows: 3, cols: 4, data: [...]}

A malformed file is a ``ValueError`` naming the file and the key.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

import yaml


@dataclass(frozen=True)
class Calibration:
    """One camera's calibration (sensor_msgs/CameraInfo fields)."""

    width: int
    height: int
    camera_name: str
    k: tuple[float, ...]   # 3x3 row-major
    distortion_model: str
    d: tuple[float, ...]
    r: tuple[float, ...]   # 3x3
    p: tuple[float, ...]   # 3x4


def _matrix(path: str, doc: dict[str, Any], key: str, rows: int, cols: int | None
            ) -> tuple[float, ...]:
    value = doc.get(key)
    if not isinstance(value, dict):
        raise ValueError(f'{path}: {key}: missing or not a mapping with rows, cols, data')
    r, c, data = value.get('rows'), value.get('cols'), value.get('data')
    if r != rows or (cols is not None and c != cols):
        want = f'{rows}x{cols}' if cols is not None else f'{rows}xN'
        raise ValueError(f'{path}: {key}: expected a {want} matrix, got rows={r!r}, '
                         f'cols={c!r}')
    if not isinstance(data, list) or not isinstance(c, int) or len(data) != r * c:
        raise ValueError(f'{path}: {key}.data: expected {r}*{c} numbers, got {data!r}')
    try:
        numbers = tuple(float(x) for x in data)
    except (TypeError, ValueError):
        raise ValueError(f'{path}: {key}.data: not all numbers: {data!r}') from None
    if not all(math.isfinite(x) for x in numbers):
        raise ValueError(f'{path}: {key}.data: not finite: {data!r}')
    return numbers


def load_calibration(path: str) -> Calibration:
    """Read and check a camera_info YAML file; ``ValueError`` names the file and key."""
    try:
        text = Path(path).read_text()
    except OSError as err:
        raise ValueError(f'{path}: cannot read: {err.strerror or err}') from err
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ValueError(f'{path}: not YAML: {err}') from err
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: expected a mapping of camera_info keys')
    sizes = {}
    for key in ('image_width', 'image_height'):
        value = doc.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise ValueError(f'{path}: {key}: expected a positive integer, got {value!r}')
        sizes[key] = value
    model = doc.get('distortion_model')
    if not isinstance(model, str) or not model:
        raise ValueError(f'{path}: distortion_model: expected a name (plumb_bob, '
                         f'rational_polynomial, equidistant), got {model!r}')
    return Calibration(
        width=sizes['image_width'], height=sizes['image_height'],
        camera_name=str(doc.get('camera_name', '')),
        k=_matrix(path, doc, 'camera_matrix', 3, 3), distortion_model=model,
        d=_matrix(path, doc, 'distortion_coefficients', 1, None),
        r=_matrix(path, doc, 'rectification_matrix', 3, 3),
        p=_matrix(path, doc, 'projection_matrix', 3, 4))
