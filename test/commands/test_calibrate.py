"""``enbarr calibrate camera`` on a folder of images, a video file and a bag (rendered views
of known intrinsics), and every mistake a user can make as one error line and exit code 2.
The live topic and ``--commit`` are node tests (test/plugins/camera/test_set_camera_info.py).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CompressedImage, Image, Imu

from enbarr_core.commands import main as cli
from enbarr_core.commands.calibrate import ACTIONS, CalibrationAction, load_action
from enbarr_core.recording.bag import BagWriter
from enbarr_core.vision.board import Board, calibration_poses, Camera, render_board
from enbarr_core.vision.sources import decode_image
from enbarr_plugins.camera.calibration import load_calibration

pytestmark = pytest.mark.unit

CAM = Camera(320, 240, 260.0, 262.0, 161.5, 118.5, (-0.2, 0.05, 0.0, 0.0, 0.0))
BOARD = Board(6, 4, 0.05)
ARGS = ['--size', '6x4', '--square', '0.05']


@pytest.fixture(scope='module')
def views() -> list[np.ndarray]:
    """Rendered views the detector finds at 320x240 (BGR)."""
    poses = [p for i, p in enumerate(calibration_poses(CAM, BOARD, 8, seed=5)) if i % 4 != 3]
    return [render_board(CAM, BOARD, p, noise=1.0, seed=i, color=True)
            for i, p in enumerate(poses)]


def write_folder(folder: Path, images: list[np.ndarray]) -> Path:
    folder.mkdir()
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / f'view{i:02d}.png'), img)
    return folder


def image_msg(img: np.ndarray, encoding: str = 'bgr8') -> Image:
    msg = Image()
    msg.height, msg.width = img.shape[:2]
    msg.encoding = encoding
    msg.step = img.shape[1] * (img.shape[2] if img.ndim == 3 else 1)
    msg.data = img.tobytes()
    return msg


def write_bag(path: Path, topic: str, msgs: list, msgtype: str) -> Path:
    writer = BagWriter(path, flush_seconds=3600.0)
    for i, msg in enumerate(msgs):
        assert writer.write(topic, msgtype, 1_000_000_000 + i * 100_000_000,
                            serialize_message(msg))
    writer.close()
    return path


def run(capsys, argv: list[str]) -> tuple[int, str, str]:
    rc = cli.main(['calibrate', 'camera', *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def check_result(out: str, yaml_path: Path) -> None:
    assert 'coverage X' in out and 'reprojection RMS' in out
    cal = load_calibration(str(yaml_path))
    assert (cal.width, cal.height, cal.distortion_model) == (320, 240, 'plumb_bob')
    fx, _, cx, _, fy, cy = cal.k[:6]
    assert fx == pytest.approx(CAM.fx, rel=0.02) and fy == pytest.approx(CAM.fy, rel=0.02)
    assert cx == pytest.approx(CAM.cx, rel=0.03) and cy == pytest.approx(CAM.cy, rel=0.03)
    assert len(cal.d) == 5 and cal.d[4] == 0.0 and cal.r == (1, 0, 0, 0, 1, 0, 0, 0, 1)
    assert cal.p[3] == cal.p[7] == cal.p[11] == 0.0 and cal.p[10] == 1.0


def test_a_folder_of_images(tmp_path, capsys, views):
    folder = write_folder(tmp_path / 'shots', views)
    rc, out, err = run(capsys, [str(folder), *ARGS, '-o', str(tmp_path / 'cam.yaml'),
                                '--camera-name', 'saucer'])
    assert rc == 0, err
    check_result(out, tmp_path / 'cam.yaml')
    assert f'wrote {tmp_path / "cam.yaml"}' in out
    assert 'view 1 kept (view00.png)' in out
    assert load_calibration(str(tmp_path / 'cam.yaml')).camera_name == 'saucer'
    assert 'coverage incomplete' in err      # six views do not cover a 320x240 image


def test_without_output_the_yaml_is_printed(tmp_path, capsys, views):
    rc, out, _ = run(capsys, [str(write_folder(tmp_path / 'shots', views)), *ARGS])
    assert rc == 0
    yaml_text = out[out.index('image_width:'):]
    (tmp_path / 'printed.yaml').write_text(yaml_text)
    check_result(out, tmp_path / 'printed.yaml')


def test_a_video_file(tmp_path, capsys, views):
    path = tmp_path / 'run.avi'
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*'MJPG'), 5.0, (320, 240))
    assert writer.isOpened()
    for img in views:
        writer.write(img)
    writer.release()
    rc, out, err = run(capsys, [str(path), *ARGS, '-o', str(tmp_path / 'cam.yaml')])
    assert rc == 0, err
    check_result(out, tmp_path / 'cam.yaml')
    assert 'kept (frame 0)' in out


@pytest.mark.parametrize('kind', ['bgr8', 'mono8', 'rgb8', 'compressed'])
def test_a_bag_of_our_recorder(tmp_path, capsys, views, kind):
    if kind == 'compressed':
        msgs = []
        for img in views:
            m = CompressedImage()
            m.format = 'png'
            m.data = cv2.imencode('.png', img)[1].tobytes()
            msgs.append(m)
        bag = write_bag(tmp_path / 'bag', '/camera/image_raw/compressed', msgs,
                        'sensor_msgs/msg/CompressedImage')
        topic = ['--topic', 'camera/image_raw/compressed']
    else:
        convert = {'bgr8': lambda i: i, 'rgb8': lambda i: i[:, :, ::-1].copy(),
                   'mono8': lambda i: cv2.cvtColor(i, cv2.COLOR_BGR2GRAY)}[kind]
        bag = write_bag(tmp_path / 'bag', '/camera/image_raw',
                        [image_msg(convert(v), kind) for v in views], 'sensor_msgs/msg/Image')
        topic = []
    rc, out, err = run(capsys, [str(bag), *ARGS, *topic, '-o', str(tmp_path / 'cam.yaml')])
    assert rc == 0, err
    check_result(out, tmp_path / 'cam.yaml')
    assert 'at 1.000 s)' in out


def one_error(rc: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert rc == 2 and 'Traceback' not in err
    assert len(lines) == 1 and lines[0].startswith('enbarr calibrate: error: '), err
    return lines[0]


def test_no_such_source(tmp_path, capsys):
    line = one_error(*run(capsys, [str(tmp_path / 'nothing')])[::2])
    assert line.endswith(f'{tmp_path / "nothing"}: no such file or folder')


def test_a_folder_without_images(tmp_path, capsys):
    (tmp_path / 'notes.txt').write_text('no pictures')
    line = one_error(*run(capsys, [str(tmp_path)])[::2])
    assert f'{tmp_path}: no image files (.png' in line


def test_an_image_that_does_not_decode(tmp_path, capsys, views):
    folder = write_folder(tmp_path / 'shots', views[:2])
    (folder / 'view01.png').write_bytes(b'\x89PNG\r\n\x1a\n broken')
    line = one_error(*run(capsys, [str(folder), *ARGS])[::2])
    assert line.endswith(f'{folder / "view01.png"}: not an image OpenCV can read')


def test_no_board_in_any_image(tmp_path, capsys, views):
    folder = write_folder(tmp_path / 'shots', [np.full((240, 320), 128, np.uint8)] * 2)
    line = one_error(*run(capsys, [str(folder), *ARGS])[::2])
    assert line.endswith(f'{folder}: no 6x4 board found in any of 2 images (--size counts '
                         'inner corners: a board of 9x7 squares is 8x6)')
    # The board is there but --size says squares, not inner corners.
    folder = write_folder(tmp_path / 'board', views)
    line = one_error(*run(capsys, [str(folder), '--size', '7x5'])[::2])
    assert 'no 7x5 board found in any of 6 images' in line


def test_a_file_that_is_no_video(tmp_path, capsys):
    path = tmp_path / 'run.avi'
    path.write_text('not a video')
    line = one_error(*run(capsys, [str(path)])[::2])
    assert line.endswith(f'{path}: not a video, image folder or bag OpenCV or rosbags can read')


def test_a_bag_without_the_topic_or_with_another_type(tmp_path, capsys, views):
    bag = write_bag(tmp_path / 'bag', '/cam/other', [image_msg(views[0])],
                    'sensor_msgs/msg/Image')
    line = one_error(*run(capsys, [str(bag)])[::2])
    assert line.endswith(f'{bag}: no topic /camera/image_raw; the image topics in it: '
                         '/cam/other')
    bag = write_bag(tmp_path / 'imu', '/imu/data', [Imu()], 'sensor_msgs/msg/Imu')
    line = one_error(*run(capsys, [str(bag), '--topic', 'imu/data'])[::2])
    assert line.endswith(f'{bag}: /imu/data is sensor_msgs/msg/Imu, not sensor_msgs/msg/Image '
                         'or sensor_msgs/msg/CompressedImage')


def test_an_image_encoding_we_cannot_read(tmp_path, capsys, views):
    msg = image_msg(views[0])
    msg.encoding = 'yuv422'
    bag = write_bag(tmp_path / 'bag', '/camera/image_raw', [msg], 'sensor_msgs/msg/Image')
    line = one_error(*run(capsys, [str(bag)])[::2])
    assert "image encoding 'yuv422' is not one of" in line


@pytest.mark.parametrize('argv, message', [
    (['--size', '8by6'], '--size: expected COLSxROWS inner corners, each at least 2'),
    (['--size', '1x6'], '--size: expected COLSxROWS'),
    (['--square', '0'], '--square must be a positive length in metres, got 0.0'),
    (['--square', 'nan'], '--square must be a positive length in metres, got nan'),
    (['--duration', '-1'], '--duration must be a positive finite number of seconds'),
    (['--views', '2'], '--views must be at least 3, got 2'),
])
def test_bad_options(tmp_path, capsys, argv, message):
    line = one_error(*run(capsys, [str(tmp_path), *argv])[::2])
    assert message in line


def test_the_manuals_square_of_0_40_is_warned_about(tmp_path, capsys, views):
    # The manual's command line says --square 0.40 for its 40 mm squares: 40 cm.
    folder = write_folder(tmp_path / 'shots', views)
    rc, _, err = run(capsys, [str(folder), '--size', '6x4', '--square', '0.40'])
    assert rc == 0
    assert ('enbarr calibrate: warning: --square 0.4 m is a square of 40 cm; a 40 mm square '
            'is 0.040') in err


@pytest.mark.parametrize('encoding, data, bigendian, want', [
    ('rgb8', [255, 0, 0], 0, [0, 0, 255]),            # red
    ('bgr8', [255, 0, 0], 0, [255, 0, 0]),            # blue
    ('rgba8', [255, 0, 0, 7], 0, [0, 0, 255]),
    ('bgra8', [255, 0, 0, 7], 0, [255, 0, 0]),
    ('mono8', [200], 0, 200),
    ('mono16', [0x12, 0xAB], 1, 0x12),                # big-endian: the high byte first
    ('mono16', [0x12, 0xAB], 0, 0xAB),
])
def test_image_encodings(encoding, data, bigendian, want):
    msg = Image()
    msg.height, msg.width, msg.encoding, msg.is_bigendian = 1, 1, encoding, bigendian
    msg.step = len(data) + 3                            # rows padded, as drivers may
    msg.data = bytes(data + [0, 0, 0])
    assert decode_image(msg, 'here')[0, 0].tolist() == want


def test_calibrate_has_a_table_of_actions():
    assert list(ACTIONS) == ['camera', 'pairs', 'lidar', 'reproject']
    assert all(isinstance(load_action(name), CalibrationAction) for name in ACTIONS)
