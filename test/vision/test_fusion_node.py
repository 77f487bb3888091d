"""Node tests: the fusion node in an in-process executor. Synthetic obstacles, poses,
camera_info and detections go in; obstacles/fused (with classes) and diagnostics come out.
"""

from __future__ import annotations

import math
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo
from support.nodes import add, param_client, probe, set_param, TIMEOUT
from support.saucer import odometry_msg

from enbarr_core.bringup.compose import build_nodes
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import Frame, FrameTree, Transform
from enbarr_core.framework.node import install_frame_tree, install_world
from enbarr_core.vision.fusion_node import FusionNode
from enbarr_interfaces import topics
from enbarr_interfaces import detections as det
from enbarr_interfaces.links import LinkBus, LinkPublisher, LinkSubscription
from enbarr_interfaces.obstacles import CIRCLE, cloud_stamp_ns, from_cloud, NO_CLASS, Obstacle
from enbarr_interfaces.obstacles import SEGMENT, to_cloud

MS = 1_000_000
T0 = 50_000 * MS
VESSEL = (10.0, 5.0, math.pi / 2)          # heading north (ENU)
BUOY = Obstacle(4, CIRCLE, 10.0, 9.0, 0.2, stamp_ns=T0)   # 4 m ahead
WALL = Obstacle(7, SEGMENT, -20.0, 12.0, 0.0, x2=20.0, y2=12.0, stamp_ns=T0)
# The camera 0.25 m above base_link, REP-103's optical rotation (as saucer_core.yaml).
TREE = FrameTree.of([
    Frame('odom'), Frame('base_link', 'odom', pose='observer/odometry'),
    Frame('camera_optical_frame', 'base_link',
          Transform.from_rpy((0.0, 0.0, 0.25), (-math.pi / 2, 0.0, -math.pi / 2)))])
# The buoy's box by hand (test_fusion.py: fx = fy = 500, cx 320, cy 240, height 0.5 m).
BUOY_BOX = (294.969, 207.105, 345.031, 272.895)


def camera_info() -> CameraInfo:
    msg = CameraInfo()
    msg.header.frame_id = 'camera_optical_frame'
    msg.width, msg.height = 640, 480
    msg.distortion_model = 'plumb_bob'
    msg.d = [0.0] * 5
    msg.k = [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]
    return msg


class Harness:
    def __init__(self, context, executor, spin, **params) -> None:
        install_frame_tree(context, TREE)
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = add(executor, FusionNode(context=context, parameter_overrides=overrides))
        self.executor, self.spin = executor, spin
        p = probe(context, executor)
        self.odom_pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self.obstacles_pub = p.create_topic_publisher(topics.OBSTACLES)
        self.info_pub = p.create_publisher(CameraInfo, topics.CAMERA_INFO.name,
                                           topics.CAMERA_INFO.qos)
        self.det_pub = p.create_publisher(topics.DETECTIONS.msg_type, topics.DETECTIONS.name,
                                          topics.DETECTIONS.qos)
        self.fused, self.diagnostics = [], []
        p.create_topic_subscription(topics.OBSTACLES_FUSED, self.fused.append)
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                              self.diagnostics.append, topics.DIAGNOSTICS.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.det_pub.get_subscription_count() > 0
                    and self.info_pub.get_subscription_count() > 0, TIMEOUT)

    def info(self) -> None:
        self.info_pub.publish(camera_info())
        assert self.spin(self.executor, lambda: self.node._camera is not None, TIMEOUT)

    def poses(self, around_ns: int) -> None:
        for t in range(around_ns - 200 * MS, around_ns + 200 * MS, 20 * MS):
            self.odom_pub.publish(odometry_msg(t, VESSEL))

    def obstacles(self, obstacles: list[Obstacle], stamp_ns: int) -> list[Obstacle]:
        before = len(self.fused)
        self.obstacles_pub.publish(to_cloud(obstacles, stamp_ns, 'odom'))
        assert self.spin(self.executor, lambda: len(self.fused) > before, TIMEOUT)
        assert cloud_stamp_ns(self.fused[-1]) == stamp_ns
        return from_cloud(self.fused[-1])

    def detections(self, rows: list[tuple], stamp_ns: int) -> None:
        n = self.node.counts['detections_msgs']
        self.det_pub.publish(det.to_cloud(rows, stamp_ns, 'camera_optical_frame'))
        assert self.spin(self.executor, lambda: self.node.counts['detections_msgs'] > n,
                         TIMEOUT)

    def status(self, predicate):
        def found():
            return [s for a in self.diagnostics for s in a.status
                    if s.hardware_id == 'fusion' and predicate(s)]
        assert self.spin(self.executor, lambda: bool(found()), TIMEOUT)
        return found()[-1]


def test_a_detected_buoy_gets_its_class_and_the_rest_stay_obstacles(context, executor, spin):
    h = Harness(context, executor, spin)
    h.info()
    h.poses(T0)
    first = h.obstacles([BUOY, WALL], T0)
    assert [o.class_id for o in first] == [NO_CLASS, NO_CLASS]
    # the buoy's box, and a stray box where no obstacle is: reported, not invented
    h.detections([(3, 0.9, *BUOY_BOX), (1, 0.8, 10.0, 10.0, 40.0, 40.0)], T0 + 30 * MS)
    assert h.node.counts['matched'] == 1
    assert h.node.counts['unmatched_detections'] == 1
    fused = h.obstacles([BUOY, WALL], T0 + 180 * MS)
    assert len(fused) == 2
    buoy, wall = fused
    assert (buoy.id, buoy.class_id, buoy.class_score) == (4, 3, pytest.approx(1.0))
    assert (buoy.x, buoy.y, buoy.radius) == (BUOY.x, BUOY.y, BUOY.radius)
    assert wall.class_id == NO_CLASS and wall.kind == SEGMENT
    status = h.status(lambda s: any(v.key == 'matched' and v.value == '1' for v in s.values))
    values = {v.key: v.value for v in status.values}
    assert values['unmatched_detections'] == '1'
    assert values['tracks_classified'] == '1'


def test_detections_alone_never_refresh_the_fused_obstacles(context, executor, spin):
    """A stalled lidar must leave obstacles/fused as stale as obstacles: the avoidance then
    goes blind and holds (ca_lidar_dropout_fusion) though the camera still sees the buoy."""
    h = Harness(context, executor, spin)
    h.info()
    h.poses(T0)
    h.obstacles([BUOY], T0)
    published = len(h.fused)
    for k in range(1, 6):   # the camera goes on at 15 fps, no scan comes
        h.detections([(3, 0.9, *BUOY_BOX)], T0 + k * 66 * MS)
    assert h.node.counts['matched'] >= 1
    assert len(h.fused) == published
    assert cloud_stamp_ns(h.fused[-1]) == T0


def test_stale_inputs_are_counted_and_not_matched(context, executor, spin):
    h = Harness(context, executor, spin, max_age=0.5)
    h.detections([(3, 0.9, *BUOY_BOX)], T0)
    assert h.node.counts['no_camera_info'] == 1
    h.info()
    h.detections([(3, 0.9, *BUOY_BOX)], T0)
    assert h.node.counts['no_obstacles'] == 1
    h.poses(T0)
    h.obstacles([BUOY], T0)
    h.detections([(3, 0.9, *BUOY_BOX)], T0 + 800 * MS)     # the obstacles 0.8 s old
    assert h.node.counts['stale_obstacles'] == 1
    h.obstacles([BUOY], T0 + 700 * MS)                      # no pose near 0.7 s after T0
    h.detections([(3, 0.9, *BUOY_BOX)], T0 + 700 * MS)
    assert h.node.counts['no_pose'] == 1
    assert h.node.counts['matched'] == 0
    assert from_cloud(h.fused[-1])[0].class_id == NO_CLASS
    h.status(lambda s: s.level == DiagnosticStatus.WARN)


def test_parameters_are_live_and_ranged(context, executor, spin):
    h = Harness(context, executor, spin)
    client = param_client(executor, spin, context, 'fusion')
    assert set_param(executor, spin, client, 'min_iou', 0.95).successful
    assert h.node.settings.fusion.min_iou == 0.95
    assert not set_param(executor, spin, client, 'min_iou', 0.0).successful
    h.info()
    h.poses(T0)
    h.obstacles([BUOY], T0)
    # the hand box shifted 10 px: IoU about 0.67, under the gate of 0.95
    x0, y0, x1, y1 = BUOY_BOX
    h.detections([(3, 0.9, x0 + 10, y0, x1 + 10, y1)], T0)
    assert h.node.counts['matched'] == 0
    assert set_param(executor, spin, client, 'min_iou', 0.5).successful
    h.detections([(3, 0.9, x0 + 10, y0, x1 + 10, y1)], T0)
    assert h.node.counts['matched'] == 1


def test_a_bad_parameter_refuses_the_node(context):
    with pytest.raises(ConfigurationError, match='object_height'):
        FusionNode(context=context, parameter_overrides=[Parameter('object_height', value=-1.0)])


def test_the_mount_comes_from_the_tree(context, executor, spin):
    # the tree's optical frame must map base_link (4, 0, 0.25) onto the optical axis
    h = Harness(context, executor, spin)
    t = h.node._optical_from_base('camera_optical_frame')
    assert t is not None
    assert t[:3, :3] @ np.array([4.0, 0.0, 0.25]) + t[:3, 3] == pytest.approx([0, 0, 4.0])


def test_saucer_fusion_sim_wires_the_guidance_to_the_fused_obstacles(context):
    # The profile's remapping, resolved by the guidance node as bringup builds it: it reads
    # /obstacles/fused, which the fusion node publishes from /obstacles.
    profile = load_profile(str(Path(__file__).parents[2] / 'params' / 'saucer_fusion_sim.yaml'))
    install_frame_tree(context, profile.frames)
    install_world(context, profile.world)
    nodes = build_nodes(profile, context)
    try:
        def links(name: str, kind: type) -> set[str]:
            node = next(n for n in nodes if n.get_name() == name)
            return {link.name for link in node._links if isinstance(link, kind)}
        assert '/obstacles/fused' in links('guidance', LinkSubscription)
        assert '/obstacles' not in links('guidance', LinkSubscription)
        assert links('fusion', LinkPublisher) == {'/obstacles/fused'}
        assert '/obstacles' in links('fusion', LinkSubscription)
    finally:
        for n in reversed(nodes):
            n.destroy_node()


def test_saucer_fusion_split_sim_crosses_the_groups_by_dds(context):
    # Each group in its own context (process), connected as bringup connects it: the links the
    # split breaks (obstacles and odometry to the fusion, obstacles/fused to the guidance)
    # must fall back to DDS subscriptions, and the operator's detector must read the JPEG,
    # the only image the vessel's camera publishes.
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    profile = load_profile(
        str(Path(__file__).parents[2] / 'params' / 'saucer_fusion_split_sim.yaml'))
    operator = Context()
    rclpy.init(context=operator, signal_handler_options=SignalHandlerOptions.NO)
    built: list = []
    try:
        nodes = {}
        for ctx, group in ((context, 'main'), (operator, 'operator')):
            install_frame_tree(ctx, profile.frames)
            install_world(ctx, profile.world)
            group_nodes = build_nodes(profile, ctx, group)
            built += group_nodes
            LinkBus.of(ctx).connect()
            nodes.update({n.get_name(): n for n in group_nodes})
        assert {'detector', 'fusion'} <= nodes.keys() and 'camera' in nodes

        def across(name: str) -> set[str]:
            return {link.name for link in nodes[name]._links
                    if isinstance(link, LinkSubscription) and not link.local}

        def ros_topics(name: str, kind: str) -> set[str]:
            return {e.topic_name for e in getattr(nodes[name], kind)}
        assert {'/obstacles', '/observer/odometry'} <= across('fusion')
        assert '/obstacles/fused' in across('guidance')
        assert '/obstacles' not in {link.name for link in nodes['guidance']._links
                                    if isinstance(link, LinkSubscription)}
        assert '/camera/image_raw/compressed' in ros_topics('detector', 'subscriptions')
        assert '/camera/image_raw' not in ros_topics('camera', 'publishers')
    finally:
        for n in reversed(built):
            n.destroy_node()
        rclpy.try_shutdown(context=operator)
