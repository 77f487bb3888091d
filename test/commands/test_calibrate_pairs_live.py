"""``enbarr calibrate pairs --live``: pairs from scans and images published in the test (a post
held at known places, drawn where it is), and a topic that carries nothing."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from enbarr_core.commands import main as cli
from enbarr_core.commands.calibrate_lidar import read_pairs
from enbarr_core.world.model import Circle, Obstacle, World

pytestmark = pytest.mark.node

RAYS = 360
RADIUS = 0.1
# (laser point [m], pixel of the post's centroid): five places, each held 2 s
PLACES = [((1.5, 0.4), (50.0, 125.0)), ((2.5, -0.5), (250.0, 122.0)),
          ((1.2, -0.3), (210.0, 131.0)), ((2.0, 0.6), (80.0, 124.0)),
          ((2.8, 0.1), (150.0, 121.0))]
#: A buoy beside the vessel, outside the region: the lidar sees it in every scan.
BUOY = Obstacle('buoy', Circle((1.0, -2.5), 0.1))
SCAN_PERIOD = 0.2      # [s] of stamps between scans (two images each)
SPEEDUP = 4.0          # stamps run this much faster than the wall clock


def timeline() -> list[tuple[float, tuple[float, float], tuple[float, float]]]:
    """(stamp [s], post centre, its pixel): held 2 s at each place, then carried to the next
    (the last: towards the first) in two scans, seen by both sensors on the way."""
    out = []
    t = 0.0
    for k, (xy, px) in enumerate(PLACES):
        for _ in range(11):
            out.append((t, xy, px))
            t += SCAN_PERIOD
        nxy, npx = PLACES[(k + 1) % len(PLACES)]
        for f in (1 / 3, 2 / 3):
            out.append((t, _lerp(xy, nxy, f), _lerp(px, npx, f)))
            t += SCAN_PERIOD
    return out


def _lerp(a: tuple[float, float], b: tuple[float, float], f: float) -> tuple[float, float]:
    return a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])


def image(px: tuple[float, float]) -> np.ndarray:
    img = np.zeros((240, 320, 3), np.uint8)
    u, v = int(px[0]), int(px[1])
    img[v - 20:v + 21, u - 4:u + 5] = (60, 160, 30)   # green, centroid (u, v)
    return img


class Publisher:
    """Publishes the timeline on scan and camera/image_raw from a thread, once."""

    def __init__(self, context: object) -> None:
        import rclpy
        from sensor_msgs.msg import Image, LaserScan
        from enbarr_interfaces import topics
        self.node = rclpy.create_node('fake_sensors', context=context)
        self.scan_pub = self.node.create_publisher(LaserScan, 'scan', topics.SCAN.qos)
        self.image_pub = self.node.create_publisher(Image, 'camera/image_raw',
                                                    topics.CAMERA_IMAGE.qos)
        self.msgs = []
        angles = -math.pi + np.arange(RAYS) * (2 * math.pi / RAYS)
        for t, xy, px in timeline():
            world = World([Obstacle('post', Circle(xy, RADIUS)), BUOY])
            scan = LaserScan()
            scan.header.stamp.sec, scan.header.stamp.nanosec = divmod(round(t * 1e9), 10**9)
            scan.header.frame_id = 'laser'
            scan.angle_min, scan.angle_increment = -math.pi, 2 * math.pi / RAYS
            scan.angle_max = scan.angle_min + (RAYS - 1) * scan.angle_increment
            scan.range_min, scan.range_max = 0.15, 12.0
            scan.ranges = world.raycast((0.0, 0.0), angles, 0.0).astype(np.float32).tolist()
            imgs = []
            for dt in (0.0, 0.1):
                msg = Image()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(round((t + dt) * 1e9),
                                                                        10**9)
                msg.height, msg.width, msg.encoding, msg.step = 240, 320, 'bgr8', 960
                msg.data = image(px).tobytes()
                imgs.append(msg)
            self.msgs.append((scan, imgs))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        # wait for the command's subscriptions, then play the timeline once
        while not self.stop.wait(0.02):
            if (self.scan_pub.get_subscription_count() and
                    self.image_pub.get_subscription_count()):
                break
        for scan, imgs in self.msgs:
            if self.stop.wait(SCAN_PERIOD / SPEEDUP):
                return
            self.scan_pub.publish(scan)
            for m in imgs:
                self.image_pub.publish(m)

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


def test_pairs_from_the_live_topics(publisher, tmp_path, capsys):
    # the timeline lasts 5 x 13 x 0.2 s / 4 = 3.25 s of wall time once the command listens;
    # --count ends the listening at the fifth place, --seconds bounds it
    out = tmp_path / 'marks.csv'
    rc = cli.main(['calibrate', 'pairs', '--live', '--seconds', '20', '--count', '5',
                   '--image-topic',
                   'camera/image_raw', '--colour', 'green', '--mark-radius', str(RADIUS),
                   '--region', '0.5,3.5,-1.5,1.5', '-o', str(out)])
    stdout, err = capsys.readouterr()
    assert rc == 0, err
    xy, uv = read_pairs(str(out))
    assert len(xy) == len(PLACES), stdout
    for (want_xy, want_uv), got_xy, got_uv in zip(PLACES, xy, uv):
        assert got_xy == pytest.approx(want_xy, abs=2e-3)
        assert got_uv == pytest.approx(want_uv, abs=1e-6)
    assert out.read_text().startswith('x,y,u,v\n# enbarr calibrate pairs from live, pixels by '
                                      'colour\n')


def test_a_topic_without_scans_is_one_error_line(publisher, capsys):
    rc = cli.main(['calibrate', 'pairs', '--live', '--seconds', '1', '--scan-topic',
                   'scan/nothing', '--colour', 'green', '-o', 'unused.csv'])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith('enbarr calibrate: error: scan/nothing: no message in 1 s; such '
                             'topics seen: '), err[0]
    assert '/scan' in err[0]
