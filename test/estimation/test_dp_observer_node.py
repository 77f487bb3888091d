"""Node tests: dp observer node."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from support.nodes import TIMEOUT, add, probe
from support.saucer import SimClock, overrides, pose_msg

from enbarr_core.estimation.dp_observer_node import DpObserverNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_dp_observer_rejects_jumps_and_dead_reckons(context, executor):
    node = add(executor, DpObserverNode(node_name='observer', context=context,
                                        parameter_overrides=overrides(node='observer')))
    clock = SimClock(node)
    p = probe(context, executor, 'mocap')
    pose_pub = p.create_topic_publisher(topics.MOCAP_POSE)
    odoms: list[Odometry] = []
    ages: list[float] = []
    p.create_topic_subscription(topics.OBSERVER_ODOMETRY, odoms.append)
    p.create_topic_subscription(topics.OBSERVER_AGE, lambda m: ages.append(m.data))
    LinkBus.of(context).connect()

    def pose(dt_s: float, eta: Any) -> None:
        t = clock.advance(dt_s)
        pose_pub.publish(pose_msg(t, eta))

    def eta_hat() -> np.ndarray:
        return convert.pose_to_eta(odoms[-1].pose.pose)

    here = [1.0, 2.0, 0.5]
    pose(0.0, here)  # the first pose initializes the estimate: nothing published yet
    assert node.observer.initialized and not odoms and node.rejected == 0
    pose(0.02, here)
    assert len(odoms) == 1 and ages == [0.0]
    assert eta_hat() == pytest.approx(here, abs=1e-9)
    assert convert.stamp_to_ns(odoms[-1].header.stamp) == clock.ns

    # 2 m away: an implausible jump, rejected, counted and not followed.
    pose(0.02, [3.0, 2.0, 0.5])
    assert node.rejected == 1 and len(odoms) == 2
    assert eta_hat() == pytest.approx(here, abs=1e-6)
    assert ages[-1] == pytest.approx(0.02)
    # NaN: rejected, nothing published.
    msg = pose_msg(clock.advance(0.02), here)
    msg.pose.position.x = math.nan
    pose_pub.publish(msg)
    assert node.rejected == 2 and len(odoms) == 2

    # Poses stop: the observer's timer dead-reckons on (integrating in steps of 1/rate), the
    # measurement age grows.
    n = len(odoms)

    def dead_reckoned() -> bool:
        return ages[-1] > 0.2 and len(odoms) >= n + 2

    deadline = time.monotonic() + TIMEOUT
    while not dead_reckoned() and time.monotonic() < deadline:
        clock.advance(0.02)
        executor.spin_once(timeout_sec=0.05)
    assert dead_reckoned()
    assert np.all(np.diff(ages[n - 1:]) > 0.0)
    stamps = [convert.stamp_to_ns(o.header.stamp) for o in odoms]
    assert np.all(np.diff(stamps) > 0)
    assert eta_hat() == pytest.approx(here, abs=1e-3)  # at rest, no force: stays put
    assert node.rejected == 2

    # A plausible pose again: accepted, the age is back to zero.
    pose(0.01, [1.01, 2.0, 0.5])
    assert ages[-1] == 0.0 and node.rejected == 2


@pytest.mark.parametrize('missing', ['k1', 'vessel.linear_damping'])
def test_dp_observer_needs_its_gains_and_vessel_from_the_profile(context, missing):
    from rclpy.parameter import Parameter
    from support.saucer import node_parameters

    from enbarr_core.framework.errors import ConfigurationError
    given = {k: v for k, v in node_parameters('observer').items() if k != missing}
    with pytest.raises(ConfigurationError,
                       match=f"parameter '{missing}' is not set; the profile must give it"):
        DpObserverNode(node_name='observer', context=context,
                       parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])


def test_dp_observer_gain_names_are_lower_case(context, executor):
    node = add(executor, DpObserverNode(node_name='observer', context=context,
                                        parameter_overrides=overrides(node='observer')))
    names = set(node.list_parameters([], 0).names)  # depth 0: every level
    assert {'k1', 'k2', 'k3', 't_b', 'vessel.inertia'} <= names
    assert not {'K1', 'K2', 'K3', 'T_b', 'vessel.M'} & names
    s = node.settings.observer
    assert s.K1 == tuple(node.get_parameter('k1').value)
