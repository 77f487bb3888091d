"""Node tests: the scan obstacles node in an in-process executor. A LaserScan cast in
support.lidar_scene and the pose estimate go in; obstacles, markers and diagnostics come out.
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import LaserScan
from support.lidar_scene import Circle, RANGE_MAX, RANGE_MIN, RAYS, cast
from support.nodes import add, probe, TIMEOUT
from support.saucer import odometry_msg
from visualization_msgs.msg import Marker

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import Frame, FrameTree, Transform
from enbarr_core.framework.node import install_frame_tree
from enbarr_core.perception.scan_obstacles_node import ScanObstaclesNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_interfaces.obstacles import CIRCLE, cloud_stamp_ns, from_cloud

MS = 1_000_000
PERIOD_NS = round(1e9 / 5.5)
LASER_XYZ = (0.2, -0.1, 0.15)        # where the lidar sits on base_link (the test's tree)
VESSEL = (1.0, -0.5, 0.3)            # x, y, psi in odom
BUOY = Circle(3.5, 1.0, 0.3)         # in odom
TREE = FrameTree.of([
    Frame('odom'), Frame('base_link', 'odom', pose='observer/odometry'),
    Frame('laser', 'base_link', Transform.from_rpy(LASER_XYZ))])


def laser_pose() -> tuple[float, float, float]:
    x, y, psi = VESSEL
    return (x + math.cos(psi) * LASER_XYZ[0] - math.sin(psi) * LASER_XYZ[1],
            y + math.sin(psi) * LASER_XYZ[0] + math.cos(psi) * LASER_XYZ[1], psi)


def scan_msg(stamp_ns: int, ranges: np.ndarray, frame: str = 'laser') -> LaserScan:
    msg = LaserScan()
    convert.ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = frame
    msg.angle_min = -math.pi
    msg.angle_increment = 2.0 * math.pi / RAYS
    msg.angle_max = msg.angle_min + (RAYS - 1) * msg.angle_increment
    msg.time_increment = 0.0
    msg.scan_time = PERIOD_NS * 1e-9
    msg.range_min, msg.range_max = RANGE_MIN, RANGE_MAX
    msg.ranges = [float(r) for r in ranges]
    return msg


class Harness:
    def __init__(self, context, executor, spin, **params) -> None:
        install_frame_tree(context, TREE)
        overrides = [Parameter(k, value=v) for k, v in {'confirm_hits': 2, **params}.items()]
        self.node = add(executor, ScanObstaclesNode(context=context,
                                                    parameter_overrides=overrides))
        self.executor, self.spin = executor, spin
        p = probe(context, executor)
        self.odom_pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self.scan_pub = p.create_publisher(LaserScan, topics.SCAN.name, topics.SCAN.qos)
        self.clouds, self.markers, self.diagnostics = [], [], []
        p.create_subscription(topics.OBSTACLES.msg_type, topics.OBSTACLES.name,
                              self.clouds.append, topics.OBSTACLES.qos)
        p.create_subscription(topics.OBSTACLE_MARKERS.msg_type,
                              topics.OBSTACLE_MARKERS.name, self.markers.append,
                              topics.OBSTACLE_MARKERS.qos)
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                              self.diagnostics.append, topics.DIAGNOSTICS.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.scan_pub.get_subscription_count() > 0, TIMEOUT)
        self.k = 0

    def poses(self, until_ns: int) -> None:
        # up to the end of the revolution: the scan arrives after its last ray
        for t in range(until_ns - PERIOD_NS, until_ns + PERIOD_NS + 40 * MS, 20 * MS):
            self.odom_pub.publish(odometry_msg(t, VESSEL))

    def scan(self, ranges: np.ndarray, with_pose: bool = True, frame: str = 'laser',
             expect_answer: bool = True) -> int:
        self.k += 1
        stamp = 10_000 * MS + self.k * PERIOD_NS
        if with_pose:
            self.poses(stamp)
        before, scans = len(self.clouds), self.node.scans
        self.scan_pub.publish(scan_msg(stamp, ranges, frame))
        assert self.spin(self.executor, lambda: self.node.scans > scans, TIMEOUT)
        if expect_answer:
            assert self.spin(self.executor, lambda: len(self.clouds) > before, TIMEOUT)
        return stamp

    def buoy_scan(self) -> np.ndarray:
        return cast(*laser_pose(), [BUOY], seed=self.k)


def test_a_buoy_comes_out_in_odom_stamped_with_the_scan(context, executor, spin):
    h = Harness(context, executor, spin)
    stamp = h.scan(h.buoy_scan())
    assert from_cloud(h.clouds[-1]) == []   # seen once: not yet confirmed, but answered
    assert cloud_stamp_ns(h.clouds[-1]) == stamp
    stamp = h.scan(h.buoy_scan())
    cloud = h.clouds[-1]
    assert cloud.header.frame_id == 'odom' and cloud_stamp_ns(cloud) == stamp
    (o,) = from_cloud(cloud)
    assert o.kind == CIRCLE and o.stamp_ns == stamp
    assert math.dist((o.x, o.y), (BUOY.x, BUOY.y)) < 0.08
    assert abs(o.radius - BUOY.r) < 0.08
    assert spin(executor, lambda: len(h.markers) >= 2, TIMEOUT)
    drawn = h.markers[-1].markers
    assert {(m.ns, m.id, m.type) for m in drawn} == {
        ('obstacles', o.id, Marker.CYLINDER), ('obstacle_labels', o.id, Marker.TEXT_VIEW_FACING)}
    assert all(m.header.frame_id == 'odom' for m in drawn)


def test_an_empty_scan_is_answered_and_a_dropped_track_deletes_its_markers(context, executor,
                                                                           spin):
    h = Harness(context, executor, spin, drop_misses=2)
    for _ in range(2):
        h.scan(h.buoy_scan())
    (o,) = from_cloud(h.clouds[-1])
    empty = np.full(RAYS, np.inf)
    h.scan(empty)
    assert [x.id for x in from_cloud(h.clouds[-1])] == [o.id]
    stamp = h.scan(empty)
    assert from_cloud(h.clouds[-1]) == [] and cloud_stamp_ns(h.clouds[-1]) == stamp
    assert spin(executor, lambda: len(h.markers) >= 4, TIMEOUT)
    gone = h.markers[-1].markers
    assert {(m.ns, m.id, m.action) for m in gone} == {
        ('obstacles', o.id, Marker.DELETE), ('obstacle_labels', o.id, Marker.DELETE)}


def test_a_scan_without_a_pose_is_counted_and_not_answered(context, executor, spin):
    h = Harness(context, executor, spin)
    h.scan(h.buoy_scan())
    answered = len(h.clouds)
    h.k += 100    # far past the last pose
    h.scan(h.buoy_scan(), with_pose=False, expect_answer=False)
    assert h.node.without_pose == 1
    level, message, values = h.node.diagnostic_status()
    assert level == 1 and 'not placed' in message and values['scans_without_pose'] == 1
    # the next scan with a pose is answered, and only it: nothing went out for the other
    stamp = h.scan(np.full(RAYS, np.inf))
    assert len(h.clouds) == answered + 1 and cloud_stamp_ns(h.clouds[-1]) == stamp
    assert spin(executor, lambda: any(
        s.hardware_id == 'scan_obstacles' for d in h.diagnostics for s in d.status), TIMEOUT)


def test_a_scan_in_a_frame_the_tree_lacks_is_counted(context, executor, spin):
    h = Harness(context, executor, spin)
    h.scan(h.buoy_scan(), frame='sonar', expect_answer=False)
    assert h.node.unknown_frame == 1 and h.clouds == []


def test_a_minimum_radius_above_the_maximum_is_refused_naming_it(context):
    install_frame_tree(context, TREE)
    with pytest.raises(ConfigurationError, match='min_radius') as err:
        ScanObstaclesNode(context=context, parameter_overrides=[
            Parameter('min_radius', value=2.0), Parameter('max_radius', value=1.0)])
    assert err.value.parameter == 'min_radius'


def test_parameters_change_live_keeping_the_tracks_and_refuse_a_contradiction(
        context, executor, spin):
    from support.nodes import param_client, set_param
    h = Harness(context, executor, spin, confirm_hits=3)
    h.scan(h.buoy_scan())
    (track,) = h.node.pipeline.tracker.circles
    client = param_client(executor, spin, context, 'scan_obstacles')
    assert set_param(executor, spin, client, 'confirm_hits', 1).successful
    assert h.node.pipeline.tracker.settings.confirm_hits == 1
    assert h.node.pipeline.tracker.circles == [track]        # kept
    h.scan(h.buoy_scan())
    assert [o.id for o in from_cloud(h.clouds[-1])] == [track.id]
    refused = set_param(executor, spin, client, 'max_radius', 0.01)
    assert not refused.successful and 'min_radius' in refused.reason
    assert h.node.settings.perception.fit.max_radius == 1.0


def test_a_scan_older_than_the_last_is_counted_and_not_answered(context, executor, spin):
    h = Harness(context, executor, spin)
    h.scan(h.buoy_scan())
    h.scan(h.buoy_scan())
    answered = len(h.clouds)
    h.k -= 2      # the first scan's stamp again: its poses are still in the history
    h.scan(h.buoy_scan(), expect_answer=False)
    assert h.node.out_of_order == 1
    h.k += 2
    stamp = h.scan(np.full(RAYS, np.inf))
    assert len(h.clouds) == answered + 1 and cloud_stamp_ns(h.clouds[-1]) == stamp
    assert h.node.diagnostic_status()[2]['scans_out_of_order'] == 1


def test_a_pose_never_waits_for_a_scan_being_processed(context, executor, spin):
    # The observer's publish calls the node on the control chain's thread: it must not
    # wait for the pipeline (held here as a scan in progress holds it).
    import threading
    h = Harness(context, executor, spin)
    with h.node._lock:
        t = threading.Thread(target=h.odom_pub.publish, args=(odometry_msg(5 * MS, VESSEL),))
        t.start()
        t.join(TIMEOUT)
        assert not t.is_alive()
    assert len(h.node.poses) == 1
