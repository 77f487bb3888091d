"""Node tests: velocity control node."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, WrenchStamped
from support.nodes import add, get_param, param_client, probe, set_param
from support.rov import imu_sample, overrides, vehicle_parameters
from support.saucer import SimClock

from enbarr_core.control.velocity_control_node import VelocityControlNode
from enbarr_core.framework import registry
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.stamps import StampVerdict
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

KP = [20.0, 20.0, 20.0, 4.0, 4.0, 4.0]


def test_default_node_name_is_the_registry_name():
    default = inspect.signature(VelocityControlNode).parameters['node_name'].default
    assert registry.resolve(default) is VelocityControlNode


class Loop:
    """The loop fed by hand: a surge goal, IMU samples with a yaw rate error of -0.5 rad/s."""

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, VelocityControlNode(context=context, parameter_overrides=(
            overrides({**vehicle_parameters(), 'ki': [0.0] * 6, 'goal_timeout': 60.0}))))
        feeder = probe(context, executor, 'feeder')
        self.imu_pub = feeder.create_topic_publisher(topics.IMU)
        goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.taus: list[np.ndarray] = []
        self.stamps: list[int] = []
        feeder.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        LinkBus.of(context).connect()
        self.client = param_client(executor, spin, context, 'velocity_control')
        goal = TwistStamped()
        goal.twist.linear.x = 0.2  # surge is not measured: feed-forward only
        goal_pub.publish(goal)
        self.t = 1_000_000_000

    def _on_tau(self, msg: WrenchStamped) -> None:
        self.taus.append(convert.wrench_to_tau(msg.wrench))
        self.stamps.append(convert.stamp_to_ns(msg.header.stamp))

    def sample(self) -> None:
        self.t += 10_000_000
        self.imu_pub.publish(imu_sample(self.t, rate_z=0.5))  # yaw rate error -0.5 rad/s

    def feed(self, count: int) -> np.ndarray:
        for _ in range(count):
            self.sample()
        assert self.stamps and self.stamps[-1] == self.t, 'no tau for the last IMU sample'
        return self.taus[-1]

    def set(self, name: str, value: Any) -> Any:
        return set_param(self.executor, self.spin, self.client, name, value)

    def get(self, name: str) -> Any:
        return get_param(self.executor, self.spin, self.client, name)


@pytest.fixture
def loop(context, executor, spin) -> Loop:
    return Loop(context, executor, spin)


def test_the_first_imu_sample_only_initializes(loop):
    loop.sample()
    assert not loop.taus


def test_goal_and_gains_reach_the_force(loop):
    loop.sample()
    tau = loop.feed(5)
    assert tau[0] > 0.0, 'the goal on trajectory_request did not reach the controller'
    assert tau[5] == pytest.approx(-4.0 * 0.5)  # kp_yaw 4, no ki: tau_N = kp e


@pytest.mark.parametrize('name, value, says', [
    # Out of range: an array element (checked by Enbarr) and a scalar (by rclpy).
    ('kp', [20.0, 20.0, 20.0, 4.0, 4.0, -1.0], ['kp[5]', '-1.0']),
    ('level_gain', 500.0, ['level_gain']),
    # Wrong length: refused by the settings build, naming the parameter.
    ('kp', [1.0, 2.0, 3.0], ['kp']),
    # Read-only.
    ('velocity_topic', 'dvl/odometry', []),
    # Wrong type.
    ('level_gain', 'high', []),
], ids=['kp element out of range', 'level_gain out of range', 'kp wrong length', 'read-only',
        'wrong type'])
def test_a_refused_change_says_why_and_keeps_the_old_values(loop, name, value, says):
    loop.sample()
    loop.feed(5)
    result = loop.set(name, value)
    assert not result.successful and result.reason
    for text in says:
        assert text in result.reason
    # The refusal kept the old values, in the node and its controller.
    assert loop.get('kp') == KP
    assert loop.get('level_gain') == 2.0
    assert loop.get('velocity_topic') == ''
    assert loop.node.controller.settings.kp == tuple(KP)
    assert loop.node.controller.settings.level_gain == 2.0
    assert loop.feed(1)[5] == pytest.approx(-2.0)


def test_a_valid_gain_acts_on_the_next_step(loop):
    loop.sample()
    loop.feed(5)
    result = loop.set('kp', [20.0, 20.0, 20.0, 4.0, 4.0, 8.0])
    assert result.successful, result.reason
    assert loop.node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 8.0)
    assert loop.get('kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 8.0]
    assert loop.feed(1)[5] == pytest.approx(-8.0 * 0.5)


def test_a_valid_scalar_is_applied(loop):
    result = loop.set('level_gain', 5.0)
    assert result.successful, result.reason
    assert loop.node.controller.settings.level_gain == 5.0
    assert loop.node.settings.controller.level_gain == 5.0


class Feeder:
    """The loop with default gains and a surge goal of 0.3 m/s stamped at 1 s."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.node = add(executor, VelocityControlNode(
            context=context, parameter_overrides=overrides(vehicle_parameters())))
        feeder = probe(context, executor, 'feeder')
        self.imu_pub = feeder.create_topic_publisher(topics.IMU)
        goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.taus: list[np.ndarray] = []
        feeder.create_topic_subscription(
            topics.FORCE_COMMAND, lambda m: self.taus.append(convert.wrench_to_tau(m.wrench)))
        LinkBus.of(context).connect()
        goal = TwistStamped()
        goal.twist.linear.x = 0.3
        self.t = 1_000_000_000
        convert.ns_to_stamp(self.t, goal.header.stamp)  # goal age: on the IMU time line
        goal_pub.publish(goal)

    def run(self, n: int) -> None:
        for _ in range(n):
            self.t += 10_000_000
            self.imu_pub.publish(imu_sample(self.t, rate_z=0.0))


@pytest.fixture
def feeder(context, executor) -> Feeder:
    return Feeder(context, executor)


def test_out_of_order_imu_is_dropped_and_the_state_kept(feeder):
    """A late or repeated IMU stamp is dropped and counted; the loop state is kept (a reset
    would drop the reference model's velocity and jolt the commanded force).
    """
    node, taus = feeder.node, feeder.taus
    feeder.run(50)
    ref_before = node.reference.nu_ref.copy()
    assert ref_before[0] > 0.1 and len(taus) == 49
    feeder.imu_pub.publish(imu_sample(feeder.t - 5_000_000, rate_z=0.0))  # from the past
    feeder.imu_pub.publish(imu_sample(feeder.t, rate_z=0.0))              # repeated
    assert node.rejected == 2 and len(taus) == 49
    np.testing.assert_array_equal(node.reference.nu_ref, ref_before)
    feeder.run(1)
    assert len(taus) == 50 and abs(taus[-1][0] - taus[-2][0]) < 0.5


def test_a_stale_goal_counts_as_zero(feeder):
    """A goal stamped more than goal_timeout before the IMU sample counts as zero."""
    node = feeder.node
    feeder.run(90)  # 0.9 s: the goal is fresh, the reference reaches it
    assert node.reference.nu_ref[0] > 0.25
    feeder.run(250)  # samples go on without a gap; from 2.0 s the goal is stale
    assert abs(node.reference.nu_ref[0]) < 1e-3
    assert node.rejected == 0  # no gap, no reset: the goal timed out


# -- the time policy on a controlled clock -------------------------------------------------

T0 = 1_000 * 1_000_000_000  # the node's clock at the start of these tests [ns]
IMU_NS = 2_500_000          # 400 Hz
GOAL_NS = 100_000_000       # the receiver's 10 Hz


class Clocked:
    """The loop on a clock the test moves; imu/data and goals stamped at the clock's present
    (what the in-process filter and receiver do)."""

    def __init__(self, context: Any, executor: Any, spin: Any, **params: Any) -> None:
        self.executor, self.spin, self.context = executor, spin, context
        self.node = add(executor, VelocityControlNode(
            context=context, parameter_overrides=overrides({**vehicle_parameters(), **params})))
        self.clock = SimClock(self.node, t0_ns=T0)
        feeder = probe(context, executor, 'feeder')
        self.imu_pub = feeder.create_topic_publisher(topics.IMU)
        self.goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.taus: list[tuple[int, np.ndarray]] = []
        feeder.create_topic_subscription(topics.FORCE_COMMAND, lambda m: self.taus.append(
            (convert.stamp_to_ns(m.header.stamp), convert.wrench_to_tau(m.wrench))))
        LinkBus.of(context).connect()
        self.t = T0
        self.reports: list[tuple[int, str, dict[str, Any]]] = []
        self.node.publish_diagnostics = lambda *a: self.reports.append(a)

    def goal(self, surge: float, stamp_ns: int | None = None) -> None:
        goal = TwistStamped()
        goal.twist.linear.x = surge
        convert.ns_to_stamp(self.t if stamp_ns is None else stamp_ns, goal.header.stamp)
        self.goal_pub.publish(goal)

    def run(self, n: int, surge: float | None = 0.3) -> None:
        """``n`` IMU samples at 400 Hz; a goal every 100 ms unless ``surge`` is None."""
        for _ in range(n):
            self.t += IMU_NS
            self.clock.set(self.t)
            if surge is not None and (self.t - T0) % GOAL_NS == 0:
                self.goal(surge)
            self.imu_pub.publish(imu_sample(self.t, rate_z=0.0))

    def report(self) -> tuple[int, str, dict[str, Any]]:
        self.node._report()
        return self.reports[-1]


@pytest.mark.parametrize('ahead_s', [20.0, 0.4])
def test_one_future_imu_sample_costs_only_itself(context, executor, spin, ahead_s):
    """Before the time policy, one sample 20 s (0.4 s) ahead stopped the loop for that long
    (watchdog -> neutral). Now it is refused and counted; every good sample after it gives a
    force."""
    rig = Clocked(context, executor, spin)
    rig.run(200)
    n = len(rig.taus)
    rig.imu_pub.publish(imu_sample(rig.t + round(ahead_s * 1e9), rate_z=0.0))
    rig.run(100)
    assert len(rig.taus) == n + 100
    assert max(t for t, _ in rig.taus) == rig.t
    assert rig.node.imu_gate.counts[StampVerdict.FUTURE] == 1
    assert rig.node.reference.nu_ref[0] > 0.2  # not reset
    _, _, values = rig.report()
    assert values['imu/data.future'] == 1


def test_a_future_goal_is_refused_and_never_outlives_its_timeout(context, executor, spin):
    """A goal stamped 20 s ahead looked fresh for 20 s + goal_timeout: the vehicle drove on
    after its commands stopped. Refused now: the goal times out as if it never came."""
    rig = Clocked(context, executor, spin)
    rig.run(200)
    rig.goal(0.3, rig.t + 20_000_000_000)
    rig.run(800, surge=None)  # 2 s without goals: goal_timeout (1 s) passed 1 s ago
    assert abs(rig.node.reference.nu_ref[0]) < 0.05  # decaying to zero (0.3 when driven)
    assert rig.node.goal_gate.counts[StampVerdict.FUTURE] == 1


def test_an_out_of_order_goal_is_refused(context, executor, spin):
    rig = Clocked(context, executor, spin)
    rig.run(800)  # 2 s: the reference settles on 0.3 m/s
    rig.goal(0.6, rig.t - 50_000_000)  # older than the last goal
    rig.run(100, surge=None)
    assert rig.node.reference.nu_ref[0] == pytest.approx(0.3, abs=0.02)
    assert rig.node.goal_gate.counts[StampVerdict.NOT_NEWER] == 1


@pytest.mark.parametrize('name, value, measured', [
    ('max_gap', 0.004, 'imu/data'),            # 400 Hz: 2 periods = 5 ms
    ('goal_timeout', 0.15, 'trajectory_request'),  # 10 Hz: 2 periods = 0.2 s
])
def test_tolerances_shorter_than_the_measured_period_are_refused(context, executor, spin,
                                                                name, value, measured):
    rig = Clocked(context, executor, spin)
    rig.run(400)
    client = param_client(executor, spin, context, 'velocity_control')
    result = set_param(executor, spin, client, name, value)
    assert not result.successful
    assert name in result.reason and measured in result.reason and 'period' in result.reason
    assert set_param(executor, spin, client, name, 0.3).successful


def test_resets_and_refusals_make_the_node_degraded(context, executor, spin):
    rig = Clocked(context, executor, spin, max_gap=0.001)  # every sample is a gap
    rig.run(400)
    level, message, values = rig.report()
    assert level != 0 and 'reset' in message and 'max_gap' in message, message
    assert values['reset.integrator'] >= 399


def test_a_healthy_loop_reports_ok(context, executor, spin):
    rig = Clocked(context, executor, spin)
    rig.run(400)
    assert rig.report()[:2] == (0, 'ok')


@pytest.mark.parametrize('missing', [
    'vehicle.mass', 'vehicle.inertia', 'vehicle.added_mass', 'vehicle.d_lin', 'vehicle.d_quad',
    'kp', 'ki', 'integral_limit', 'tau_max', 'reference_time_constant', 'max_accel',
    'level_gain'])
def test_the_model_and_the_tuning_come_from_the_profile_only(context, missing):
    """Vessel data (the feed-forward model, and the gains, limits and reference model tuned
    for that vehicle) has no default in the code: without it the loop refuses to start,
    naming the parameter (bringup turns this into a ProfileError naming the file)."""
    given = {k: v for k, v in vehicle_parameters().items() if k != missing}
    with pytest.raises(ConfigurationError, match=(
            f"node 'control_loop': parameter '{missing}' is not set; the profile must give it")):
        VelocityControlNode(node_name='control_loop', context=context,
                            parameter_overrides=overrides(given))
