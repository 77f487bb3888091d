"""The simulated camera node (sim_camera): frames scheduled by the truth's stamps at the frame
rate, the world rendered at each frame's stamp from the mount of the frame tree, the topics
and types of the real driver, and the JPEG as image_transport's compressed transport sends it
(decoded back here)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from support.nodes import add, probe, TIMEOUT
from support.saucer import odometry_msg, SimClock, T0_NS

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import Frame, FrameTree, Transform
from enbarr_core.framework.node import install_frame_tree, install_world
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Walls, World
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.camera.sim import SimCameraNode
from enbarr_plugins.camera.sim_render import Look, PinholeModel, SimulatedCamera

pytestmark = pytest.mark.node

BASIN = Obstacle('basin', Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225),
                                 (-20.0, 3.225)), closed=True))
# The CS Saucer's frames (params/saucer_core.yaml): the camera 0.08 m behind the CO, 0.25 m up,
# its optical frame rpy (-90 deg, 0, -90 deg) under camera_link.
OPTICAL = Transform.from_rpy((0.0, 0.0, 0.0), (-math.pi / 2, 0.0, -math.pi / 2))
TREE = FrameTree.of([
    Frame('odom'), Frame('base_link', 'odom', pose='observer/odometry'),
    Frame('camera_link', 'base_link', Transform((-0.08, 0.0, 0.25))),
    Frame('camera_optical_frame', 'camera_link', OPTICAL)])
# image_transport's compressed plugin, compressed_publisher.cpp: format = the encoding +
# "; jpeg compressed " + "bgr8" for a colour image
IMAGE_TRANSPORT_JPEG_FORMAT = 'bgr8; jpeg compressed bgr8'


class Rig:
    def __init__(self, context, executor, spin, world, tree=TREE, subscribe=True, **params):
        install_world(context, world, epoch_ns=T0_NS)
        install_frame_tree(context, tree)
        self.executor, self.spin = executor, spin
        self.node = add(executor, SimCameraNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        self.node.start()
        self.clock = SimClock(self.node)
        p = probe(context, executor, 'simulator')
        self.truth = p.create_topic_publisher(self.topic('SIM_ODOMETRY'))
        self.raw: list[Image] = []
        self.jpeg: list[CompressedImage] = []
        self.info: list[CameraInfo] = []
        self.subscribe = subscribe
        for name, cls, out in (('camera/image_raw', Image, self.raw),
                               ('camera/image_raw/compressed', CompressedImage, self.jpeg),
                               ('camera/camera_info', CameraInfo, self.info)):
            if subscribe or cls is CameraInfo:
                p.create_subscription(cls, name, out.append, self.topic('CAMERA_IMAGE').qos)
        LinkBus.of(context).connect()
        topic = 'camera/image_raw/compressed' if subscribe else 'camera/camera_info'
        assert spin(executor, lambda: self.node.count_subscribers(topic) > 0, TIMEOUT)

    @staticmethod
    def topic(name):
        from enbarr_interfaces import topics
        return getattr(topics, name)

    def feed(self, eta=(0.0, 0.0, 0.0)):
        """One truth now, its frame (if due) received, then 10 ms on."""
        n = self.node.truths
        self.truth.publish(odometry_msg(self.clock.ns, list(eta)))
        node = self.node
        assert self.spin(self.executor, lambda: node.truths == n + 1 and node.idle
                         and len(self.info) == node.frames
                         and (not self.subscribe or len(self.jpeg) == node.frames), TIMEOUT)
        self.clock.advance(0.01)


def seconds(msg) -> float:
    return (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec - T0_NS) * 1e-9


def test_frames_at_the_frame_rate_of_truth_time_with_the_drivers_topics(
        context, executor, spin):
    rig = Rig(context, executor, spin, World([BASIN]))
    for _ in range(101):  # 1 s of truth at 100 Hz
        rig.feed()
    # frame k due at k/15 s, sent on the first truth at or after it (10 ms truths)
    assert [seconds(m) for m in rig.jpeg] == pytest.approx(
        [0.0, 0.07, 0.14, 0.2, 0.27, 0.34, 0.4, 0.47, 0.54, 0.6, 0.67, 0.74, 0.8, 0.87,
         0.94, 1.0], abs=1e-6)
    assert rig.node.status_values()['frames'] == 16
    raw, jpeg, info = rig.raw[-1], rig.jpeg[-1], rig.info[-1]
    assert raw.header == jpeg.header == info.header
    assert raw.header.frame_id == 'camera_optical_frame'
    assert (raw.width, raw.height, raw.encoding, raw.step) == (640, 480, 'bgr8', 1920)
    assert jpeg.format == IMAGE_TRANSPORT_JPEG_FORMAT
    image = np.frombuffer(bytes(raw.data), np.uint8).reshape(480, 640, 3)
    decoded = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (480, 640, 3)
    assert np.abs(decoded.astype(int) - image).mean() < 3.0  # JPEG at quality 80
    assert bytes(jpeg.data)[:2] == b'\xff\xd8'  # a JPEG's SOI marker
    assert len(jpeg.data) < len(raw.data) / 8
    # the model rendered is the one announced: 500 px, centred, the default barrel
    assert (info.width, info.height, info.distortion_model) == (640, 480, 'plumb_bob')
    assert list(info.k) == [500.0, 0.0, 319.5, 0.0, 500.0, 239.5, 0.0, 0.0, 1.0]
    assert list(info.d) == [-0.12, 0.02, 0.0, 0.0, 0.0]
    assert list(info.p) == [500.0, 0.0, 319.5, 0.0, 0.0, 500.0, 239.5, 0.0, 0.0, 0.0, 1.0,
                            0.0]


def test_a_truth_stamped_ahead_is_refused_and_does_not_move_the_frames(
        context, executor, spin):
    """A truth stamped ahead of the clock is refused and counted (DEGRADED for it): it
    neither makes a frame nor moves the schedule of the next ones."""
    rig = Rig(context, executor, spin, World([BASIN]), width=64, height=48, focal_length=50.0)
    for _ in range(10):
        rig.feed()
    node = rig.node
    for ahead in (20.0, 5.0):
        rig.truth.publish(odometry_msg(rig.clock.ns + round(ahead * 1e9), [0.0, 0.0, 0.0]))
    assert spin(executor, lambda: node.status_values()['refused'] == 2, TIMEOUT)
    level, message = node.status()
    assert level == 1 and 'sim/odometry: refused 2 of 12' in message, message
    for _ in range(91):
        rig.feed()
    assert [seconds(m) for m in rig.jpeg] == pytest.approx(
        [0.0, 0.07, 0.14, 0.2, 0.27, 0.34, 0.4, 0.47, 0.54, 0.6, 0.67, 0.74, 0.8, 0.87,
         0.94, 1.0], abs=1e-6)
    assert node.truths == 101


def test_the_world_is_drawn_at_the_stamp_from_the_mount_at_the_true_pose(
        context, executor, spin):
    """A buoy crossing from left to right 4 m ahead of a vessel at (1, 0.5) heading 20 deg:
    each frame is what the camera at the frame tree's mount sees of the world at the frame's
    world time (the renderer checked on its own in test_sim_render)."""
    buoy = Obstacle('buoy', Circle((5.0, 3.0), 0.2), ConstantVelocity((0.0, -3.0)),
                    colour=(220, 30, 30))
    world = World([BASIN, buoy])
    rig = Rig(context, executor, spin, world, frame_rate=5.0)
    eta = (1.0, 0.5, math.radians(20.0))
    for _ in range(41):
        rig.feed(eta)
    assert len(rig.raw) == 3
    mount = TREE.lookup('base_link', 'camera_optical_frame')
    cam = SimulatedCamera(PinholeModel.nominal(640, 480, 500.0, (-0.12, 0.02, 0, 0, 0)),
                          mount, Look(seed=1))
    columns = []
    for msg in rig.raw:
        image = np.frombuffer(bytes(msg.data), np.uint8).reshape(480, 640, 3)
        t = seconds(msg)
        expected = cam.render(world, eta[0], eta[1], eta[2], t)
        assert np.array_equal(image, expected.image)
        columns.append(np.nonzero(expected.labels == 1)[1].mean())
    assert columns[0] < columns[1] < columns[2]  # it moves left to right in the image


def test_the_jpeg_quality_and_no_raw_image(context, executor, spin):
    rig = Rig(context, executor, spin, World([BASIN]), publish_raw=False, jpeg_quality=30)
    rig.feed()
    assert rig.node.count_publishers('camera/image_raw') == 0
    assert not rig.raw and len(rig.jpeg) == 1
    small = len(rig.jpeg[0].data)
    rig.node.set_parameters([Parameter('jpeg_quality', value=95)])
    for _ in range(7):
        rig.feed()
    assert len(rig.jpeg) == 2 and len(rig.jpeg[1].data) > 1.5 * small


def test_nothing_is_encoded_while_nobody_subscribes(context, executor, spin):
    """As image_transport: no subscriber to the JPEG or the raw image, no encoding (the
    camera_info still goes out, a frame's heartbeat)."""
    rig = Rig(context, executor, spin, World([BASIN]), subscribe=False, frame_rate=5.0)
    for _ in range(21):
        rig.feed()
    assert rig.node.frames == 2 and len(rig.info) == 2
    assert rig.node.status_values()['encoded'] == 0


def test_a_missing_frame_a_tilted_mount_and_bad_parameters_are_named(context):
    install_world(context, World())
    install_frame_tree(context, FrameTree.of([Frame('base_link')]))
    with pytest.raises(ConfigurationError, match="frame_id: the frame tree cannot place the "
                                                 "camera: no frame 'camera_optical_frame'"):
        SimCameraNode(context=context)
    install_frame_tree(context, FrameTree.of([
        Frame('base_link'), Frame('cam', 'base_link', Transform.from_rpy(
            (0.0, 0.0, 0.3), (-math.pi / 2 - 0.2, 0.0, -math.pi / 2)))]))
    with pytest.raises(ConfigurationError, match='must be level'):
        SimCameraNode(context=context, parameter_overrides=[Parameter('frame_id', value='cam')])
    with pytest.raises(ConfigurationError, match='distortion: expected k1, k2, p1, p2, k3'):
        SimCameraNode(context=context, parameter_overrides=[
            Parameter('frame_id', value='cam'), Parameter('distortion', value=[0.1, 0.0])])
    with pytest.raises(ConfigurationError, match='lens_file: .*nothing.yaml'):
        SimCameraNode(context=context, parameter_overrides=[
            Parameter('lens_file', value='/nonexistent/nothing.yaml')])


def test_frames_rendered_in_the_callers_step_are_all_rendered(context, executor, spin):
    """On simulated time (``enbarr scenario``) the caller renders each due frame: its thread
    is stopped, ``render_pending`` renders the due one once and says so, and no frame is
    skipped: 16 frames in 1 s of truth, each at its stamp."""
    rig = Rig(context, executor, spin, World([BASIN]), width=64, height=48, focal_length=50.0)
    node = rig.node
    assert node.render_in_caller() and not node._loop.running
    assert not node.render_pending()  # nothing due yet
    for _ in range(101):
        n = node.truths
        rig.truth.publish(odometry_msg(rig.clock.ns, [0.0, 0.0, 0.0]))
        assert spin(executor, lambda: node.truths == n + 1, TIMEOUT)
        if node.render_pending():
            assert spin(executor, lambda: len(rig.jpeg) == node.frames, TIMEOUT)
        rig.clock.advance(0.01)
    assert node.frames == 16 and node.skipped == 0 and not node.render_pending()
    assert [seconds(m) for m in rig.jpeg] == pytest.approx([k / 15 for k in range(16)],
                                                          abs=0.01)
