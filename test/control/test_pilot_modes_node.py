"""Node tests: the ROV's pilot modes in the velocity control node (requests, refusals with
their reason, the depth fallback, manual forces, the holds acting on the force)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped, WrenchStamped
from std_msgs.msg import String
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from support.nodes import add, probe, TIMEOUT
from support.rov import imu_sample, overrides, vehicle_parameters

from enbarr_core.control.pilot_modes import EXECUTOR
from enbarr_core.control.velocity_control_node import VelocityControlNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

pytestmark = pytest.mark.node

G = 9.80665
TAU_MAX = [80.0, 80.0, 120.0, 10.0, 10.0, 10.0]   # params/enbarr_sim.yaml's control_loop


class Rov:
    """The velocity control node fed by hand at 100 Hz, level, at rest, depth at 10 Hz."""

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, VelocityControlNode(context=context, parameter_overrides=(
            overrides({**vehicle_parameters(), 'goal_timeout': 60.0}))))
        p = probe(context, executor, 'pilot')
        self.imu_pub = p.create_topic_publisher(topics.IMU)
        self.goal_pub = p.create_topic_publisher(topics.TRAJECTORY_REQUEST)
        self.io_pub = p.create_topic_publisher(topics.IO_REQUEST)
        self.depth_pub = p.create_topic_publisher(topics.DEPTH)
        self.taus: list[np.ndarray] = []
        self.modes: list[str] = []
        self.reasons: list[str] = []
        p.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        p.create_topic_subscription(topics.PILOT_MODE, lambda m: self.modes.append(m.data))
        p.create_topic_subscription(topics.PILOT_MODE_REASON,
                                    lambda m: self.reasons.append(m.data))
        LinkBus.of(context).connect()
        self.node.start()
        self.t = 1_000_000_000
        self.depth = 1.0

    def _on_tau(self, msg: WrenchStamped) -> None:
        self.taus.append(convert.wrench_to_tau(msg.wrench))

    def goal(self, nu: list[float]) -> None:
        msg = TwistStamped()
        convert.ns_to_stamp(self.t, msg.header.stamp)
        msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z = nu[:3]
        msg.twist.angular.x, msg.twist.angular.y, msg.twist.angular.z = nu[3:]
        self.goal_pub.publish(msg)

    def request(self, mode: str) -> None:
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=mode)
        self.io_pub.publish(ParameterMsg(name=EXECUTOR, value=value))

    def run(self, seconds: float, depth: bool = True, yaw: float = 0.0) -> np.ndarray:
        for k in range(int(round(seconds * 100))):
            self.t += 10_000_000
            if depth and k % 10 == 0:
                d = PoseWithCovarianceStamped()
                convert.ns_to_stamp(self.t, d.header.stamp)
                d.pose.pose.position.z = -self.depth
                d.pose.covariance[14] = 4e-6
                self.depth_pub.publish(d)   # over DDS: taken before the next IMU sample
                t = self.t
                assert self.spin(self.executor, lambda: self.node._depth_ns == t, TIMEOUT)
            imu = imu_sample(self.t, rate_z=0.0)
            imu.linear_acceleration.z = G   # at rest: the specific force is +g up
            imu.orientation.z, imu.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            self.imu_pub.publish(imu)
        return self.taus[-1]


@pytest.fixture
def rov(context, executor, spin) -> Rov:
    return Rov(context, executor, spin)


def test_starts_in_velocity_and_says_so_latched(rov, spin):
    rov.run(0.1)
    assert rov.node.modes.mode == 'velocity'
    assert spin(rov.executor, lambda: rov.modes, TIMEOUT)   # latched: a late joiner has it
    assert rov.modes == ['velocity']


def test_depth_hold_without_a_depth_is_refused_with_the_reason(rov, spin):
    rov.run(0.5, depth=False)
    rov.request('depth_hold')
    assert spin(rov.executor, lambda: rov.reasons, TIMEOUT)
    assert rov.reasons[-1] == 'depth_hold refused: no depth sensor heard'
    assert rov.node.modes.mode == 'velocity'
    rov.request('warp_drive')
    assert spin(rov.executor, lambda: len(rov.reasons) == 2, TIMEOUT)
    assert "'warp_drive' refused: not a mode" in rov.reasons[-1]


def test_depth_hold_holds_where_it_was_engaged_and_pushes_back_down(rov, spin):
    rov.run(0.5)
    rov.request('depth_hold')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'depth_hold', TIMEOUT)
    rov.run(0.5)
    assert rov.node.depth_hold.target == pytest.approx(-1.0, abs=0.01)
    # the vehicle rises 20 cm: the hold asks for heave down (negative Z)
    rov.depth = 0.8
    tau = rov.run(1.0)
    assert tau[2] < -1.0
    # back in velocity mode the heave reference goes on from the hold's goal (no step) down
    # to the zero goal, and then the same rise gets no reaction (heave not measured): the
    # force left is the heave integral the hold had learnt, frozen
    held = float(rov.node.reference.nu_ref[2])
    learnt = float(rov.node.output.integral[2])
    assert learnt < -0.1
    assert held < -0.1
    rov.request('velocity')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'velocity', TIMEOUT)
    rov.run(0.01)
    assert rov.node.reference.nu_ref[2] == pytest.approx(held, abs=0.01)   # 0.5 m/s^2 x 10 ms
    tau = rov.run(3.0)
    assert tau[2] == pytest.approx(learnt, abs=0.05)
    assert rov.run(1.0)[2] == pytest.approx(tau[2], abs=0.05)


def test_a_depth_gone_stale_falls_back_to_stabilize_with_the_reason(rov, spin):
    rov.run(0.5)
    rov.request('depth_hold')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'depth_hold', TIMEOUT)
    rov.run(0.3)
    rov.run(1.0, depth=False)   # depth_timeout is 0.5 s
    assert rov.node.modes.mode == 'stabilize'
    assert spin(rov.executor, lambda: rov.modes[-1] == 'stabilize' and rov.reasons, TIMEOUT)
    assert rov.reasons[-1].startswith('depth_hold -> stabilize: depth ')
    assert rov.node.modes.fallbacks == 1


def test_stabilize_holds_the_heading_it_settled_on(rov, spin):
    rov.run(0.3, yaw=0.5)
    rov.request('stabilize')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'stabilize', TIMEOUT)
    rov.run(0.3, yaw=0.5)
    assert rov.node.heading_hold.target == pytest.approx(0.5, abs=1e-6)
    tau = rov.run(0.5, yaw=0.4)   # turned 0.1 rad to starboard: yaw moment to port (+N)
    assert tau[5] > 0.05


def test_manual_maps_the_goal_to_forces(rov, spin):
    rov.run(0.2)
    rov.request('manual')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'manual', TIMEOUT)
    rov.goal([0.25, -1.0, 0.0, 0.0, 0.0, 0.5])   # half surge, sway past full, half yaw
    tau = rov.run(0.2)
    np.testing.assert_allclose(tau, [0.5 * TAU_MAX[0], -TAU_MAX[1], 0.0, 0.0, 0.0,
                                     0.5 * TAU_MAX[5]], atol=1e-9)


def test_entering_depth_hold_while_diving_stops_the_vehicle_without_a_step(rov, spin):
    """Diving at 0.3 m/s in velocity mode, the pilot centres the stick and asks for depth hold:
    the hold first runs the climb rate down from the measured one (its deceleration fed
    forward), so the heave force carries on from where it was; the depth is taken once the
    run-down is over."""
    rov.goal([0.0, 0.0, -0.3, 0.0, 0.0, 0.0])
    for _ in range(40):            # 4 s: the estimator learns the 0.3 m/s descent
        rov.depth += 0.03
        rov.run(0.1)
    assert rov.node.depth_estimator.vertical_velocity == pytest.approx(-0.3, abs=0.03)
    before = rov.taus[-1][2]
    rov.goal([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    rov.request('depth_hold')
    assert spin(rov.executor, lambda: rov.modes and rov.modes[-1] == 'depth_hold', TIMEOUT)
    rov.depth += 0.003
    after = rov.run(0.01)[2]
    assert rov.node.depth_hold.stopping and rov.node.depth_hold.target is None
    # taking the depth at once steps it by k_p w = 20 x 0.3 = 6 N; here only the model's
    # feed-forward at the estimated rate differs from the reference's
    assert abs(after - before) < 2.0, (before, after)
    assert rov.node.reference.nu_ref_dot[2] > 0.0     # braking the descent, fed forward
    for _ in range(30):            # the run-down (5 stop_time = 2 s) ends: the depth is taken
        rov.run(0.1)
    assert not rov.node.depth_hold.stopping and rov.node.depth_hold.target is not None


# -- the failsafes' action (control.failsafe_node publishes it) -------------------------------
def _failsafe(rov, context, executor, spin, action: str) -> None:
    pub = getattr(rov, 'failsafe_pub', None)
    if pub is None:
        pub = rov.failsafe_pub = probe(context, executor, 'failsafe').create_topic_publisher(
            topics.FAILSAFE_ACTION)
    pub.publish(String(data=action))
    assert spin(executor, lambda: rov.node.failsafe == action, TIMEOUT)


def test_surface_climbs_in_depth_hold_with_the_heading_held_and_refuses_the_pilot(
        rov, context, executor, spin):
    rov.run(0.5)
    rov.goal([0.0, 0.0, -0.3, 0.0, 0.0, 0.0])   # the pilot dives
    rov.run(0.5)
    _failsafe(rov, context, executor, spin, 'surface')
    assert rov.node.modes.mode == 'depth_hold'
    assert spin(executor, lambda: rov.reasons and 'failsafe surface' in rov.reasons[-1], TIMEOUT)
    assert rov.reasons[-1] == 'velocity -> depth_hold: failsafe surface'
    rov.run(1.0)
    # depth hold asks for the climb rate (0.25 m/s up) whatever the pilot's dive goal
    assert rov.node.depth_hold.target is None
    assert rov.node.reference.nu_ref[2] == pytest.approx(0.25, abs=0.01)
    assert rov.taus[-1][2] > 1.0   # heave force up
    assert rov.node.heading_hold.target == pytest.approx(0.0, abs=0.01)
    rov.request('velocity')
    assert spin(executor, lambda: "'velocity' refused: failsafe surface active"
                in rov.reasons[-1], TIMEOUT)
    assert rov.node.modes.mode == 'depth_hold'
    _failsafe(rov, context, executor, spin, 'none')   # cleared: the pilot has the vehicle back
    rov.request('velocity')
    assert spin(executor, lambda: rov.node.modes.mode == 'velocity', TIMEOUT)


def test_surface_without_a_depth_climbs_in_stabilize(rov, context, executor, spin):
    rov.run(0.5, depth=False)
    _failsafe(rov, context, executor, spin, 'surface')
    assert rov.node.modes.mode == 'stabilize'
    rov.run(3.0, depth=False)   # the reference model's ramp to the climb rate
    assert rov.node.reference.nu_ref[2] == pytest.approx(0.25, abs=0.01)


def test_neutral_puts_out_zero_force_from_the_next_sample(rov, context, executor, spin):
    rov.goal([0.3, 0.0, 0.0, 0.0, 0.0, 0.2])
    tau = rov.run(1.0)
    assert abs(tau[0]) > 1.0
    _failsafe(rov, context, executor, spin, 'neutral')
    n = len(rov.taus)
    rov.run(0.02)
    assert all(not t.any() for t in rov.taus[n:]) and len(rov.taus) > n
    _failsafe(rov, context, executor, spin, 'none')
    assert rov.run(0.5)[0] > 1.0


def test_stabilize_takes_depth_hold_to_stabilize(rov, context, executor, spin):
    rov.run(0.5)
    rov.request('depth_hold')
    assert spin(executor, lambda: rov.node.modes.mode == 'depth_hold', TIMEOUT)
    _failsafe(rov, context, executor, spin, 'stabilize')
    assert rov.node.modes.mode == 'stabilize'
