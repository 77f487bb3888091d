"""``enbarr calibrate camera`` on the live image topic: views from a publisher of rendered
frames, and a topic that carries nothing.
"""

from __future__ import annotations

import threading

import pytest

from enbarr_core.commands import main as cli
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.vision.board import Board, calibration_poses, Camera, render_board
from enbarr_interfaces import topics
from enbarr_plugins.camera.calibration import load_calibration

pytestmark = pytest.mark.node

CAM = Camera(320, 240, 260.0, 262.0, 161.5, 118.5, (-0.2, 0.05, 0.0, 0.0, 0.0))
BOARD = Board(6, 4, 0.05)


class Publisher:
    """Publishes rendered views on camera/image_raw from a thread, round and round."""

    def __init__(self, context: object) -> None:
        from sensor_msgs.msg import Image
        poses = [p for i, p in enumerate(calibration_poses(CAM, BOARD, 8, seed=5))
                 if i % 4 != 3]
        self.msgs = []
        for i, pose in enumerate(poses):
            img = render_board(CAM, BOARD, pose, seed=i, color=True)
            msg = Image()
            msg.height, msg.width = 240, 320
            msg.encoding, msg.step = 'bgr8', 960
            msg.data = img.tobytes()
            self.msgs.append(msg)
        self.node = EnbarrNode('fake_camera', context=context)
        self.pub = self.node.create_publisher(Image, topics.CAMERA_IMAGE.name,
                                              topics.CAMERA_IMAGE.qos)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        i = 0
        while not self.stop.wait(0.05):
            self.pub.publish(self.msgs[i % len(self.msgs)])
            i += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.node.destroy_node()


@pytest.fixture
def publisher(context):
    p = Publisher(context)
    try:
        yield p
    finally:
        p.close()


def test_views_from_the_live_topic(publisher, tmp_path, capsys):
    rc = cli.main(['calibrate', 'camera', '--size', '6x4', '--square', '0.05', '--duration',
                   '6', '--views', '3', '-o', str(tmp_path / 'cam.yaml')])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert 'kept (camera/image_raw at ' in out
    cal = load_calibration(str(tmp_path / 'cam.yaml'))
    assert cal.k[0] == pytest.approx(CAM.fx, rel=0.03) and (cal.width, cal.height) == (320, 240)


def test_a_topic_without_images_is_one_error_line(publisher, capsys):
    rc = cli.main(['calibrate', 'camera', '--topic', 'camera/nothing', '--timeout', '1',
                   '--duration', '10'])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith('enbarr calibrate: error: camera/nothing: no image in 1 s; image '
                             'topics seen: ')
