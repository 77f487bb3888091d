"""Node tests: guidance node (mode + estimate -> reference for that estimate)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from trajectory_msgs.msg import MultiDOFJointTrajectory
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, String
from support.nodes import TIMEOUT, add, get_param, param_client, probe, set_param
from support.saucer import T0_NS, odometry_msg, overrides

from enbarr_interfaces.modes import Mode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.guidance.guidance_node import GuidanceNode, msg_to_reference
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

PATH = [0.0, 0.0, 2.0, 0.0, 2.0, 2.0]


class Harness:
    """A GuidanceNode, the mode (as the controller publishes it) and estimates in, references
    out."""

    def __init__(self, context: Any, executor: Any, spin: Any, **params: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, GuidanceNode(node_name='guidance', context=context,
                                               parameter_overrides=overrides(params)))
        self.node.start()  # announces path_available before the probe below subscribes
        p = probe(context, executor, 'controller')
        self.mode_pub = p.create_publisher(String, topics.MODE.name, topics.MODE.qos)
        self.available: list[bool] = []
        p.create_subscription(Bool, topics.GUIDANCE_PATH_AVAILABLE.name,
                              lambda m: self.available.append(m.data),
                              topics.GUIDANCE_PATH_AVAILABLE.qos)
        self.odom_pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self.refs: list[MultiDOFJointTrajectory] = []
        p.create_topic_subscription(topics.GUIDANCE_REFERENCE, self.refs.append)
        LinkBus.of(context).connect()
        self.t = T0_NS

    def mode(self, mode: Mode) -> None:
        self.mode_pub.publish(String(data=mode.value))
        assert self.spin(self.executor, lambda: self.node.mode is mode, TIMEOUT)

    def estimate(self, eta: Any, nu: Any = (0.0, 0.0, 0.0)) -> None:
        self.t += 20_000_000
        self.odom_pub.publish(odometry_msg(self.t, eta, nu))


def test_path_available_is_announced_latched(context, executor, spin):
    h = Harness(context, executor, spin)  # subscribes after the node published
    assert spin(executor, lambda: h.available == [False], TIMEOUT)
    assert not h.node.settings.waypoints
    h.node.set_parameters([Parameter('path.waypoints', value=PATH)])
    assert spin(executor, lambda: h.available == [False, True], TIMEOUT)


def test_manual_publishes_nothing(context, executor, spin):
    h = Harness(context, executor, spin)
    h.estimate([0.1, 0.2, 0.3])
    h.estimate([0.1, 0.2, 0.3])
    assert not h.refs and h.node.mode is Mode.MANUAL


def test_automatic_holds_the_pose_of_the_latest_estimate(context, executor, spin):
    h = Harness(context, executor, spin)
    eta0 = [0.3, -0.2, 0.4]
    h.estimate(eta0)
    h.mode(Mode.AUTOMATIC)
    h.estimate([0.5, 0.0, 0.0])
    assert len(h.refs) == 1
    ref = msg_to_reference(h.refs[-1])
    assert convert.stamp_to_ns(h.refs[-1].header.stamp) == h.t  # for this estimate
    assert ref.eta_d == pytest.approx(eta0, abs=1e-12)
    assert ref.position_mask == (True, True, True)
    h.mode(Mode.MANUAL)
    h.estimate([0.5, 0.0, 0.0])
    assert len(h.refs) == 1  # nothing in manual again


def test_guidance_follows_the_path_with_line_of_sight(context, executor, spin):
    h = Harness(context, executor, spin, **{'path.waypoints': PATH})
    h.estimate([0.0, 0.5, 0.0])
    h.mode(Mode.GUIDANCE)
    h.estimate([0.0, 0.5, 0.0])  # 0.5 m left of the first leg
    ref = msg_to_reference(h.refs[-1])
    assert ref.position_mask == (False, False, True)  # velocity tracking, heading held
    assert np.isnan(ref.eta_d[:2]).all()  # no position reference on the topic
    assert ref.eta_d[2] == pytest.approx(0.0, abs=1e-12)
    # The law's own reference keeps the closest point on the path (tests and logs only).
    assert h.node.reference.eta_d[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
    assert math.hypot(*ref.nu_d[:2]) == pytest.approx(0.2)  # path.speed
    assert ref.nu_d[1] < 0.0  # steering back right, towards the path


def test_one_waypoint_is_gone_to(context, executor, spin):
    h = Harness(context, executor, spin, **{'path.waypoints': [3.0, 1.5]})
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.GUIDANCE)
    for _ in range(50):
        h.estimate([0.0, 0.0, 0.0])
    ref = msg_to_reference(h.refs[-1])
    assert ref.position_mask == (True, True, True)
    assert 0.0 < ref.eta_d[0] < 3.0 and ref.eta_d[1] == pytest.approx(ref.eta_d[0] / 2.0)


def test_a_bad_path_is_refused_with_its_parameter(context):
    with pytest.raises(ConfigurationError, match='path'):
        GuidanceNode(node_name='guidance', context=context, parameter_overrides=overrides(
            {'path.waypoints': [0.0, 0.0, 0.0, 0.0]}))  # zero-length segment
    with pytest.raises(ConfigurationError, match='path.waypoints'):
        GuidanceNode(node_name='guidance', context=context, parameter_overrides=overrides(
            {'path.waypoints': [0.0, 0.0, 1.0]}))


def test_path_heading_is_checked_and_set_live(context, executor, spin):
    node = add(executor, GuidanceNode(node_name='guidance', context=context,
                                      parameter_overrides=overrides()))
    client = param_client(executor, spin, context, 'guidance')
    result = set_param(executor, spin, client, 'path.heading', 'sideways')
    assert not result.successful and 'path.heading' in result.reason
    assert get_param(executor, spin, client, 'path.heading') == 'fixed'
    result = set_param(executor, spin, client, 'path.heading', 'course')
    assert result.successful, result.reason
    assert node.settings.heading == 'course'


def test_a_future_estimate_costs_itself_and_is_reported(context, executor, spin):
    # Before the time policy, an estimate stamped 20 s ahead became the guidance's time base;
    # the good estimates after it were "older" and got no reference.
    from support.saucer import SimClock
    h = Harness(context, executor, spin)
    clock = SimClock(h.node, t0_ns=T0_NS + 20_000_000)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)
    for _ in range(5):
        clock.set(h.t + 20_000_000)
        h.estimate([0.0, 0.0, 0.0])
    n = len(h.refs)
    h.odom_pub.publish(odometry_msg(clock.ns + 20_000_000_000, [0.0, 0.0, 0.0]))
    for _ in range(10):
        clock.set(h.t + 20_000_000)
        h.estimate([0.0, 0.0, 0.0])
    assert len(h.refs) == n + 10
    assert max(convert.stamp_to_ns(r.header.stamp) for r in h.refs) <= clock.ns
    level, message, values = h.node.diagnostic_status()
    assert level == 1 and 'observer/odometry: refused 1 of' in message, message
    assert values['observer/odometry.future'] == 1
    h.node.diagnostic_status()
    # The estimate period is measured: a max_future that could hide the next estimate is
    # refused with it.
    result = h.node.set_parameters([Parameter('max_future', value=0.05)])[0]
    assert not result.successful and 'measured 0.02 s' in result.reason, result.reason
