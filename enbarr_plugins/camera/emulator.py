"""An emulated camera: a short synthetic video file the camera driver reads like any file.

``write_test_video`` writes a test pattern (colour bars, a moving bar and the frame number,
in digits and as 16 black/white blocks along the top edge that survive JPEG compression)
with ``cv2.VideoWriter`` (Motion-JPEG in AVI, which every OpenCV build reads back).
``read_counter`` decodes the blocks: a test checks which frame it got.

``CameraEmulatorNode`` writes one such file to a temporary directory and registers its path
as the ``camera`` endpoint ``name`` (``emulation``; the driver's ``device: emulated[:NAME]``).
``stall()`` replaces the file with one OpenCV cannot read (a camera that stops delivering:
the driver's next open fails and it retries with backoff), ``resume()`` writes the video
again. ``/diagnostics`` says what it wrote and whether it is stalled.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import os
import shutil
import tempfile
from typing import Any

import cv2
import numpy as np

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins import emulation

BITS = 16       # frame counter bits along the top edge
BLOCK = 16      # [px] per bit


def test_pattern(index: int, width: int, height: int) -> np.ndarray:
    """Return frame ``index`` of the test pattern (bgr8)."""
    bars = np.array([[255, 255, 255], [0, 255, 255], [255, 255, 0], [0, 255, 0],
                     [255, 0, 255], [0, 0, 255], [255, 0, 0], [0, 0, 0]], dtype=np.uint8)
    columns = (np.arange(width) * len(bars) // width)
    frame = np.repeat(bars[columns][np.newaxis], height, axis=0)
    x = (index * 8) % max(1, width)
    frame[height // 2:, x:x + 8] = 128
    cv2.putText(frame, str(index), (width // 8, height * 3 // 4), cv2.FONT_HERSHEY_SIMPLEX,
                max(1.0, height / 160), (255, 255, 255), 3)
    frame[:BLOCK, :BITS * BLOCK] = 0
    for bit in range(BITS):
        if index >> bit & 1:
            frame[:BLOCK, bit * BLOCK:(bit + 1) * BLOCK] = 255
    return frame


def read_counter(frame: np.ndarray) -> int:
    """Return the frame number the top-edge blocks of ``frame`` encode."""
    value = 0
    for bit in range(BITS):
        block = frame[2:BLOCK - 2, bit * BLOCK + 2:(bit + 1) * BLOCK - 2]
        if block.mean() > 127:
            value |= 1 << bit
    return value


def write_test_video(directory: str, width: int, height: int, frame_rate: float,
                     frames: int) -> str:
    """Write ``frames`` test-pattern frames to ``directory``/test_pattern.avi; return the path.

    Written beside and renamed into place, so a reader never opens a half-written file.
    """
    path = os.path.join(directory, 'test_pattern.avi')
    partial = os.path.join(directory, 'test_pattern.partial.avi')
    writer = cv2.VideoWriter(partial, cv2.VideoWriter_fourcc(*'MJPG'), frame_rate,
                             (width, height))
    if not writer.isOpened():
        raise OSError(f'{partial}: OpenCV cannot write Motion-JPEG AVI')
    try:
        for i in range(frames):
            writer.write(test_pattern(i, width, height))
    finally:
        writer.release()
    os.replace(partial, path)
    return path


SPECS = [
    ParamSpec('name', 'default', "Name of the emulated camera (the driver's device: "
              "'emulated' for 'default', else 'emulated:NAME')", read_only=True),
    ParamSpec('width', 640, 'Image width', 'px', 16 * BITS, 4096, read_only=True),
    ParamSpec('height', 480, 'Image height', 'px', 32, 4096, read_only=True),
    ParamSpec('frame_rate', 15.0, 'Frame rate written in the file', 'Hz', 1.0, 120.0,
              read_only=True),
    ParamSpec('duration', 2.0, 'Length of the video (the driver loops it)', 's', 0.1, 60.0,
              read_only=True),
]


@dataclass(frozen=True)
class CameraEmulatorSettings:
    """Settings of ``CameraEmulatorNode``."""

    name: str
    width: int         # [px]
    height: int        # [px]
    frame_rate: float  # [Hz]
    duration: float    # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> CameraEmulatorSettings:
        """Build from the parameters."""
        return cls(name=v['name'], width=v['width'], height=v['height'],
                   frame_rate=v['frame_rate'], duration=v['duration'])


class CameraEmulatorNode(EnbarrNode):
    """Writes the test video and offers it as the emulated camera; see the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (orchestrator.build_nodes)

    def __init__(self, node_name: str = 'camera_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: CameraEmulatorSettings
        self.bind_settings(SPECS, CameraEmulatorSettings.from_params, self._apply)
        self.directory = tempfile.mkdtemp(prefix='enbarr-camera-')
        self.stalled = False
        self.path = self._write()
        emulation.register('camera', self.settings.name, self.path, owner=self)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: CameraEmulatorSettings) -> None:
        self.settings = settings

    def _write(self) -> str:
        s = self.settings
        self.frames = max(1, round(s.frame_rate * s.duration))
        return write_test_video(self.directory, s.width, s.height, s.frame_rate, self.frames)

    def stall(self) -> None:
        """Replace the video with a file OpenCV cannot read: the camera stops delivering."""
        partial = self.path + '.partial'
        with open(partial, 'wb') as f:
            f.write(b'not a video')
        os.replace(partial, self.path)
        self.stalled = True

    def resume(self) -> None:
        """Write the video again: frames return."""
        self._write()
        self.stalled = False

    def _report(self) -> None:
        s = self.settings
        self.publish_diagnostics(1 if self.stalled else 0,
                                 'stalled' if self.stalled else 'emulating', {
                                     'path': self.path, 'frames': self.frames,
                                     'size': f'{s.width}x{s.height}',
                                     'frame_rate': s.frame_rate})

    def destroy_node(self) -> None:
        """Withdraw the endpoint and delete the file."""
        emulation.unregister('camera', self.settings.name, self.path)
        shutil.rmtree(self.directory, ignore_errors=True)
        super().destroy_node()
