"""Simulated camera (``sim_camera``): the profile's world as the vessel's camera sees it.

It renders the profile's ``world`` (``EnbarrNode.world``) with ``sim_render`` from the
camera's mount, the frame tree's ``base_link -> frame_id`` (``camera_optical_frame``: manual
section 1.5, on a rod behind the lidar, looking ahead along surge), at the simulated vessel's
true pose (``sim/odometry``), and publishes what the real driver (``camera``) publishes
(``common.ImageOutput``): ``camera/image_raw`` (bgr8), ``camera/image_raw/compressed`` (JPEG)
and ``camera/camera_info``.

The TRUE lens, what is drawn: a ROS camera_info YAML (``lens_file``; its size is the
image's), or without one a pinhole of ``focal_length`` centred on a ``width`` x ``height``
image with ``distortion`` (plumb_bob k1, k2, p1, p2, k3). The default distortion is a mild
barrel, an ESTIMATE of a wide lens (the manual gives no calibration). The camera_info
published: without a ``calibration_file`` the true lens (a perfectly calibrated camera, so a
consumer that undistorts with it gets straight lines); with one, as the real driver
(``opencv_camera``): the file's calibration, or the image size alone (uncalibrated) while the
file is not there yet. ``camera/set_camera_info`` stores a calibration in ``calibration_file``
with the real driver's code (``common.store_camera_info``) and publishes it from then on; the
lens drawn never changes.

``scene``: ``world`` draws the profile's world (below); ``checkerboard`` draws only the
manual's calibration board (4.1: 9x7 squares of 40 mm, ``board_cols`` x ``board_rows`` inner
corners of ``board_square``) waved in front of the lens (``sim_board``: ``board_poses``
poses, each held ``board_hold`` seconds of the node clock), one frame per ``1 / frame_rate``
stamped with the node clock; no truth is needed, nor a mount in the frame tree.

Time, as ``sim_lidar``: the truth's stamps schedule the frames, one every ``1 / frame_rate``
of the node clock (simulated time in a scenario). A frame is rendered at one instant: the
truth's pose and the world at that stamp (``EnbarrNode.world_time``), and carries that stamp.
Rendering and encoding take milliseconds, so they run on the node's own thread: the truth's
callback only hands the latest due frame over (a frame still waiting when the next is due is
replaced and counted, ``skipped``), and the executor is never held by the camera. On
simulated time the scenario runner renders each due frame itself instead, right after the
step that made it due (``render_in_caller``, ``render_pending``): simulated time would run
ahead of a renderer on the wall clock, skipping frames by the machine's speed, and a run would
not repeat.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import math
import os
import threading
from typing import Any

from nav_msgs.msg import Odometry
from sensor_msgs.srv import SetCameraInfo

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.params import ParamSpec
from enbarr_core.vision.board import Board
from enbarr_interfaces import convert, topics
from enbarr_plugins.camera.calibration import Calibration, load_calibration
from enbarr_plugins.camera.common import (
    camera_info, ImageOutput, OUTPUT_SPECS, store_camera_info)
from enbarr_plugins.camera.sim_board import board_run, BoardScene, SCENES
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
    ParamSpec('scene', 'world', "What the camera sees: 'world' (the profile's) or "
              "'checkerboard' (a calibration board waved in front of it)", read_only=True),
    ParamSpec('lens_file', '', 'ROS camera_info YAML file of the true lens drawn (empty: '
              'width, height, focal_length and distortion below)', read_only=True),
    ParamSpec('calibration_file', '', 'ROS camera_info YAML published and written by '
              'set_camera_info, as the real driver (empty: the true lens is published; not '
              'there yet: uncalibrated until set_camera_info writes it)', read_only=True),
    ParamSpec('width', 640, 'Image width without a calibration file', 'px', 16, 4096,
              read_only=True),
    ParamSpec('height', 480, 'Image height without a calibration file', 'px', 16, 4096,
              read_only=True),
    ParamSpec('focal_length', 500.0, 'fx = fy without a calibration file (500 px at 640 px '
              'wide: 65 deg across)', 'px', 10.0, 10000.0, read_only=True),
    ParamSpec('distortion', [-0.12, 0.02, 0.0, 0.0, 0.0], 'plumb_bob k1, k2, p1, p2, k3 '
              'without a calibration file (ESTIMATE: a mild barrel)', '', -10.0, 10.0,
              read_only=True),
    ParamSpec('seed', 1, 'Seed of the water texture, and of the board poses', '', 0,
              2**31 - 1, read_only=True),
    # The CS Saucer manual's board (4.1): 9x7 squares of 40 mm, 8x6 inner corners.
    ParamSpec('board_cols', 8, 'checkerboard: inner corners along a row', '', 2, 40,
              read_only=True),
    ParamSpec('board_rows', 6, 'checkerboard: inner corners along a column', '', 2, 40,
              read_only=True),
    ParamSpec('board_square', 0.040, 'checkerboard: side of a square', 'm', 0.001, 1.0,
              read_only=True),
    ParamSpec('board_poses', 12, 'checkerboard: poses of the board, shown in turn', '', 1, 500,
              read_only=True),
    ParamSpec('board_hold', 1.0, 'checkerboard: how long each pose is held', 's', 0.01, 600.0,
              read_only=True),
    *OUTPUT_SPECS,
]


@dataclass(frozen=True)
class SimCameraSettings:
    """Settings of ``SimCameraNode`` (see ``SPECS``)."""

    frame_id: str
    frame_rate: float              # [Hz]
    model: PinholeModel            # the true lens: what is drawn
    calibration_file: str
    calibration: Calibration | None  # what camera_info carries (None: uncalibrated)
    seed: int
    jpeg_quality: int
    publish_raw: bool
    scene: str = 'world'
    board: Board | None = None     # the checkerboard scene's board
    board_poses: int = 12
    board_hold: float = 1.0        # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimCameraSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        frame_id = v['frame_id'].strip()
        if not frame_id or frame_id.startswith('/') or ' ' in frame_id:
            raise ValueError(f"frame_id: a frame name such as 'camera_optical_frame' (no "
                             f"leading '/', no spaces), got {v['frame_id']!r}")
        if v['scene'] not in SCENES:
            raise ValueError(f"scene: one of {', '.join(SCENES)}, got {v['scene']!r}")
        if v['lens_file']:
            try:
                cal = load_calibration(v['lens_file'])
                model = PinholeModel(cal.width, cal.height, cal.k, cal.d, cal.distortion_model)
            except ValueError as err:
                raise ValueError(f'lens_file: {err}') from err
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
        published: Calibration | None = cal
        # As the real driver: a file not there yet is no calibration yet (set_camera_info
        # writes it); one that is there must be right.
        if v['calibration_file']:
            published = None
            if os.path.exists(v['calibration_file']):
                try:
                    published = load_calibration(v['calibration_file'])
                except ValueError as err:
                    raise ValueError(f'calibration_file: {err}') from err
        board = None
        if v['scene'] == 'checkerboard':
            try:
                board = Board(int(v['board_cols']), int(v['board_rows']), v['board_square'])
            except ValueError as err:
                raise ValueError(f'board_cols, board_rows, board_square: {err}') from err
        return cls(frame_id, v['frame_rate'], model, v['calibration_file'], published,
                   int(v['seed']), int(v['jpeg_quality']), v['publish_raw'], v['scene'],
                   board, int(v['board_poses']), float(v['board_hold']))


class SimCameraNode(TruthSensor):
    """See the module docstring."""

    def __init__(self, node_name: str = 'camera', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimCameraSettings
        self.bind_settings(SPECS, SimCameraSettings.from_params, self._apply)
        s = self.settings
        self.output = ImageOutput(self, s.publish_raw)
        self.frames = 0
        self.create_service(SetCameraInfo, topics.CAMERA_SET_INFO, self._set_camera_info)
        self.skipped = 0
        self.truths = 0
        self._t0_ns: int | None = None  # the first truth's stamp: frame 0
        self._k = 0  # the next frame's number
        self._rendering = False
        self._due: tuple[Any, float, float, float, float, float] | None = None
        self._lock = threading.Lock()
        if s.board is not None:
            self._init_board(s.board)
            return
        mount = self.mount(s.frame_id, 'camera')
        try:
            self.camera = SimulatedCamera(s.model, mount, Look(seed=s.seed))
        except ValueError as err:
            raise ConfigurationError(f'node {self.get_name()!r}: {err}') from err
        self._loop = self.create_rate_loop(s.frame_rate * POLLS_PER_FRAME,
                                            self.render_pending)
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def _init_board(self, board: Board) -> None:
        s = self.settings
        try:
            self.board = BoardScene(board_run(s.model, board, s.board_poses, s.board_hold,
                                              s.seed))
        except ValueError as err:
            raise ConfigurationError(f'node {self.get_name()!r}: scene checkerboard: {err}',
                                     parameter='scene') from err
        self._last_ns: int | None = None
        self._prepared = False
        self._loop = self.create_rate_loop(s.frame_rate, self._render_board)

    def _render_board(self) -> None:
        """One frame of the board at the node clock's now (none while the clock stands)."""
        if not self.started:
            return
        if not self._prepared:   # every pose drawn before the first frame: none is late
            self.board.prepare()
            self._prepared = True
        t = self.now_ns()
        if t == self._last_ns:
            return
        self._last_ns = t
        s = self.settings
        image = self.board.render(t)
        h, w = image.shape[:2]
        self.output.publish(image, convert.ns_to_stamp(t), camera_info(s.calibration, w, h),
                            s.jpeg_quality)
        self.frames += 1
        self.sample_received()

    def _apply(self, s: SimCameraSettings) -> None:
        self.settings = s

    def _set_camera_info(self, request: SetCameraInfo.Request,
                         response: SetCameraInfo.Response) -> SetCameraInfo.Response:
        """Store and publish a calibration as the real driver; the lens drawn stays."""
        s = self.settings
        cal = store_camera_info(self, f'camera {self.get_name()}', s.calibration_file,
                                s.calibration, (s.model.width, s.model.height), request,
                                response)
        if cal is not None:
            self._apply(replace(self.settings, calibration=cal))
        return response

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

    def render_in_caller(self) -> bool:
        """Stop the render thread: the caller renders each due frame (``render_pending``).

        For a run on simulated time (``enbarr scenario``). False, and nothing changes, for the
        checkerboard scene, whose frames follow the node clock on their own.
        """
        if self.settings.board is not None:
            return False
        self._loop.stop()
        return True

    def render_pending(self) -> bool:
        """Render the due frame now, if there is one; True when one was rendered."""
        with self._lock:
            due, self._due = self._due, None
            if due is None or not self.started:
                return False
            self._rendering = True
        try:
            self._render(due)
        finally:
            with self._lock:
                self._rendering = False
        return True

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
