"""Node tests: the DP observer's time policy, honest diagnostics and rate-aware parameters.
Every test runs on a simulated clock that only the test advances.
"""

from __future__ import annotations

import math
import re
import sys
import threading
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.nodes import add, probe
from support.saucer import SimClock, overrides, pose_msg

from enbarr_core.estimation.dp_observer_node import DpObserverNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

HERE = [1.0, 2.0, 0.5]
PERIOD = 0.02  # the pose period of these tests: 50 Hz, as the simulated motion capture


class Observer:
    """An observer node on a simulated clock, its pose input and its outputs (links)."""

    def __init__(self, context: Any, executor: Any, extra: dict[str, Any] | None = None):
        self.executor = executor
        self.node = add(executor, DpObserverNode(
            node_name='observer', context=context,
            parameter_overrides=overrides(extra, node='observer')))
        self.clock = SimClock(self.node)
        p = probe(context, executor, 'mocap')
        self.pub = p.create_topic_publisher(topics.MOCAP_POSE)
        self.odoms: list[tuple[int, int]] = []   # (clock when published, stamp)
        self.ages: list[float] = []
        p.create_topic_subscription(topics.OBSERVER_ODOMETRY, lambda m: self.odoms.append(
            (self.clock.ns, convert.stamp_to_ns(m.header.stamp))))
        p.create_topic_subscription(topics.OBSERVER_AGE, lambda m: self.ages.append(m.data))
        LinkBus.of(context).connect()

    def poses(self, n: int, ahead: float = 0.0, eta: Any = HERE) -> None:
        """``n`` poses, one per PERIOD of the clock, stamped ``ahead`` [s] of it; the timers
        (dead reckoning) run between them.
        """
        for _ in range(n):
            t = self.clock.advance(PERIOD)
            self.pub.publish(pose_msg(t + round(ahead * 1e9), eta))
            self.executor.spin_once(timeout_sec=0.0)


def test_one_future_pose_costs_itself_and_never_becomes_the_time_base(context, executor):
    # Before the time policy, one mocap/pose stamped 20 s ahead became the observer's time
    # base: every good pose after it looked old and was dropped for 20 s, the estimate was one
    # 20 s step, and the observer said "ok, age 0.0" all along.
    o = Observer(context, executor)
    o.poses(50)
    n = len(o.odoms)
    t = o.clock.advance(PERIOD)
    o.pub.publish(pose_msg(t + 20_000_000_000, HERE))
    o.poses(50)
    assert all(stamp <= now for now, stamp in o.odoms), 'an estimate stamped in the future'
    assert len(o.odoms) == n + 50 and o.ages[-50:] == [0.0] * 50  # every good pose used
    assert o.node.health.totals[('mocap/pose', 'future')] == 1
    e = o.node.estimate
    assert e.eta_hat == pytest.approx(HERE, abs=1e-6) and np.abs(e.nu_hat).max() < 1e-6


def test_a_past_pose_is_refused_and_counted(context, executor):
    o = Observer(context, executor)
    o.poses(20)
    n = len(o.odoms)
    o.pub.publish(pose_msg(o.clock.ns - 500_000_000, [1.1, 2.0, 0.5]))  # 0.5 s old
    o.pub.publish(pose_msg(o.clock.ns, HERE))                            # a repeat
    assert len(o.odoms) == n
    assert o.node.health.totals[('mocap/pose', 'not_newer')] == 2


def test_a_mocap_clock_ahead_is_reported_not_ok_age_zero(context, executor):
    # A motion-capture computer whose clock runs 1 s ahead: every pose is refused, so the
    # observer has no estimate, and /diagnostics must say so and why.
    o = Observer(context, executor)
    # 2.8 s: the node's own 1 s report closes the input-health window at 1, 2 and 3 s, and
    # must not have closed it at the instant asked here
    o.poses(140, ahead=1.0)
    level, message, values = o.node.diagnostic_status()
    assert level == 1, message
    assert re.search(r'mocap/pose: refused (\d+) of \1 in 1 s \(future \1\)', message), message
    assert values['mocap/pose.future'] == 140 and not o.odoms


def test_poses_ahead_within_max_future_are_taken(context, executor):
    # Another computer's clock (chrony: milliseconds) a little ahead is the normal case.
    o = Observer(context, executor)
    o.poses(50, ahead=0.008)
    assert len(o.odoms) == 49 and o.ages[-1] == 0.0
    assert o.node.diagnostic_status()[:2] == (0, 'ok')


def test_pose_rate_dependent_parameters_are_refused_with_the_measured_period(
        context, executor):
    o = Observer(context, executor)
    node = o.node
    assert node.set_parameters([Parameter('stale_after', value=0.03)])[0].successful  # unknown
    assert node.set_parameters([Parameter('stale_after', value=2.0)])[0].successful
    o.poses(20)
    result = node.set_parameters([Parameter('stale_after', value=0.03)])[0]
    assert not result.successful
    assert 'stale_after' in result.reason and 'measured 0.02 s' in result.reason
    result = node.set_parameters([Parameter('max_future', value=0.02)])[0]
    assert not result.successful and 'max_future' in result.reason
    assert node.settings.observer.stale_after == 2.0 and node.settings.max_future == 0.01
    assert node.set_parameters([Parameter('stale_after', value=0.5)])[0].successful


def test_a_harmful_start_value_is_reported_once_the_period_is_measured(context, executor):
    o = Observer(context, executor, extra={'stale_after': 0.03})
    o.poses(5)
    assert o.node.diagnostic_status()[0] == 0 and not o.node.problems  # not measured yet
    o.poses(20)
    level, message, _ = o.node.diagnostic_status()
    assert level == 1 and 'stale_after 0.03 s' in message and 'measured 0.02 s' in message
    assert len(o.node.problems) == 1 and 'stale_after' in o.node.problems[0]


def test_a_diverged_estimate_is_reset_and_reported(context, executor):
    o = Observer(context, executor)
    o.poses(10)
    o.node.observer._x[3] = math.inf  # as a blown-up state would be
    o.poses(1)
    assert o.node.observer.divergences == 1
    level, message, _ = o.node.diagnostic_status()
    assert level == 1 and 'reset estimate 1x' in message
    o.poses(3)  # the next pose starts it over
    assert o.node.observer.initialized and o.ages[-1] == 0.0


def test_poses_arriving_late_are_still_taken(context, executor):
    # Found by test/e2e/test_time_saucer.py: with the observer in its own process, poses cross
    # DDS and arrive tens of milliseconds after their stamp. Dead reckoning (10 Hz) moved the
    # estimate to the clock's present whenever the last pose was 30 ms old, and the next poses,
    # stamped before that, were dropped as late: 8 % of them, every second.
    o = Observer(context, executor)
    o.poses(100, ahead=-0.04)
    assert o.node.health.totals[('mocap/pose', 'late')] == 0
    assert o.ages[-1] == 0.0 and o.node.diagnostic_status()[:2] == (0, 'ok')


def test_the_age_published_while_dead_reckoning_is_the_clocks(context, executor):
    # Dead reckoning stays max_latency behind the clock, but observer/measurement_age is the
    # time since the last pose on the clock (what dp_control compares with estimate_max_age).
    o = Observer(context, executor)
    o.poses(10)
    t_pose = o.clock.ns
    for _ in range(50):  # 1 s without poses
        o.clock.advance(PERIOD)
        o.executor.spin_once(timeout_sec=0.0)
    assert o.ages[-1] == pytest.approx((o.clock.ns - t_pose) * 1e-9, abs=0.1 + 1e-9)
    assert o.ages[-1] > 0.9


def test_poses_and_dead_reckoning_on_two_threads_never_step_backwards(context, executor):
    # Poses step the estimate on the chain's thread while dead reckoning runs on the
    # executor's: unserialized, a catch-up step computed from a time base the other thread
    # had just moved went backwards (ValueError: dt must be finite and > 0), seen once in a
    # loaded emulated Saucer run.
    o = Observer(context, executor)
    o.poses(5)
    errors: list[BaseException] = []
    stop = threading.Event()

    def reckon() -> None:
        while not stop.is_set():
            try:
                o.node._dead_reckon()
            except Exception as err:  # noqa: BLE001 - collected for the assert
                errors.append(err)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads take turns every few bytecodes: the race shows
    thread = threading.Thread(target=reckon)
    thread.start()
    try:
        for i in range(3000):
            t = o.clock.advance(PERIOD * (15 if i % 3 == 0 else 1))  # gaps: dead reckoning runs
            o.pub.publish(pose_msg(t, HERE))
    finally:
        stop.set()
        thread.join()
        sys.setswitchinterval(interval)
    link_errors = sum(s.errors for s in o.node.link_bus._subscriptions.get('/mocap/pose', ()))
    assert not errors and link_errors == 0, (errors[:3], link_errors)
