"""The simulated camera in checkerboard mode (sim_camera, scene: checkerboard): each frame is
the manual's board drawn through the TRUE lens at the pose its stamp falls in, the poses
change on the clock's schedule, camera_info is what the real driver publishes, and
set_camera_info stores a calibration as the real driver's does without changing the lens."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo
from support.nodes import add, call, probe, TIMEOUT
from support.saucer import SimClock, T0_NS

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import Frame, FrameTree
from enbarr_core.framework.node import install_frame_tree, install_world
from enbarr_core.vision.board import Board, calibration_poses, Camera, render_board
from enbarr_core.world.model import World
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.camera.calibration import load_calibration, save_calibration
from enbarr_plugins.camera.common import camera_info
from enbarr_plugins.camera.sim import SimCameraNode
from enbarr_plugins.camera.sim_render import PinholeModel

pytestmark = pytest.mark.node

# The CS Saucer manual's board (4.1): 9x7 squares of 40 mm, i.e. 8x6 inner corners.
MANUAL_BOARD = Board(8, 6, 0.040)
# A small lens (the node's width, height, focal_length, distortion below) keeps drawing cheap.
LENS = Camera(320, 240, 250.0, 250.0, 159.5, 119.5, (-0.12, 0.02, 0.0, 0.0, 0.0))
LENS_PARAMS = {'width': 320, 'height': 240, 'focal_length': 250.0,
               'distortion': [-0.12, 0.02, 0.0, 0.0, 0.0]}
S = 10**9


class BoardRig:
    """A sim_camera in checkerboard mode on a simulated clock, with no mount in the tree."""

    def __init__(self, context, executor, spin, **params):
        install_world(context, World(), epoch_ns=T0_NS)
        install_frame_tree(context, FrameTree.of([Frame('base_link')]))  # no camera frame
        self.executor, self.spin = executor, spin
        params = {'scene': 'checkerboard', **LENS_PARAMS, **params}
        self.node = add(executor, SimCameraNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        self.clock = SimClock(self.node)
        self.probe = probe(context, executor)
        self.raw: list[Image] = []
        self.info: list[CameraInfo] = []
        self.probe.create_subscription(Image, 'camera/image_raw', self.raw.append,
                                       topics.CAMERA_IMAGE.qos)
        self.probe.create_subscription(CameraInfo, 'camera/camera_info', self.info.append,
                                       topics.CAMERA_IMAGE.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.node.count_subscribers('camera/image_raw') > 0,
                    TIMEOUT)
        self.node.start()

    def frame_at(self, t_ns: int) -> tuple[np.ndarray, CameraInfo]:
        """Set the clock to ``t_ns``; the frame stamped then, and its camera_info."""
        self.clock.set(t_ns)
        assert self.spin(self.executor, lambda: any(stamp(m) == t_ns for m in self.raw)
                         and any(stamp(m) == t_ns for m in self.info), 3 * TIMEOUT)
        raw = next(m for m in self.raw if stamp(m) == t_ns)
        info = next(m for m in self.info if stamp(m) == t_ns)
        return np.frombuffer(bytes(raw.data), np.uint8).reshape(raw.height, raw.width, 3), info

    def commit(self, info: CameraInfo) -> SetCameraInfo.Response:
        client = self.probe.create_client(SetCameraInfo, topics.CAMERA_SET_INFO)
        assert self.spin(self.executor, client.service_is_ready, TIMEOUT)
        request = SetCameraInfo.Request()
        request.camera_info = info
        return call(self.executor, client.call_async(request))


def stamp(msg) -> int:
    return msg.header.stamp.sec * S + msg.header.stamp.nanosec


def pose_number(t_ns: int, hold: float, n: int) -> int:
    return int(t_ns // round(hold * S)) % n


def test_each_frame_is_the_board_at_the_pose_of_its_stamp_changing_on_schedule(
        context, executor, spin):
    rig = BoardRig(context, executor, spin, board_poses=3, board_hold=0.5, seed=4)
    poses = calibration_poses(LENS, MANUAL_BOARD, 3, 4)
    drawn = [render_board(LENS, MANUAL_BOARD, p, color=True) for p in poses]
    assert len({d.tobytes() for d in drawn}) == 3
    cycle = 3 * S // 2   # three poses of half a second
    t0 = (T0_NS // cycle + 1) * cycle   # the clock at a whole number of runs: pose 0
    times = [t0, t0 + S // 2 - 1, t0 + S // 2, t0 + S, t0 + 3 * S // 2, t0 + 3 * S // 2 + 7]
    seen = []
    for t in times:
        image, _ = rig.frame_at(t)
        k = pose_number(t, 0.5, 3)
        assert np.array_equal(image, drawn[k]), (t - t0, k)
        seen.append(k)
    # held for half a second, then the next, round and round
    assert seen == [0, 0, 1, 2, 0, 0]
    # one frame per clock reading: the times set, and the clock's start if the loop saw it
    stamps = [stamp(m) for m in rig.raw]
    assert len(stamps) == len(set(stamps)) == rig.node.frames
    assert sorted(set(stamps) - {T0_NS}) == times


def test_the_defaults_are_the_manuals_board():
    from enbarr_plugins.camera.sim import SPECS
    defaults = {s.name: s.default for s in SPECS}
    assert (defaults['board_cols'], defaults['board_rows'], defaults['board_square']) == (
        8, 6, 0.040)
    assert defaults['scene'] == 'world'


def test_camera_info_is_the_real_drivers_and_a_commit_changes_it_not_the_lens(
        context, executor, spin, tmp_path):
    path = tmp_path / 'cal.yaml'
    rig = BoardRig(context, executor, spin, board_poses=2, board_hold=1.0,
                   calibration_file=str(path))
    t = T0_NS - T0_NS % S + 10 * S
    before, info = rig.frame_at(t)
    # no file yet: uncalibrated, the image size alone, as the real driver
    assert (info.width, info.height, info.distortion_model) == (320, 240, '')
    assert list(info.k) == [0.0] * 9
    committed = PinholeModel.nominal(320, 240, 251.5, (-0.1, 0.0, 0.0, 0.0, 0.0))
    from enbarr_plugins.camera.calibration import Calibration
    cal = Calibration(320, 240, 'camera', committed.k, 'plumb_bob', committed.d,
                      (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), committed.projection)
    response = rig.commit(camera_info(cal, 320, 240))
    assert response.success, response.status_message
    assert response.status_message == f'stored in {path}'
    assert load_calibration(str(path)).k == committed.k
    after, info = rig.frame_at(t + 1)
    assert list(info.k) == list(committed.k) and list(info.d) == list(committed.d)
    assert np.array_equal(after, before)   # the lens drawn is the true one still
    # a calibration for other images is refused, as by the real driver
    wrong = Calibration(640, 480, 'camera', committed.k, 'plumb_bob', committed.d, cal.r,
                        committed.projection)
    response = rig.commit(camera_info(wrong, 640, 480))
    assert not response.success
    assert response.status_message == ('calibration for 640x480 images, but the camera gives '
                                       '320x240')


def test_without_a_calibration_file_the_true_lens_is_published_and_a_commit_refused(
        context, executor, spin):
    rig = BoardRig(context, executor, spin, board_poses=1)
    _, info = rig.frame_at(T0_NS)
    assert list(info.k) == [250.0, 0.0, 159.5, 0.0, 250.0, 119.5, 0.0, 0.0, 1.0]
    assert list(info.d) == [-0.12, 0.02, 0.0, 0.0, 0.0]
    response = rig.commit(info)
    assert not response.success
    assert response.status_message == 'no calibration_file is configured: nowhere to store it'


def test_a_calibration_file_there_is_published_from_the_start(context, executor, spin,
                                                               tmp_path):
    from enbarr_plugins.camera.calibration import Calibration
    model = PinholeModel.nominal(320, 240, 260.0)
    path = tmp_path / 'cal.yaml'
    save_calibration(Calibration(320, 240, 'saucer', model.k, 'plumb_bob', model.d,
                                 (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
                                 model.projection), str(path))
    rig = BoardRig(context, executor, spin, board_poses=1, calibration_file=str(path))
    image, info = rig.frame_at(T0_NS)
    assert list(info.k) == list(model.k)
    assert np.array_equal(image, render_board(
        LENS, MANUAL_BOARD, calibration_poses(LENS, MANUAL_BOARD, 1, 1)[0], color=True))


@pytest.mark.parametrize('params, message', [
    ({'scene': 'sky'}, "scene: one of world, checkerboard, got 'sky'"),
    ({'board_square': 0.0}, 'board_square'),
    ({'board_cols': 1}, 'board_cols'),
    ({'board_hold': 0.0}, 'board_hold'),
    ({'lens_file': 'RATIONAL'}, 'scene checkerboard: the checkerboard is drawn through a '
                                'plumb_bob lens, not rational_polynomial'),
])
def test_bad_parameters_are_named(context, tmp_path, params, message):
    install_world(context, World())
    install_frame_tree(context, FrameTree.of([Frame('base_link')]))
    if params.get('lens_file') == 'RATIONAL':
        from enbarr_plugins.camera.calibration import Calibration
        path = tmp_path / 'lens.yaml'
        model = PinholeModel.nominal(320, 240, 250.0, (0.0,) * 8)
        save_calibration(Calibration(320, 240, 'lens', model.k, 'rational_polynomial',
                                     model.d, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
                                     model.projection), str(path))
        params = {'lens_file': str(path)}
    params = {'scene': 'checkerboard', **params}
    with pytest.raises(ConfigurationError, match=message):
        SimCameraNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
