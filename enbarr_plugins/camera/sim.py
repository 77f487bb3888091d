"""Simulated camera (``sim_camera``): the profile's world as the vessel's camera sees it.

It renders the profile's ``world`` (``EnbarrNode.world``) with ``sim_render`` from the
camera's mount, the frame tree's ``base_link -> frame_id`` (``camera_optical_frame``: manual
section 1.5, on a rod behind the lidar, looking ahead along surge), at the simulated vessel's
true pose (``sim/odometry``), and publishes what the real driver (``camera``) publishes
(``common.ImageOutput``): ``camera/image_raw`` (bgr8), ``camera/image_raw/compressed`` (JPEG)
and ``camera/camera_info``.

The intrinsics: a ROS camera_info YAML (``calibration_file``, as the real driver's; its size
is the image's), or without one a pinhole of ``focal_length`` centred on a ``width`` x
``height`` image with ``distortion`` (plumb_bob k1, k2, p1, p2, k3). The default distortion is
a mild barrel, an ESTIMATE of a wide lens (the manual gives no calibration); the camera_info
published is the model rendered, so a consumer that undistorts with it gets straight lines.

Time, as ``sim_lidar``: the truth's stamps schedule the frames, one every ``1 / frame_rate``
of the node clock (simulated time in a scenario). A frame is rendered at one instant: the
truth's pose and the world at that stamp (``EnbarrNode.world_time``), and carries that stamp.
Rendering and encoding take milliseconds, so they run on the node's own thread: the truth's
callback only hands the latest due frame over (a frame still waiting when the next is due is
replaced and counted, ``skipped``), and the executor is never held by the camera.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import threading
from typing import Any

from nav_msgs.msg import Odometry

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins.camera.calibration import Calibration, load_calibration
from enbarr_plugins.camera.common import camera_info, ImageOutput, OUTPUT_SPECS
from enbarr_plugins.camera.sim_render import Look, PinholeModel, SimulatedCamera
from enbarr_plugins.sim_sensor import TruthSensor

#: The render thread looks for a due frame this many times per frame period.
POLLS_PER_FRAME = 4

SPECS = [
    ParamSpec('frame_id', topics.CAMERA_OPTICAL_FRAME, "The camera's optical frame (REP-103: "
              'z ahead, x right, y down); the frame tree places it on the vessel',
              read_only=True),
    ParamSpec('frame_rate', 15.0, 'Frames per second of truth time', 'Hz', 1.0, 60.0,
              read_only=True),
    ParamSpec('calibration_file', '', 'ROS camera_info YAML file of the intrinsics (empty: '
              'width, height, focal_length and distortion below)', read_only=True),
    ParamSpec('width', 640, 'Image width without a calibration file', 'px', 16, 4096,
              read_only=True),
    ParamSpec('height', 480, 'Image height without a calibration file', 'px', 16, 4096,
              read_only=True),
    ParamSpec('focal_length', 500.0, 'fx = fy without a calibration file (500 px at 640 px '
              'wide: 65 deg across)', 'px', 10.0, 10000.0, read_only=True),
    ParamSpec('distortion', [-0.12, 0.02, 0.0, 0.0, 0.0], 'plumb_bob k1, k2, p1, p2, k3 '
              'without a calibration file (ESTIMATE: a mild barrel)', '', -10.0, 10.0,
              read_only=True),
    ParamSpec('seed', 1, 'Seed of the water texture', '', 0, 2**31 - 1, read_only=True),
    *OUTPUT_SPECS,
]


@dataclass(frozen=True)
class SimCameraSettings:
    """Settings of ``SimCameraNode`` (see ``SPECS``)."""

    frame_id: str
    frame_rate: float              # [Hz]
    model: PinholeModel
    calibration: Calibration       # what camera_info carries: the model rendered
    seed: int
    jpeg_quality: int
    publish_raw: bool

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimCameraSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        frame_id = v['frame_id'].strip()
        if not frame_id or frame_id.startswith('/') or ' ' in frame_id:
            raise ValueError(f"frame_id: a frame name such as 'camera_optical_frame' (no "
                             f"leading '/', no spaces), got {v['frame_id']!r}")
        if v['calibration_file']:
            try:
                cal = load_calibration(v['calibration_file'])
                model = PinholeModel(cal.width, cal.height, cal.k, cal.d, cal.distortion_model)
            except ValueError as err:
                raise ValueError(f'calibration_file: {err}') from err
        else:
            d = tuple(float(x) for x in v['distortion'])
            if len(d) != 5:
                raise ValueError(f'distortion: expected k1, k2, p1, p2, k3 (5 numbers), got '
                                 f'{len(d)}')
            model = PinholeModel.nominal(int(v['width']), int(v['height']),
                                         v['focal_length'], d)
            cal = Calibration(model.width, model.height, 'sim_camera', model.k,
                              model.distortion_model, model.d,
                              (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), model.projection)
        return cls(frame_id, v['frame_rate'], model, cal, int(v['seed']),
                   int(v['jpeg_quality']), v['publish_raw'])


class SimCameraNode(TruthSensor):
    """See the module docstring."""

    def __init__(self, node_name: str = 'camera', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimCameraSettings
        self.bind_settings(SPECS, SimCameraSettings.from_params, self._apply)
        s = self.settings
        mount = self.mount(s.frame_id, 'camera')
        try:
            self.camera = SimulatedCamera(s.model, mount, Look(seed=s.seed))
        except ValueError as err:
            raise ConfigurationError(f'node {self.get_name()!r}: {err}') from err
        self.output = ImageOutput(self, s.publish_raw)
        self.frames = 0
        self.skipped = 0
        self.truths = 0
        self._t0_ns: int | None = None  # the first truth's stamp: frame 0
        self._k = 0  # the next frame's number
        self._rendering = False
        self._due: tuple[Any, float, float, float, float, float] | None = None
        self._lock = threading.Lock()
        self._loop = self.create_rate_loop(s.frame_rate * POLLS_PER_FRAME, self._render_due)
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def _apply(self, s: SimCameraSettings) -> None:
        self.settings = s

    def status_values(self) -> dict[str, Any]:
        """Return the driver's status, with the frames published, skipped, truths refused."""
        return {**super().status_values(), 'frames': self.frames, 'skipped': self.skipped,
                'encoded': self.output.encoded, 'obstacles': len(self.world),
                'refused': self.truth_gate.refused}

    def _on_truth(self, truth: Odometry) -> None:
        t = self.admit_truth(truth)
        if t is None:
            return
        self.truths += 1
        if not self.started:  # a source: silent before start and after stop
            return
        # frame k is due at t0 + k / frame_rate, each rounded on its own (no drift)
        rate = self.settings.frame_rate
        if self._t0_ns is None:
            self._t0_ns, self._k = t, 0
        if t < self._t0_ns + round(self._k * 1e9 / rate):
            return
        self._k = max(self._k + 1, math.floor((t - self._t0_ns) * rate / 1e9) + 1)
        p = truth.pose.pose
        due = (truth.header.stamp, self.world_time(t), p.position.x, p.position.y,
               convert.quaternion_to_yaw(p.orientation), p.position.z)
        with self._lock:
            if self._due is not None:
                self.skipped += 1  # the renderer is behind: the newer frame wins
            self._due = due

    @property
    def idle(self) -> bool:
        """Whether no frame is waiting or being rendered."""
        with self._lock:
            return self._due is None and not self._rendering

    def _render_due(self) -> None:
        with self._lock:
            due, self._due = self._due, None
            if due is None or not self.started:
                return
            self._rendering = True
        try:
            self._render(due)
        finally:
            with self._lock:
                self._rendering = False

    def _render(self, due: tuple[Any, float, float, float, float, float]) -> None:
        stamp, now, x, y, psi, z = due
        s = self.settings
        frame = self.camera.render(self.world, x, y, psi, now, z=z, labels=False)
        h, w = frame.image.shape[:2]
        self.output.publish(frame.image, stamp, camera_info(s.calibration, w, h),
                            s.jpeg_quality)
        self.frames += 1
        self.sample_received()

    def destroy_node(self) -> None:
        """Stop the render thread, destroy the node."""
        self.stop()
        super().destroy_node()
