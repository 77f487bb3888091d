"""OpenCV camera driver against the emulated camera (a test video): frames, calibration,
absent source, stall and recovery, check-device.
"""

from __future__ import annotations

import itertools
import threading
from typing import Any

import cv2
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

from enbarr_core.commands import main as cli
from enbarr_core.framework.driver import ERROR
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.camera import opencv_camera
from enbarr_plugins.camera.calibration import load_calibration
from enbarr_plugins.camera.check import check_device
from enbarr_plugins.camera.emulator import CameraEmulatorNode
from enbarr_plugins.camera.pattern_video import read_counter
from enbarr_plugins.camera.opencv_camera import CameraNode
from enbarr_plugins.check import CheckTarget
from support.waiting import spin_until

TIMEOUT = 10.0
_names = itertools.count()

CALIBRATION = """\
image_width: 320
image_height: 240
camera_name: hull_cam
camera_matrix: {rows: 3, cols: 3, data: [300.0, 0.0, 160.0, 0.0, 300.0, 120.0, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0.0, 0.0, 0.0]}
rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
projection_matrix: {rows: 3, cols: 4, data: [300, 0, 160, 0, 0, 300, 120, 0, 0, 0, 1, 0]}
"""


def test_calibration_file_is_read(tmp_path):
    path = tmp_path / 'cam.yaml'
    path.write_text(CALIBRATION)
    cal = load_calibration(str(path))
    assert (cal.width, cal.height, cal.camera_name) == (320, 240, 'hull_cam')
    assert cal.k[0] == 300.0 and len(cal.d) == 5 and len(cal.p) == 12


@pytest.mark.parametrize('change, key', [
    (('camera_matrix: {rows: 3, cols: 3, data: [300.0', 'camera_matrix: {rows: 3, cols: 2, '
      'data: [300.0'), 'camera_matrix'),
    (('image_width: 320', 'image_width: wide'), 'image_width'),
    (('projection_matrix: {rows: 3, cols: 4, data: [300, 0, 160, 0, ',
      'projection_matrix: {rows: 3, cols: 4, data: ['), r'projection_matrix\.data'),
    (('distortion_model: plumb_bob\n', ''), 'distortion_model'),
])
def test_a_malformed_calibration_names_file_and_key(tmp_path, change, key):
    path = tmp_path / 'bad.yaml'
    path.write_text(CALIBRATION.replace(*change))
    with pytest.raises(ValueError, match=rf'{path}: {key}'):
        load_calibration(str(path))


def test_check_device_and_command_line(capsys):
    lines = check_device(CheckTarget(device='emulated'))
    assert lines == ['camera emulated: 640x480 at 15 fps (FFMPEG)', 'one frame: 640x480 bgr8']
    assert cli.main(['check-device', 'camera', '--device', 'emulated']) == 0
    assert '640x480' in capsys.readouterr().out
    assert cli.main(['check-device', 'camera', '--device', '/nonexistent/video.avi']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['enbarr check-device: error: camera /nonexistent/video.avi: no such video '
                   'file /nonexistent/video.avi']
    with pytest.raises(DeviceError, match='/dev/video9: cannot open'):
        check_device(CheckTarget(device='/dev/video9'))


class Rig:
    def __init__(self, context, executor, *, emulator: bool = True, **params) -> None:
        self.context, self.executor = context, executor
        self.name = f'cam-{next(_names)}'
        self.images, self.infos, self.jpegs = [], [], []
        probe = EnbarrNode('probe', context=context)
        executor.add_node(probe)
        probe.create_subscription(topics.CAMERA_COMPRESSED.msg_type,
                                  topics.CAMERA_COMPRESSED.name, self.jpegs.append,
                                  topics.CAMERA_COMPRESSED.qos)
        probe.create_subscription(topics.CAMERA_IMAGE.msg_type, topics.CAMERA_IMAGE.name,
                                  self.images.append, topics.CAMERA_IMAGE.qos)
        probe.create_subscription(topics.CAMERA_INFO.msg_type, topics.CAMERA_INFO.name,
                                  self.infos.append, topics.CAMERA_INFO.qos)
        self.emulator = self.add_emulator() if emulator else None
        overrides = {'device': f'emulated:{self.name}', 'frame_rate': 30.0,
                     'reconnect.initial_delay': 0.05, 'reconnect.max_delay': 0.2}
        overrides.update(params)
        self.driver = CameraNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()])
        executor.add_node(self.driver)
        self.driver.start()

    def add_emulator(self) -> CameraEmulatorNode:
        node = CameraEmulatorNode(context=self.context, parameter_overrides=[
            Parameter('name', value=self.name), Parameter('width', value=320),
            Parameter('height', value=240), Parameter('duration', value=0.5)])
        self.executor.add_node(node)
        node.start()
        self.emulator = node
        return node

    def spin_until(self, condition, timeout: float = TIMEOUT) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.02)

    def frames_flow(self) -> bool:
        n = self.driver.samples
        return self.spin_until(lambda: self.driver.samples >= n + 3 and len(self.images) > 0)


def test_frames_and_calibration_are_published_with_one_stamp(context, executor, tmp_path):
    path = tmp_path / 'cam.yaml'
    path.write_text(CALIBRATION)
    rig = Rig(context, executor, calibration_file=str(path))
    assert rig.spin_until(lambda: len(rig.images) >= 20 and len(rig.infos) >= 20)
    img = rig.images[-1]
    assert (img.width, img.height, img.encoding, img.step) == (320, 240, 'bgr8', 960)
    assert img.header.frame_id == 'camera_optical_frame'
    frame = np.frombuffer(bytes(img.data), np.uint8).reshape(240, 320, 3)
    assert 0 <= read_counter(frame) < 15                    # a frame of the 15-frame video
    counters = [read_counter(np.frombuffer(bytes(m.data), np.uint8).reshape(240, 320, 3))
                for m in rig.images]
    assert any(b < a for a, b in zip(counters, counters[1:]))  # the video looped
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in rig.images}
    assert any((i.header.stamp.sec, i.header.stamp.nanosec) in stamps for i in rig.infos)
    info = rig.infos[-1]
    assert info.k[0] == 300.0 and info.distortion_model == 'plumb_bob'


def test_each_frame_goes_out_as_jpeg_too_as_image_transport_sends_it(context, executor):
    """camera/image_raw/compressed: format 'bgr8; jpeg compressed bgr8' (image_transport's
    compressed_publisher.cpp: the encoding, '; jpeg compressed ', bgr8 for colour), the raw
    frame's header, and it decodes to the raw frame; without publish_raw, only the JPEG."""
    rig = Rig(context, executor)
    assert rig.spin_until(lambda: len(rig.jpegs) >= 5 and len(rig.images) >= 5)
    raw = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in rig.images}
    both = [j for j in rig.jpegs if (j.header.stamp.sec, j.header.stamp.nanosec) in raw]
    assert both
    jpeg = both[-1]
    image = raw[(jpeg.header.stamp.sec, jpeg.header.stamp.nanosec)]
    assert jpeg.format == 'bgr8; jpeg compressed bgr8'
    assert jpeg.header.frame_id == 'camera_optical_frame'
    decoded = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    frame = np.frombuffer(bytes(image.data), np.uint8).reshape(240, 320, 3)
    assert decoded.shape == frame.shape
    assert np.abs(decoded.astype(int) - frame).mean() < 4.0


def test_without_raw_only_the_jpeg_goes_out(context, executor):
    rig = Rig(context, executor, publish_raw=False)
    assert rig.spin_until(lambda: len(rig.jpegs) >= 3 and len(rig.infos) >= 3)
    assert rig.driver.count_publishers(topics.CAMERA_IMAGE.name) == 0 and not rig.images


def test_absent_source_is_an_error_then_found(context, executor):
    rig = Rig(context, executor, emulator=False)
    assert not rig.driver.connected and rig.driver.status()[0] == ERROR
    assert 'no camera emulator named' in rig.driver.last_fault
    rig.add_emulator()
    assert rig.frames_flow()


def test_a_camera_that_stops_is_a_fault_and_frames_return(context, executor):
    rig = Rig(context, executor)
    assert rig.frames_flow()
    rig.emulator.stall()
    assert rig.spin_until(lambda: 'cannot read' in rig.driver.last_fault)
    assert not rig.driver.connected and rig.driver.status()[0] == ERROR
    rig.emulator.resume()
    assert rig.frames_flow() and rig.driver.connected


class BlockingCapture:
    """A capture whose read blocks like a stalled V4L2 device."""

    def __init__(self) -> None:
        self.unblock = threading.Event()
        self.released = False

    def read(self):
        self.unblock.wait(TIMEOUT)
        return False, None

    def release(self) -> None:
        self.released = True

    def get(self, prop):
        return 0.0

    def getBackendName(self):  # noqa: N802 - OpenCV's name
        return 'BLOCKING'


def test_a_stalled_read_is_a_fault_without_blocking_the_executor(context, executor,
                                                                    monkeypatch):
    stalled = BlockingCapture()
    real_open = opencv_camera.open_capture
    monkeypatch.setattr(opencv_camera, 'open_capture', lambda *a, **k: stalled)
    rig = Rig(context, executor, stall_timeout=0.3)
    assert rig.driver.connected
    assert rig.spin_until(lambda: 'stalled' in rig.driver.last_fault)  # the executor spins
    assert rig.driver.stalls == 1 and not rig.driver.connected
    monkeypatch.setattr(opencv_camera, 'open_capture', real_open)
    stalled.unblock.set()
    assert rig.spin_until(lambda: stalled.released)  # released by the capture thread
    assert rig.frames_flow()


def test_a_file_that_ends_stops_without_a_fault(context, executor):
    rig = Rig(context, executor, loop=False)
    assert rig.spin_until(lambda: rig.driver.ended)
    assert rig.driver.samples == 8 and rig.driver.faults == 0   # 0.5 s at 15 fps


def test_constructing_the_driver_and_the_emulator_opens_nothing(context, executor,
                                                                monkeypatch):
    """``bringup --check`` builds every node: no capture opened, no video written, until
    start."""
    captures: list[Any] = []
    real_capture = cv2.VideoCapture
    monkeypatch.setattr(cv2, 'VideoCapture',
                        lambda *a: captures.append(a[0]) or real_capture(*a))
    emulator = CameraEmulatorNode(context=context, parameter_overrides=[
        Parameter('name', value='quiet'), Parameter('width', value=320),
        Parameter('height', value=240), Parameter('duration', value=0.5)])
    executor.add_node(emulator)
    driver = CameraNode(context=context, parameter_overrides=[
        Parameter('device', value='emulated:quiet')])
    executor.add_node(driver)
    assert captures == [] and emulator.path is None and emulator.directory is None
    with pytest.raises(DeviceError, match="no camera emulator named 'quiet'"):
        emulation.lookup('camera', 'emulated:quiet')
    emulator.start()
    driver.start()
    assert captures == [emulator.path] and driver.connected


def test_bad_parameters_name_the_parameter(context, tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('image_width: 320\n')
    with pytest.raises(ConfigurationError, match=rf'calibration_file: {path}: image_height'):
        CameraNode(context=context, parameter_overrides=[
            Parameter('device', value='emulated:x'),
            Parameter('calibration_file', value=str(path))])
    with pytest.raises(ConfigurationError, match='device: empty'):
        CameraNode(context=context, parameter_overrides=[Parameter('device', value=' ')])


# -- set_camera_info: the manual's "commit" ----------------------------------------------------

def call_set_camera_info(rig: Rig, info: CameraInfo) -> SetCameraInfo.Response:
    """Call the driver's service through the ROS graph; its response."""
    client_node = EnbarrNode(f'committer_{next(_names)}', context=rig.context)
    rig.executor.add_node(client_node)
    client = client_node.create_client(SetCameraInfo, topics.CAMERA_SET_INFO)
    assert rig.spin_until(client.service_is_ready)
    request = SetCameraInfo.Request()
    request.camera_info = info
    future = client.call_async(request)
    assert rig.spin_until(future.done)
    return future.result()


def info_of(text: str) -> CameraInfo:
    """The CameraInfo of a camera_info YAML text (as the driver would publish it)."""
    import yaml
    doc = yaml.safe_load(text)
    info = CameraInfo()
    info.width, info.height = doc['image_width'], doc['image_height']
    info.distortion_model = doc['distortion_model']
    info.k = [float(x) for x in doc['camera_matrix']['data']]
    info.d = [float(x) for x in doc['distortion_coefficients']['data']]
    info.r = [float(x) for x in doc['rectification_matrix']['data']]
    info.p = [float(x) for x in doc['projection_matrix']['data']]
    return info


def test_set_camera_info_stores_the_file_and_publishes_it(context, executor, tmp_path):
    path = tmp_path / 'calib' / 'cam.yaml'
    path.parent.mkdir()
    rig = Rig(context, executor, calibration_file=str(path))   # no file yet: uncalibrated
    assert rig.frames_flow() and rig.infos[-1].k[0] == 0.0
    info = info_of(CALIBRATION.replace('300.0, 0.0, 160.0', '310.5, 0.0, 161.0'))
    response = call_set_camera_info(rig, info)
    assert response.success and response.status_message == f'stored in {path}'
    cal = load_calibration(str(path))
    assert cal.k[:3] == (310.5, 0.0, 161.0) and cal.d == (-0.1, 0.01, 0.0, 0.0, 0.0)
    assert cal.camera_name == 'camera' and cal.p[0] == 300.0
    assert [p.name for p in path.parent.iterdir()] == ['cam.yaml']   # no temporary left
    n = len(rig.infos)
    assert rig.spin_until(lambda: len(rig.infos) > n + 2 and rig.infos[-1].k[0] == 310.5)
    # A second commit replaces the first, keeping the camera's name.
    path.write_text(CALIBRATION)
    second = info_of(CALIBRATION.replace('300.0, 0.0, 160.0', '305.0, 0.0, 160.0'))
    assert call_set_camera_info(rig, second).success
    cal = load_calibration(str(path))
    assert cal.k[0] == 305.0 and cal.camera_name == 'camera'


@pytest.mark.parametrize('change, status', [
    (lambda i: setattr(i, 'width', 640), 'calibration for 640x240 images, but the camera '
     'gives 320x240'),
    (lambda i: setattr(i, 'd', [-0.1, 0.01, 0.0, 0.0]), 'plumb_bob has 5 coefficients, D has 4'),
    (lambda i: setattr(i, 'distortion_model', 'fisheye'), "distortion_model 'fisheye': not one "
     'of plumb_bob, rational_polynomial, equidistant'),
    (lambda i: setattr(i, 'k', [0.0] * 9), 'K: not a camera matrix'),
    (lambda i: i.k.__setitem__(0, float('nan')), 'K: not finite'),
])
def test_set_camera_info_refuses_a_malformed_calibration(context, executor, tmp_path, change,
                                                         status):
    path = tmp_path / 'cam.yaml'
    path.write_text(CALIBRATION)
    rig = Rig(context, executor, calibration_file=str(path))
    assert rig.frames_flow()
    info = info_of(CALIBRATION.replace('300.0, 0.0, 160.0', '999.0, 0.0, 160.0'))
    change(info)
    response = call_set_camera_info(rig, info)
    assert not response.success and status in response.status_message
    assert path.read_text() == CALIBRATION                      # the file is untouched
    assert rig.driver.settings.calibration.k[0] == 300.0


def test_set_camera_info_refuses_without_a_calibration_file(context, executor):
    rig = Rig(context, executor)
    assert rig.frames_flow()
    response = call_set_camera_info(rig, info_of(CALIBRATION))
    assert not response.success
    assert response.status_message == 'no calibration_file is configured: nowhere to store it'


def test_set_camera_info_refuses_when_the_file_cannot_be_written(context, executor, tmp_path):
    rig = Rig(context, executor, calibration_file=str(tmp_path / 'gone' / 'cam.yaml'))
    assert rig.frames_flow()
    response = call_set_camera_info(rig, info_of(CALIBRATION))
    assert not response.success
    assert response.status_message.startswith(f'{tmp_path / "gone" / "cam.yaml"}: cannot write')


def board_views(folder) -> str:
    """Rendered views of a 6x4 board at 320x240 (the emulator's size) in ``folder``."""
    from enbarr_core.vision.board import Board, calibration_poses, Camera, render_board
    cam = Camera(320, 240, 260.0, 262.0, 161.5, 118.5, (-0.2, 0.05, 0.0, 0.0, 0.0))
    board = Board(6, 4, 0.05)
    folder.mkdir()
    for i, pose in enumerate(calibration_poses(cam, board, 8, seed=5)):
        if i % 4 != 3:   # at 320x240 the small corner views are too small to detect
            cv2.imwrite(str(folder / f'{i}.png'), render_board(cam, board, pose, seed=i))
    return str(folder)


def commit_from_a_thread(rig: Rig, folder: str) -> int:
    """Run ``enbarr calibrate camera FOLDER --commit`` while the driver's executor spins."""
    done: list[int] = []
    worker = threading.Thread(target=lambda: done.append(cli.main([
        'calibrate', 'camera', folder, '--size', '6x4', '--square', '0.05', '--commit',
        '--timeout', '20'])))
    worker.start()
    assert rig.spin_until(lambda: bool(done), timeout=60.0)
    worker.join()
    return done[0]


def test_enbarr_calibrate_camera_commit_calls_the_service(context, executor, tmp_path, capsys):
    folder = board_views(tmp_path / 'shots')
    path = tmp_path / 'cam.yaml'
    rig = Rig(context, executor, calibration_file=str(path))
    assert rig.frames_flow()
    rc = commit_from_a_thread(rig, folder)
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert f'committed to camera/set_camera_info: stored in {path}' in out
    cal = load_calibration(str(path))
    assert cal.k[0] == pytest.approx(260.0, rel=0.02) and (cal.width, cal.height) == (320, 240)
    assert rig.spin_until(lambda: rig.infos[-1].k[0] == cal.k[0])


def test_a_commit_the_driver_refuses_is_one_error_line(context, executor, tmp_path, capsys):
    folder = board_views(tmp_path / 'shots')
    rig = Rig(context, executor)                       # no calibration_file
    assert rig.frames_flow()
    assert commit_from_a_thread(rig, folder) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ('enbarr calibrate: error: camera/set_camera_info refused: no '
                       'calibration_file is configured: nowhere to store it')
    assert 'Traceback' not in '\n'.join(err)


def test_commit_without_a_driver_is_an_error(tmp_path, context):
    from enbarr_core.commands.calibrate_camera import commit
    from enbarr_core.framework.errors import CalibrationError
    (tmp_path / 'c.yaml').write_text(CALIBRATION)
    cal = load_calibration(str(tmp_path / 'c.yaml'))
    with pytest.raises(CalibrationError, match='camera/set_camera_info: no such service in '
                       r'0.5 s \(is the camera driver running, in this ROS_DOMAIN_ID\?\)'):
        commit(cal, topics.CAMERA_SET_INFO, 0.5)
