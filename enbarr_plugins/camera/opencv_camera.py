"""Camera through OpenCV: ``camera/image_raw`` (bgr8), its JPEG and ``camera/camera_info``.

The ``device`` parameter names the source (``capture``): a V4L2 index or device, a video
file, or ``'emulated[:NAME]'`` (the video file a ``camera_emulator`` node of this process
wrote; from there the driver reads it exactly like a file). ``frame_rate``,
``width``/``height`` are asked of a V4L2 device (the driver publishes what the device gives
and warns when it differs); a file is read at ``frame_rate`` and starts over at its end
(``loop``) or stops there. ``calibration_file`` is a ROS camera_info YAML file
(``calibration``); without one CameraInfo carries only the image size (uncalibrated). What is
published, and the JPEG on ``camera/image_raw/compressed`` (``jpeg_quality``, ``publish_raw``),
is every camera's (``common.ImageOutput``).

``camera/set_camera_info`` (sensor_msgs/srv/SetCameraInfo, camera_info_manager's name) stores
a calibration in ``calibration_file`` (replaced atomically) and publishes it from then on: the
"commit" of ROS's cameracalibrator and of ``enbarr calibrate camera --commit``. It refuses
(success false, a status message saying why) when no ``calibration_file`` is set, when the
message is malformed (image size other than the frames', a distortion of the wrong length, a
K that is no camera matrix) or when the file cannot be written. A ``calibration_file`` not
there yet is no calibration yet (the first commit writes it).

Capture runs on the node's own loop thread (``cv2.VideoCapture.read`` blocks until a frame);
opening the device too, once the node is started. Faults: a source that cannot be opened is
a ``DeviceError`` (absent: retried with backoff); a read that fails (unplugged, a file that
cannot be read again) is a device fault; no frame for ``stall_timeout`` while the source
should deliver is a stall, reported as a device fault from the supervision timer; the
capture is then released by the loop thread when its read returns and the device is opened
again. Frames are stamped on the node clock when ``read`` returns.
Reference: OpenCV 4 videoio (``cv::VideoCapture``, ``CAP_PROP_*``), REP-104 (CameraInfo).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import os
import threading
import time
from typing import Any

from sensor_msgs.srv import SetCameraInfo

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.camera.calibration import Calibration, load_calibration
from enbarr_plugins.camera.capture import describe, open_capture, parse_device, Source
from enbarr_plugins.camera.common import (
    camera_info, ImageOutput, OUTPUT_SPECS, store_camera_info)

SPECS = [
    ParamSpec('device', '0', "Source: V4L2 index ('0'), device ('/dev/video0'), a video file, "
              "or 'emulated[:NAME]'", read_only=True),
    ParamSpec('frame_rate', 15.0, 'Frames per second asked of the device; the read rate of '
              'a file', 'Hz', 1.0, 120.0, read_only=True),
    ParamSpec('width', 640, 'Image width asked of a V4L2 device (0: its default)', 'px', 0,
              8192, read_only=True),
    ParamSpec('height', 480, 'Image height asked of a V4L2 device (0: its default)', 'px', 0,
              8192, read_only=True),
    ParamSpec('calibration_file', '', 'ROS camera_info YAML file (empty: uncalibrated; not '
              'there yet: uncalibrated until set_camera_info writes it)', read_only=True),
    ParamSpec('loop', True, 'A video file starts over at its end (false: publishing stops '
              'there)', read_only=True),
    ParamSpec('stall_timeout', 2.0, 'No frame for this long is a stalled device (fault)', 's',
              0.1, 60.0),
    *OUTPUT_SPECS,
]

@dataclass(frozen=True)
class CameraSettings:
    """Settings of ``CameraNode``."""

    device: str
    source: Source
    frame_rate: float              # [Hz]
    width: int                     # [px], 0: the device's
    height: int                    # [px]
    calibration_file: str
    calibration: Calibration | None
    loop: bool
    stall_timeout: float           # [s]
    jpeg_quality: int = 80
    publish_raw: bool = True

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> CameraSettings:
        """Build from the parameters; a malformed calibration file names file and key."""
        calibration = None
        # A file not there yet is no calibration yet (camera_info_manager's rule): the first
        # set_camera_info creates it. One that is there must be right.
        if v['calibration_file'] and os.path.exists(v['calibration_file']):
            try:
                calibration = load_calibration(v['calibration_file'])
            except ValueError as err:
                raise ValueError(f'calibration_file: {err}') from err
        return cls(device=v['device'], source=parse_device(v['device']),
                   frame_rate=v['frame_rate'], width=v['width'], height=v['height'],
                   calibration_file=v['calibration_file'], calibration=calibration,
                   loop=v['loop'], stall_timeout=v['stall_timeout'],
                   jpeg_quality=int(v['jpeg_quality']), publish_raw=v['publish_raw'])


class CameraNode(SensorDriver):
    """Publishes frames of an OpenCV source; see the module docstring."""

    def __init__(self, node_name: str = 'camera', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: CameraSettings
        self.bind_settings(SPECS, CameraSettings.from_params, self._apply)
        s = self.settings
        self.device = f'camera {s.device}'
        self.output = ImageOutput(self, s.publish_raw)
        self._cap: Any = None
        self._cap_lock = threading.Lock()
        self._reading = False
        self._last_frame_ns = 0
        self._size_warned = False
        self.ended = False
        self.read_failures = 0
        self.stalls = 0
        self.description = ''
        self._frame_size: tuple[int, int] | None = None   # (width, height) of the last frame
        self.create_service(SetCameraInfo, topics.CAMERA_SET_INFO, self._set_camera_info)
        self._loop = self.create_rate_loop(s.frame_rate, self._tick)
        if s.calibration_file and s.calibration is None:
            self.get_logger().warn(f'{self.device}: no calibration file {s.calibration_file} '
                                   'yet: uncalibrated until set_camera_info stores one')
        self.open_on(self._loop)  # opening a source may block: never on the executor

    def _apply(self, settings: CameraSettings) -> None:
        self.settings = settings
        self._stall_ns = int(settings.stall_timeout * 1e9)

    # -- device lifecycle ---------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the source and note what it gives."""
        s = self.settings
        cap = open_capture(s.source, s.device, (s.width, s.height), s.frame_rate)
        self.description = describe(cap)
        self.get_logger().info(f'{self.device}: {self.description}')
        with self._cap_lock:
            self._cap = cap
        self.ended = False
        self._last_frame_ns = time.monotonic_ns()

    def close_device(self) -> None:
        """Release the capture, or leave that to the capture thread while it reads."""
        with self._cap_lock:
            cap, self._cap = self._cap, None
            if cap is not None and not self._reading:
                cap.release()

    def supervise(self) -> None:
        """Report a stall: no frame for ``stall_timeout`` while the source should deliver."""
        if not self.connected or self.ended:
            return
        idle = time.monotonic_ns() - self._last_frame_ns
        if idle > self._stall_ns:
            self.stalls += 1
            self.device_fault(DeviceError(f'no frame for {idle * 1e-9:.1f} s (stalled)'))

    # -- capture thread -----------------------------------------------------------------------
    def _tick(self) -> None:
        if not self.connected:
            self.open_if_requested()
            return
        with self._cap_lock:
            cap = self._cap
            if cap is None or self.ended:
                return
            self._reading = True
        try:
            ok, frame = cap.read()
        finally:
            with self._cap_lock:
                self._reading = False
                closed = self._cap is not cap
        if closed:
            cap.release()  # faulted (stall) while this read blocked
            return
        if not ok:
            self._read_failed(cap)
            return
        self._publish(frame)

    def _read_failed(self, cap: Any) -> None:
        s = self.settings
        if s.source.is_file:
            if not s.loop:
                self.ended = True
                self.get_logger().info(f'{self.device}: end of the video file')
                return
            try:  # start over: open the file again (it may have been replaced)
                new = open_capture(s.source, s.device)
            except DeviceError as err:
                self.device_fault(err)
                return
            with self._cap_lock:
                if self._cap is cap:
                    self._cap = new
                    new = None
            cap.release()
            if new is not None:
                new.release()
            return
        self.read_failures += 1
        self.device_fault(DeviceError('read failed (unplugged?)'))

    def _publish(self, frame: Any) -> None:
        if not self.started:  # a source: silent before start and after stop
            return
        stamp = self.get_clock().now().to_msg()
        self._last_frame_ns = time.monotonic_ns()
        h, w = frame.shape[:2]
        self._frame_size = (w, h)
        s = self.settings
        if not self._size_warned and not s.source.is_file and s.width and s.height and (
                (w, h) != (s.width, s.height)):
            self._size_warned = True
            self.get_logger().warn(f'{self.device}: gives {w}x{h}, not the {s.width}x'
                                   f'{s.height} asked')
        self.output.publish(frame, stamp, camera_info(s.calibration, w, h), s.jpeg_quality)
        self.sample_received()

    def _set_camera_info(self, request: SetCameraInfo.Request,
                         response: SetCameraInfo.Response) -> SetCameraInfo.Response:
        """Store and publish a calibration (see the module docstring); refuse with a reason."""
        cal = store_camera_info(self, self.device, self.settings.calibration_file,
                                self.settings.calibration, self._frame_size, request, response)
        if cal is not None:
            self._apply(replace(self.settings, calibration=cal))
        return response

    def status_values(self) -> dict[str, Any]:
        """Return frame counts, stalls and what the source gives."""
        values = super().status_values()
        values.update({'source': self.description, 'stalls': self.stalls,
                       'read_failures': self.read_failures, 'ended': self.ended,
                       'overruns': self._loop.overruns})
        return values

    def destroy_node(self) -> None:
        """Stop the capture thread, release the source, destroy the node."""
        self.stop()
        self.close_device()
        super().destroy_node()

