"""An emulated camera: a short synthetic video file the camera driver reads like any file.

``CameraEmulatorNode``, once started, writes a test video (``pattern_video``: colour bars, a
moving bar and the frame number, Motion-JPEG in AVI) to a temporary directory, from a child
process so that the encoder's memory stays out of the vessel's, and registers its path as the
``camera`` endpoint ``name`` (``emulation``; the driver's ``device: emulated[:NAME]``).
``stall()`` replaces the file with one OpenCV cannot read (a camera that stops delivering:
the driver's next open fails and it retries with backoff), ``resume()`` writes the video
again.
``/diagnostics`` says what it wrote and whether it is stalled.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import os
import shutil
import tempfile
from typing import Any

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins import emulation
from enbarr_plugins.camera.pattern_video import BITS, write_in_child

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

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'camera_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: CameraEmulatorSettings
        self.bind_settings(SPECS, CameraEmulatorSettings.from_params, self._apply)
        self.directory: str | None = None
        self.path: str | None = None
        self.frames = 0
        self.stalled = False
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Write the video and offer it (the camera is plugged in), then start the sources."""
        if self.path is None:
            self.path = self._write()
            emulation.register('camera', self.settings.name, self.path, owner=self)
        super().start()

    def _apply(self, settings: CameraEmulatorSettings) -> None:
        self.settings = settings

    def _write(self) -> str:
        if self.directory is None:
            self.directory = tempfile.mkdtemp(prefix='enbarr-camera-')
        s = self.settings
        self.frames = max(1, round(s.frame_rate * s.duration))
        return write_in_child(self.directory, s.width, s.height, s.frame_rate, self.frames)

    def stall(self) -> None:
        """Replace the video with a file OpenCV cannot read: the camera stops delivering."""
        if self.path is None:
            raise RuntimeError('camera emulator: stall() before start()')
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
        state = 'not started' if self.path is None else 'stalled' if self.stalled else 'emulating'
        self.publish_diagnostics(1 if self.stalled else 0, state, {
            'path': self.path or '', 'frames': self.frames, 'size': f'{s.width}x{s.height}',
            'frame_rate': s.frame_rate})

    def destroy_node(self) -> None:
        """Withdraw the endpoint and delete the file."""
        if self.path is not None:
            emulation.unregister('camera', self.settings.name, self.path)
        if self.directory is not None:
            shutil.rmtree(self.directory, ignore_errors=True)
        super().destroy_node()
