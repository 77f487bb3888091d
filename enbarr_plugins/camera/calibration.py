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

A malformed file is a ``ValueError`` naming the file and the key. ``save_calibration`` writes
the same layout (``enbarr calibrate camera``, and the driver's ``set_camera_info``), replacing
the file in one step so a reader never sees half of it.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
from pathlib import Path
import tempfile
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


def check_calibration(cal: Calibration) -> None:
    """Raise ``ValueError`` naming the field when ``cal`` is not a usable calibration."""
    if cal.width <= 0 or cal.height <= 0:
        raise ValueError(f'image size must be positive, got {cal.width}x{cal.height}')
    for name, values, n in (('K', cal.k, 9), ('R', cal.r, 9), ('P', cal.p, 12)):
        if len(values) != n:
            raise ValueError(f'{name}: expected {n} numbers, got {len(values)}')
    for name, values in (('K', cal.k), ('D', cal.d), ('R', cal.r), ('P', cal.p)):
        if not all(math.isfinite(x) for x in values):
            raise ValueError(f'{name}: not finite: {list(values)}')
    if not cal.distortion_model:
        raise ValueError('distortion_model: empty')
    if not (cal.k[0] > 0 and cal.k[4] > 0 and cal.k[8] == 1.0):
        raise ValueError(f'K: not a camera matrix (fx, fy > 0, K[2][2] = 1): {list(cal.k)}')


def _row(values: tuple[float, ...]) -> str:
    return '[' + ', '.join(repr(float(x)) for x in values) + ']'


def format_calibration(cal: Calibration) -> str:
    """Return ``cal`` as camera_info YAML (the layout in the module docstring)."""
    check_calibration(cal)
    name = cal.camera_name or 'camera'
    return '\n'.join([
        f'image_width: {cal.width}',
        f'image_height: {cal.height}',
        f'camera_name: {yaml.safe_dump(name, default_style=None).splitlines()[0]}',
        'camera_matrix:', '  rows: 3', '  cols: 3', f'  data: {_row(cal.k)}',
        f'distortion_model: {cal.distortion_model}',
        'distortion_coefficients:', '  rows: 1', f'  cols: {len(cal.d)}',
        f'  data: {_row(cal.d)}',
        'rectification_matrix:', '  rows: 3', '  cols: 3', f'  data: {_row(cal.r)}',
        'projection_matrix:', '  rows: 3', '  cols: 4', f'  data: {_row(cal.p)}',
        ''])


def save_calibration(cal: Calibration, path: str) -> None:
    """Write ``cal`` to ``path`` atomically (a temporary file beside it, then a rename).

    ``ValueError`` for a malformed calibration; ``OSError`` when the file cannot be written.
    """
    text = format_calibration(cal)
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f'.{target.name}.', suffix='.tmp',
                               dir=target.parent if str(target.parent) else '.')
    try:
        os.chmod(tmp, 0o644)   # mkstemp's 0600 would hide it from a driver run as another user
        with os.fdopen(fd, 'w') as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


#: Coefficients of each distortion model (REP-104, sensor_msgs/distortion_models.hpp).
DISTORTION_LENGTHS = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}


def calibration_of(info: Any, camera_name: str) -> Calibration:
    """Return the ``Calibration`` a sensor_msgs/CameraInfo carries; ``ValueError`` says what."""
    if info.width <= 0 or info.height <= 0:
        raise ValueError(f'image size {info.width}x{info.height}: not positive')
    want = DISTORTION_LENGTHS.get(info.distortion_model)
    if want is None:
        raise ValueError(f'distortion_model {info.distortion_model!r}: not one of '
                         f'{", ".join(DISTORTION_LENGTHS)}')
    if len(info.d) != want:
        raise ValueError(f'{info.distortion_model} has {want} coefficients, D has {len(info.d)}')
    cal = Calibration(width=int(info.width), height=int(info.height), camera_name=camera_name,
                      k=tuple(float(x) for x in info.k),
                      distortion_model=str(info.distortion_model),
                      d=tuple(float(x) for x in info.d), r=tuple(float(x) for x in info.r),
                      p=tuple(float(x) for x in info.p))
    check_calibration(cal)
    if cal.p[0] <= 0 or cal.p[5] <= 0:
        raise ValueError(f'P: not a projection matrix (fx, fy > 0): {list(cal.p)}')
    return cal
