"""Node tests: the failsafe supervisor fed by hand on simulated time (the leak, the pilot
input and the attitude filter's report), its latched topics and the operator's clear."""

from __future__ import annotations

from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, String
from support.nodes import add, probe, TIMEOUT

from enbarr_core.control.failsafe_node import EXECUTOR, FailsafeNode
from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools.scenario import simulated_time
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus

pytestmark = pytest.mark.node


class Rig:
    """The failsafe node on a simulated clock, with a probe publishing its inputs."""

    def __init__(self, context: Any, executor: Any, spin: Any, **params: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, FailsafeNode(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        self.set_time = simulated_time([self.node.get_clock()])
        self.t = 1.0
        self.set_time(int(self.t * 1e9))
        p = probe(context, executor, 'topside')
        self.twist_pub = p.create_topic_publisher(topics.SURFACE_TWIST)
        self.leak_pub = p.create_topic_publisher(topics.LEAK)
        self.diag_pub = p.create_publisher(DiagnosticArray, topics.DIAGNOSTICS.name,
                                           topics.DIAGNOSTICS.qos)
        self.io_pub = p.create_topic_publisher(topics.IO_REQUEST)
        self.actions: list[str] = []
        self.active: list[str] = []
        p.create_topic_subscription(topics.FAILSAFE_ACTION, lambda m: self.actions.append(m.data))
        p.create_topic_subscription(topics.FAILSAFE_ACTIVE, lambda m: self.active.append(m.data))
        LinkBus.of(context).connect()
        self.node.start()
        self.report(0)   # the attitude filter is alive from the start

    def at(self, t: float) -> None:
        """Move the clock to ``t`` [s] and run the checks once."""
        self.t = t
        self.set_time(int(t * 1e9))
        self.node.check()

    def twist(self) -> None:
        self.twist_pub.publish(TwistStamped())
        n = self.node
        assert self.spin(self.executor, lambda: abs(n._pilot_at - self.t) < 1e-6, TIMEOUT)

    def leak(self, wet: bool) -> None:
        self.leak_pub.publish(Bool(data=wet))
        assert self.spin(self.executor, lambda: self.node._leak is wet, TIMEOUT)

    def report(self, samples: int, level: int = 0) -> None:
        status = DiagnosticStatus(level=bytes([level]), name='/filtering', message='m',
                                  hardware_id='filtering',
                                  values=[KeyValue(key='samples', value=str(samples))])
        self.diag_pub.publish(DiagnosticArray(status=[status]))
        n = self.node
        assert self.spin(self.executor, lambda: n._attitude_report_at is not None
                         and abs(n._attitude_report_at - self.t) < 1e-6, TIMEOUT)

    def clear(self) -> None:
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value='clear')
        before = self.node.clears
        self.io_pub.publish(ParameterMsg(name=EXECUTOR, value=value))
        assert self.spin(self.executor, lambda: self.node.clears > before, TIMEOUT)

    def last(self) -> tuple[str, str]:
        assert self.spin(self.executor, lambda: self.actions and self.active, TIMEOUT)
        return self.actions[-1], self.active[-1]

    def wait(self, action: str, active: str) -> None:
        """Spin until both latched topics say ``action`` and ``active`` (a prefix)."""
        self.spin(self.executor, lambda: self.actions and self.active and (
            self.actions[-1], self.active[-1][:len(active)]) == (action, active), TIMEOUT)
        assert (self.actions[-1], self.active[-1][:len(active)]) == (action, active), \
            (self.actions[-1:], self.active[-1:])


@pytest.fixture
def rig(context, executor, spin) -> Rig:
    return Rig(context, executor, spin)


def test_starts_with_no_failsafe_and_says_so_latched(rig):
    assert rig.last() == ('none', 'none')


def test_a_leak_surfaces_at_once_and_latches_until_cleared_dry(rig):
    rig.at(2.0)
    rig.twist()
    rig.leak(True)   # acted on when it arrives, not at the next check
    rig.wait('surface', 'leak: surface since 2.00 s (leak detected)')
    rig.clear()      # still wet: nothing changes
    assert rig.node.verdict.action == 'surface'
    rig.leak(False)
    rig.at(3.0)
    assert rig.node.verdict.action == 'surface'   # latched
    rig.clear()
    rig.wait('none', 'none')


def test_pilot_input_lost_for_its_timeout_goes_neutral_and_clears_when_it_returns(rig):
    rig.at(2.0)
    rig.twist()
    rig.report(100)
    rig.at(4.0)
    rig.report(300)   # the attitude filter alive: only the pilot input is missing
    rig.at(5.0)
    assert rig.node.verdict.action == 'none'   # 3.0 s: at the limit
    rig.at(5.2)
    rig.wait('neutral', 'pilot_input: neutral since 5.20 s (no pilot input for 3.2 s (limit '
                        '3 s))')
    rig.twist()
    rig.at(5.3)
    rig.wait('none', 'none')


def test_the_attitude_filter_without_imu_samples_goes_neutral(rig):
    for t in (1.5, 2.5, 3.5):
        rig.at(t)
        rig.twist()
        rig.report(100)   # from 1.5 s on the count stands still: no IMU samples
        rig.at(t)
    assert rig.node.verdict.action == 'none'   # 2.0 s since the last sample counted
    rig.at(3.6)
    rig.wait('neutral', 'attitude: neutral since 3.60 s (attitude filter has no IMU samples '
                        'for 2.1 s')


def test_the_attitude_filter_silent_trips_too_but_not_on_one_late_report(rig):
    rig.at(1.5)
    rig.twist()
    rig.at(3.5)
    rig.twist()
    rig.at(3.9)   # its one report at 1.0 s: two late, on a loaded machine, is not silence
    assert rig.node.verdict.active == ()
    rig.at(4.1)
    rig.twist()
    rig.at(4.1)
    assert rig.node.verdict.active[0].reason.startswith(
        'no report from the attitude filter (filtering) for 3.1 s')


def _depth_rig(rig):
    """Publishers of the loop's mode and of a depth, a depth at the start, and depth hold."""
    mode_pub = probe(rig.node.context, rig.executor, 'loop').create_topic_publisher(
        topics.PILOT_MODE)
    depth_pub = probe(rig.node.context, rig.executor, 'depth').create_topic_publisher(
        topics.DEPTH)
    n = rig.node
    depth_pub.publish(PoseWithCovarianceStamped())
    assert rig.spin(rig.executor, lambda: n._depth_at is not None, TIMEOUT)
    mode_pub.publish(String(data='depth_hold'))
    assert rig.spin(rig.executor, lambda: n._mode == 'depth_hold', TIMEOUT)
    return mode_pub


def _leave(rig, mode_pub, t: float, mode: str) -> None:
    """The loop publishes ``mode`` at ``t`` [s], before this node's next check."""
    rig.t = t
    rig.set_time(int(t * 1e9))
    mode_pub.publish(String(data=mode))
    assert rig.spin(rig.executor, lambda: rig.node._mode == mode, TIMEOUT)


def test_a_depth_lost_in_depth_hold_is_reported_after_the_loop_fell_back_itself(rig):
    mode_pub = _depth_rig(rig)
    _leave(rig, mode_pub, 1.75, 'stabilize')   # the loop's own fallback came first
    rig.twist()   # (the node's own 10 Hz check may run while this spins: at 1.75 s)
    rig.at(1.8)
    rig.wait('stabilize', 'depth: stabilize since 1.')
    assert rig.active[-1].endswith(' s (depth 0.8 s old (limit 0.5 s))'), rig.active[-1]


def test_leaving_depth_hold_by_choice_then_losing_the_depth_trips_nothing(rig):
    mode_pub = _depth_rig(rig)
    _leave(rig, mode_pub, 1.2, 'velocity')     # the depth 0.2 s old: the pilot's choice
    rig.twist()
    rig.at(2.5)
    assert rig.node.verdict.active == ()


def test_a_bad_action_is_refused_at_start_naming_the_parameter(context):
    with pytest.raises(EnbarrError, match="leak.action: 'neutral' is not one of disabled, "
                                          'warn, surface'):
        FailsafeNode(context=context, parameter_overrides=[
            Parameter('leak.action', value='neutral')])
