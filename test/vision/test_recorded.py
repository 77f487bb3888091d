"""Calibration data from bag messages (pure): images, scans, and the board's still poses."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision import recorded

pytestmark = pytest.mark.unit


def _header(t_ns: int) -> SimpleNamespace:
    return SimpleNamespace(stamp=SimpleNamespace(sec=t_ns // 10**9, nanosec=t_ns % 10**9))


def _image(encoding: str, data: np.ndarray, step: int | None = None) -> SimpleNamespace:
    h, w = data.shape[:2]
    return SimpleNamespace(header=_header(0), encoding=encoding, height=h, width=w,
                           step=step or data.strides[0], data=data.tobytes())


def test_image_encodings_become_bgr() -> None:
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[0, 0] = (10, 20, 30)
    assert recorded.image_array(_image('bgr8', bgr))[0, 0].tolist() == [10, 20, 30]
    assert recorded.image_array(_image('rgb8', bgr))[0, 0].tolist() == [30, 20, 10]
    mono = np.full((2, 3), 7, np.uint8)
    assert recorded.image_array(_image('mono8', mono)).shape == (2, 3, 3)
    # rows padded to 16 bytes
    padded = np.zeros((2, 16), np.uint8)
    padded[:, :9] = bgr.reshape(2, 9)
    img = recorded.image_array(SimpleNamespace(header=_header(0), encoding='bgr8', height=2,
                                               width=3, step=16, data=padded.tobytes()))
    assert img[0, 0].tolist() == [10, 20, 30] and img.flags.writeable
    with pytest.raises(CalibrationError, match="encoding 'yuv422'"):
        recorded.image_array(_image('yuv422', bgr))
    with pytest.raises(CalibrationError, match='do not hold it'):
        recorded.image_array(SimpleNamespace(header=_header(0), encoding='bgr8', height=4,
                                             width=3, step=9, data=bgr.tobytes()))


def test_compressed_images_are_decoded() -> None:
    bgr = np.zeros((4, 4, 3), np.uint8)
    bgr[:, :, 2] = 200
    ok, png = cv2.imencode('.png', bgr)
    msg = SimpleNamespace(header=_header(0), format='png', data=png.tobytes())
    assert recorded.image_array(msg)[0, 0].tolist() == [0, 0, 200]


def test_scan_points_drop_non_finite_ranges() -> None:
    msg = SimpleNamespace(ranges=[1.0, float('inf'), 2.0], angle_min=0.0,
                          angle_increment=np.pi / 2)
    assert recorded.scan_xy(msg) == pytest.approx(np.array([[1.0, 0.0], [-2.0, 0.0]]))


def _stream(events: list[tuple[str, float, object]]):
    """('image', t [s], corners or None) and ('scan', t [s], xy) as messages."""
    for kind, t, payload in events:
        msg = SimpleNamespace(header=_header(int(t * 1e9)))
        if kind == 'image':
            msg.encoding, msg.height, msg.width, msg.step = 'mono8', 1, 1, 1
            msg.data = b'\0'
            msg.payload = payload
        else:
            msg.ranges, msg.angle_min, msg.angle_increment = payload, 0.0, 0.1
        yield kind, msg


def test_still_poses_are_split_by_motion_and_by_a_lost_board(monkeypatch) -> None:
    c0 = np.zeros((4, 2))
    events: list[tuple[str, float, object]] = []
    for k in range(7):                                 # pose A: still for 0.6 s
        events.append(('image', 0.1 * k, c0 + 0.1 * (k % 2)))
        events.append(('scan', 0.1 * k + 0.05, [1.0]))
    for k in range(7):                                 # moved by 5 px: pose B
        events.append(('image', 1.0 + 0.1 * k, c0 + 5.0))
        events.append(('scan', 1.0 + 0.1 * k + 0.05, [2.0]))
    events.append(('image', 1.8, None))                # board lost
    for k in range(3):                                 # held only 0.2 s: dropped
        events.append(('image', 2.0 + 0.1 * k, c0 + 9.0))
    seen = iter([e[2] for e in events if e[0] == 'image'])
    poses = recorded.board_poses(_stream(events), 2, 2, corners_of=lambda img, c, r: next(seen))
    assert len(poses) == 2
    a, b = poses
    assert a.images == 7 and len(a.scans) == 6          # the scans inside 0.0 .. 0.6 s
    assert a.corners == pytest.approx(c0 + 3 / 7 * 0.1)
    assert b.images == 7 and len(b.scans) == 6
    assert all(s[0, 0] == pytest.approx(2.0) for s in b.scans)
