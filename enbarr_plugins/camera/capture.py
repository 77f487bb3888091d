"""How the camera driver names and opens a source through OpenCV's videoio.

``device`` names a V4L2 index (``'0'``) or device (``'/dev/video0'``, opened with the V4L2
backend), a video file (any format the OpenCV FFmpeg backend reads), or ``'emulated[:NAME]'``
(the video file a ``camera_emulator`` node of this process wrote, read like any file).
Reference: OpenCV 4 videoio (``cv::VideoCapture``, ``CAP_PROP_*``). No ROS here: the driver
and ``enbarr check-device camera`` both open sources with it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
import os
from typing import Any

import cv2

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation


@dataclass(frozen=True)
class Source:
    """What ``device`` names: a V4L2 index, or a file path (emulated: the emulator's file)."""

    index: int | None
    path: str | None
    emulated: bool

    @property
    def is_file(self) -> bool:
        """Whether frames come from a video file."""
        return self.index is None


def parse_device(value: str) -> Source:
    """Return the source ``device`` names; ``ValueError`` naming ``device`` when empty."""
    text = value.strip()
    if not text:
        raise ValueError("device: empty; give a V4L2 index ('0'), '/dev/videoN', a video "
                         "file or 'emulated'")
    if emulation.is_emulated(text):
        return Source(None, None, True)
    if text.isdigit():
        return Source(int(text), None, False)
    if text.startswith('/dev/video') and text[len('/dev/video'):].isdigit():
        return Source(int(text[len('/dev/video'):]), None, False)
    return Source(None, text, False)


def open_capture(source: Source, device: str, size: tuple[int, int] = (0, 0),
                 frame_rate: float = 0.0) -> Any:
    """Open the source with OpenCV; ``DeviceError`` naming it when it cannot.

    ``size`` (width, height [px]; 0: the device's) and ``frame_rate`` [Hz] (0: the device's)
    are asked of a V4L2 device; a file gives what it holds.
    """
    if source.emulated:
        path = emulation.lookup('camera', device)
        return _open_file(path, device)
    if source.is_file:
        return _open_file(source.path, device)
    with quiet_opencv():  # OpenCV logs its own warning lines for an absent device
        cap = cv2.VideoCapture(source.index, cv2.CAP_V4L2)
    if not cap.isOpened():
        cap.release()
        raise DeviceError(f'camera /dev/video{source.index}: cannot open (absent, or in use '
                          'by another program?)')
    if size[0] and size[1]:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
    if frame_rate:
        cap.set(cv2.CAP_PROP_FPS, frame_rate)
    cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a queue of old ones
    return cap




@contextmanager
def quiet_opencv() -> Iterator[None]:
    """Silence OpenCV's own log lines (the ``DeviceError`` says what went wrong)."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


def _open_file(path: str, device: str) -> Any:
    if not os.path.isfile(path):
        raise DeviceError(f'camera {device}: no such video file {path}')
    with quiet_opencv():
        cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        cap.release()
        raise DeviceError(f'camera {device}: OpenCV cannot read {path} as a video')
    return cap


def describe(cap: Any) -> str:
    """Return resolution, rate and backend of an open capture."""
    w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    return f'{w}x{h} at {cap.get(cv2.CAP_PROP_FPS):g} fps ({cap.getBackendName()})'
