"""Node tier of the CS Saucer: DP control (operator modes), observer, azimuth allocation, PWM
mapping, the simulated Arduino, simulator and motion capture, each in a private rclpy context.

Fast topics are fed and observed through the in-process ``LinkBus`` (synchronous calls), the
joystick and the mode through ordinary ROS topics. Where a node's behaviour depends on its ROS
clock (joystick timeout, dead reckoning, simulation) the test sets that clock itself, as
``enbarr scenario`` does, so nothing depends on how fast this machine happens to be; the
wall-clock watchdogs (PWM mapper, Arduino) are waited for by spinning until they act.
"""

from __future__ import annotations

from collections.abc import Callable
import math
import time
from typing import Any

from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.time import Time
from sensor_msgs.msg import JointState, Joy
from std_msgs.msg import Float64, String

from enbarr_core.guidance.guidance import HoldPose
from enbarr_core.control.modes import Mode
from enbarr_core.framework.errors import AllocationError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.allocation.azimuth_allocation_node import AzimuthAllocationNode
from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_core.estimation.dp_observer_node import DpObserverNode
from enbarr_core.allocation.pwm_mapper_node import PwmMapperNode
from enbarr_core.simulation.saucer_simulator_node import SaucerSimulatorNode
from enbarr_core.bringup.profile import load_profile
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.mocap.sim import SimMocapNode
from enbarr_plugins.arduino.sim import SimArduinoNode

TIMEOUT = 10.0  # [s] every spin-until; never a bound on how fast anything must be
T0_NS = 1_000_000_000  # simulated clocks start at 1 s
SERVO_LIMIT = math.radians(114.0)
COMMON = dict(load_profile('saucer_sim').parameters)  # layout, pwm tables, vessel
NAMES = list(COMMON['azimuth_names'])
POSITIONS = np.array([COMMON[f'azimuths.{n}.position'] for n in NAMES])
MAX_FORWARD = np.array([COMMON[f'azimuths.{n}.max_forward'] for n in NAMES])
MAX_REVERSE = np.array([COMMON[f'azimuths.{n}.max_reverse'] for n in NAMES])
DUTY_MIN, DUTY_MAX = 4.3, 9.4
NEUTRAL_DUTY = 6.85  # middle of the 6.7 .. 7.0 % dead band; servo 0 rad at 6.85 %
TRIANGLE, SQUARE, CROSS = 2, 3, 0


# --- helpers ------------------------------------------------------------------------------


def overrides(extra: dict[str, Any] | None = None) -> list[Parameter]:
    """The common saucer parameters (plus ``extra``) as parameter overrides."""
    return [Parameter(k, value=v) for k, v in {**COMMON, **(extra or {})}.items()]


def add(executor: Any, node: Any) -> Any:
    """Hand ``node`` to the executor (which destroys it at teardown) and return it."""
    executor.add_node(node)
    return node


def probe(context: Any, executor: Any, name: str = 'probe') -> EnbarrNode:
    """A helper node in the test's context, to publish and listen as other nodes would."""
    return add(executor, EnbarrNode(name, context=context))


def call(executor: Any, future: Any) -> Any:
    executor.spin_until_future_complete(future, timeout_sec=TIMEOUT)
    assert future.done(), 'no answer from the parameter service'
    return future.result()


class SimClock:
    """Simulated ROS time on the given nodes' clocks (what ``enbarr scenario`` does): their
    timers fire, and their ``now()`` moves, only when the test advances it."""

    def __init__(self, *nodes: Any, t0_ns: int = T0_NS) -> None:
        self.clocks = [n.get_clock() for n in nodes]
        for c in self.clocks:
            c._set_ros_time_is_active(True)  # what rclpy's TimeSource does for /clock
        self.ns = 0
        self.set(t0_ns)

    def set(self, ns: int) -> None:
        self.ns = int(ns)
        for c in self.clocks:
            c.set_ros_time_override(Time(nanoseconds=self.ns, clock_type=c.clock_type))

    def advance(self, seconds: float) -> int:
        self.set(self.ns + round(seconds * 1e9))
        return self.ns


def joy_msg(surge: float = 0.0, sway: float = 0.0, yaw: float = 0.0,
            pressed: tuple[int, ...] = ()) -> Joy:
    axes = [0.0] * 8
    axes[1], axes[0], axes[3] = surge, sway, yaw  # Ds4Mapping defaults
    buttons = [0] * 13
    for b in pressed:
        buttons[b] = 1
    return Joy(axes=axes, buttons=buttons)


def pose_msg(t_ns: int, eta: Any) -> PoseStamped:
    msg = PoseStamped()
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    msg.header.frame_id = topics.WORLD_FRAME
    convert.set_pose_eta(msg.pose, eta)
    return msg


def odometry_msg(t_ns: int, eta: Any, nu: Any = (0.0, 0.0, 0.0)) -> Odometry:
    msg = Odometry()
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    msg.header.frame_id = topics.WORLD_FRAME
    msg.child_frame_id = topics.BODY_FRAME
    convert.set_pose_eta(msg.pose.pose, eta)
    convert.set_twist_nu3(msg.twist.twist, nu)
    return msg


def azimuth_msg(thrust: list[float], angle: list[float], names: list[str] = NAMES,
                stamp_ns: int = 0) -> JointState:
    msg = JointState(name=list(names), effort=[float(f) for f in thrust],
                     position=[float(a) for a in angle])
    convert.ns_to_stamp(stamp_ns, msg.header.stamp)
    return msg


def duty_msg(duties: dict[str, float]) -> JointState:
    return JointState(name=list(duties), effort=[float(d) for d in duties.values()])


def tau_of(positions: np.ndarray, thrust: Any, angle: Any) -> np.ndarray:
    """[X, Y, N] of azimuth thrusts, computed here from the geometry (not by the code under
    test): f = T (cos a, sin a) at (x, y), N = x f_y - y f_x."""
    T, a = np.asarray(thrust, float), np.asarray(angle, float)
    fx, fy = T * np.cos(a), T * np.sin(a)
    return np.array([fx.sum(), fy.sum(), (positions[:, 0] * fy - positions[:, 1] * fx).sum()])


# --- 1. DP control: operator modes --------------------------------------------------------


class DpHarness:
    """A DpControlNode on a simulated clock, its joystick (ROS), observer (links) and
    outputs."""

    def __init__(self, context: Any, executor: Any, spin: Callable[..., bool],
                 extra: dict[str, Any]) -> None:
        self.executor, self.spin = executor, spin
        self.node = node = add(executor, DpControlNode(
            node_name='dp_control', context=context, parameter_overrides=overrides(extra)))
        self.clock = SimClock(node)
        p = probe(context, executor, 'operator')
        self.joy_pub = p.create_publisher(Joy, topics.JOY.name, topics.JOY.qos)
        self.modes: list[str] = []
        p.create_subscription(String, topics.MODE.name, lambda m: self.modes.append(m.data),
                              topics.MODE.qos)
        self.odom_pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self.age_pub = p.create_topic_publisher(topics.OBSERVER_AGE)
        self.bias_pub = p.create_topic_publisher(topics.OBSERVER_BIAS)
        self.taus: list[np.ndarray] = []
        self.tau_stamps: list[int] = []
        self.refs: list[Odometry] = []
        p.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        p.create_topic_subscription(topics.GUIDANCE_REFERENCE, self.refs.append)
        LinkBus.of(context).connect()
        # Count every joystick sample the node's mode manager sees (accepted or not).
        self.joy_seen = 0
        real = node.manager.on_joy

        def counting(*args: Any, **kwargs: Any) -> Any:
            self.joy_seen += 1
            return real(*args, **kwargs)

        node.manager.on_joy = counting
        self.t_odom = T0_NS

    def _on_tau(self, msg: WrenchStamped) -> None:
        self.taus.append(convert.wrench_to_tau3(msg.wrench))
        self.tau_stamps.append(convert.stamp_to_ns(msg.header.stamp))

    def joy(self, msg: Joy) -> None:
        """Publish ``msg`` until the node has handled it (the joystick topic is best effort;
        a repeated sample is harmless: held buttons do not trigger again)."""
        seen = self.joy_seen
        deadline = time.monotonic() + TIMEOUT
        while self.joy_seen == seen and time.monotonic() < deadline:
            self.joy_pub.publish(msg)
            self.spin(self.executor, lambda: self.joy_seen > seen, 0.5)
        assert self.joy_seen > seen, 'the joystick sample never reached dp_control'

    def estimate(self, eta: Any, nu: Any = (0.0, 0.0, 0.0), age: float = 0.0) -> None:
        """One observer output, as the observer publishes it (age, bias, then odometry)."""
        self.t_odom += 20_000_000
        self.age_pub.publish(Float64(data=age))
        self.bias_pub.publish(WrenchStamped())
        self.odom_pub.publish(odometry_msg(self.t_odom, eta, nu))

    def wait_mode(self, mode: str) -> None:
        assert self.spin(self.executor, lambda: self.modes and self.modes[-1] == mode,
                         TIMEOUT), f'mode {mode} never published: {self.modes}'


def test_dp_control_modes_bumpless_refusals_and_joystick_loss(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    node = h.node
    assert spin(executor, lambda: h.joy_pub.get_subscription_count() > 0, TIMEOUT)
    h.wait_mode('manual')  # latched: a late subscriber still learns the mode
    assert h.modes == ['manual'] and node.mode is Mode.MANUAL
    manual_tau_max = np.array([1.5, 1.5, 0.2])  # the default
    assert node.settings['manual_tau_max'] == manual_tau_max.tolist()

    eta0 = np.array([0.3, -0.2, 0.4])
    h.estimate(eta0)
    assert not h.taus  # in manual the estimate does not produce force

    # Manual: the sticks are the force.
    sticks = (0.5, -0.4, 0.25)
    h.joy(joy_msg(*sticks))
    assert len(h.taus) == 1
    # Joy axes are float32: the force is tau_max times the stick as it arrived.
    tau_manual = manual_tau_max * np.array(sticks, dtype=np.float32).astype(float)
    assert h.taus[-1] == pytest.approx(tau_manual, abs=1e-12)

    # Triangle with a fresh estimate: automatic, and bumpless. The first controller output
    # equals the manual force of the moment although the vessel is now 0.2 m off the held
    # pose and moving (a plain PID would jump to about -2 N in surge).
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    assert node.mode is Mode.AUTOMATIC and node.refusals == 0
    assert len(h.taus) == 1  # the joystick no longer publishes force
    h.estimate(eta0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 2
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)
    assert h.tau_stamps[-1] == h.t_odom  # stamped with the estimate it answers
    assert len(h.refs) == 1  # holding the pose where the vessel was at the switch
    assert convert.pose_to_eta(h.refs[-1].pose.pose) == pytest.approx(eta0, abs=1e-12)
    h.estimate(eta0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 3 and len(h.refs) == 2  # the controller runs on every estimate

    # Cross: manual again, the sticks' force at once.
    h.joy(joy_msg(*sticks, pressed=(CROSS,)))
    h.wait_mode('manual')
    assert h.taus[-1] == pytest.approx(tau_manual, abs=1e-12)

    # Triangle while the observer dead-reckons for too long: refused, still manual.
    h.estimate(eta0, age=5.0)  # > estimate_max_age 1.5 s
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    assert node.refusals == 1 and node.mode is Mode.MANUAL
    h.joy(joy_msg(*sticks))
    assert h.modes[-1] == 'manual' and 'automatic' not in h.modes[2:]

    # Square without path.waypoints: refused, even with a fresh estimate.
    h.estimate(eta0, age=0.0)
    h.joy(joy_msg(*sticks, pressed=(SQUARE,)))
    assert node.refusals == 2 and node.mode is Mode.MANUAL
    h.joy(joy_msg(*sticks))

    # With a path: guidance, and the guidance reference follows each estimate.
    result = node.set_parameters([Parameter('path.waypoints', value=[0.3, -0.2, 2.3, -0.2])])
    assert result[0].successful, result[0].reason
    assert node.settings['waypoints'] == [(0.3, -0.2), (2.3, -0.2)]
    h.joy(joy_msg(*sticks, pressed=(SQUARE,)))
    h.wait_mode('guidance')
    assert node.mode is Mode.GUIDANCE and node.refusals == 2
    n_refs, n_taus = len(h.refs), len(h.taus)
    h.estimate(eta0)
    assert len(h.refs) == n_refs + 1 and len(h.taus) == n_taus + 1
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)  # bumpless too
    ref = h.refs[-1]
    assert convert.stamp_to_ns(ref.header.stamp) == h.t_odom
    eta_d, nu_d = convert.pose_to_eta(ref.pose.pose), convert.twist_to_nu3(ref.twist.twist)
    assert eta_d == pytest.approx([0.3, -0.2, 0.4], abs=1e-9)  # on the path, heading kept
    assert math.hypot(nu_d[0], nu_d[1]) == pytest.approx(0.2)  # path.speed
    h.joy(joy_msg(*sticks, pressed=(CROSS,)))
    h.wait_mode('manual')

    # A joystick sample with a NaN axis: refused and counted, no force published.
    rejected, n_taus = node.manager.rejected_samples, len(h.taus)
    tau_before = node.tau.copy()
    h.joy(joy_msg(math.nan, 0.9, 0.9))
    assert node.manager.rejected_samples > rejected
    assert len(h.taus) == n_taus and node.mode is Mode.MANUAL
    np.testing.assert_array_equal(node.tau, tau_before)

    # Automatic, then the joystick goes silent for longer than joy_timeout (0.2 s): the
    # supervisor (10 Hz timer) returns to manual and publishes zero force.
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    h.estimate(eta0 + [0.1, 0.1, 0.0])
    assert np.any(h.taus[-1])
    n_modes = len(h.modes)
    h.clock.advance(0.3)
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)
    assert node.mode is Mode.MANUAL
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    assert h.tau_stamps[-1] == h.clock.ns


def test_dp_control_stale_estimate_in_automatic_falls_back_to_manual(context, executor, spin):
    h = DpHarness(context, executor, spin, {'estimate_max_age': 0.5})
    h.estimate([0.0, 0.0, 0.0])
    assert spin(executor, lambda: h.joy_pub.get_subscription_count() > 0, TIMEOUT)
    h.joy(joy_msg(0.3))
    h.joy(joy_msg(0.3, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    h.estimate([0.05, 0.0, 0.0], age=0.3)
    assert np.any(h.taus[-1])
    h.estimate([0.05, 0.0, 0.0], age=0.6)  # the observer has been dead-reckoning too long
    n = len(h.modes)
    h.clock.advance(0.15)  # the next supervisor tick; the joystick (0.5 s) is not lost yet
    assert spin(executor, lambda: len(h.modes) > n and h.modes[-1] == 'manual', TIMEOUT)
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    assert h.node.manager.tau_manual.tolist() == [0.0, 0.0, 0.0]


# --- 2. DP control: live gains through the parameter services -----------------------------


def test_dp_control_live_gains(context, executor, spin):
    node = add(executor, DpControlNode(node_name='dp_control', context=context,
                                       parameter_overrides=overrides()))
    caller = probe(context, executor, 'ros2_param')
    client = AsyncParameterClient(caller, 'dp_control')
    assert spin(executor, client.services_are_ready, TIMEOUT), 'parameter services not found'

    def set_(name: str, value: Any) -> Any:
        response = call(executor, client.set_parameters([Parameter(name, value=value)]))
        assert len(response.results) == 1
        return response.results[0]

    def get(name: str) -> Any:
        response = call(executor, client.get_parameters([name]))
        return convert.parameter_value_to_python(response.values[0])

    kp0 = tuple(node.controller.settings.Kp)
    assert kp0 == (10.0, 10.0, 1.5)
    assert not node.controller.ramping

    result = set_('Kp', [10.0, -1.0, 1.5])
    assert not result.successful and 'Kp' in result.reason
    result = set_('Kp', [10.0, 10.0])
    assert not result.successful and 'Kp' in result.reason
    result = set_('path.heading', 'sideways')
    assert not result.successful and 'path.heading' in result.reason
    result = set_('joy.button_guidance', 2)  # = triangle
    assert not result.successful and 'buttons' in result.reason
    result = set_('Kp', 'stiff')
    assert not result.successful and result.reason
    # Every refusal kept the old values, in the node and in its controller.
    assert get('Kp') == list(kp0) and get('path.heading') == 'fixed'
    assert get('joy.button_guidance') == 3
    assert tuple(node.controller.settings.Kp) == kp0
    assert node.manager.mapping.button_guidance == 3
    assert not node.controller.ramping

    result = set_('Kp', [20.0, 20.0, 3.0])
    assert result.successful, result.reason
    assert tuple(node.controller.settings.Kp) == (20.0, 20.0, 3.0)
    assert node.controller.ramping  # blended in over gain_ramp_time, not stepped
    assert get('Kp') == [20.0, 20.0, 3.0]
    # The ramp ends after gain_ramp_time (1 s) of control steps.
    ref = HoldPose((0.0, 0.0, 0.0)).reference((0.0, 0.0, 0.0), 0.1)
    for _ in range(11):
        node.controller.step((0.1, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), ref, 0.1)
    assert not node.controller.ramping

    result = set_('path.heading', 'course')
    assert result.successful, result.reason
    assert node.settings['path.heading'] == 'course'
    result = set_('joy_timeout', 0.3)
    assert result.successful, result.reason
    assert node.manager.joy_timeout == 0.3


# --- 3. DP observer -----------------------------------------------------------------------


def test_dp_observer_rejects_jumps_and_dead_reckons(context, executor):
    node = add(executor, DpObserverNode(node_name='observer', context=context,
                                        parameter_overrides=overrides()))
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


# --- 4. azimuth allocation ----------------------------------------------------------------


def test_azimuth_allocation(context, executor):
    node = add(executor, AzimuthAllocationNode(node_name='allocation', context=context,
                                               parameter_overrides=overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    delivered: list[WrenchStamped] = []
    p.create_topic_subscription(topics.AZIMUTH_COMMANDS, commands.append)
    p.create_topic_subscription(topics.ALLOCATION_DELIVERED, delivered.append)
    LinkBus.of(context).connect()

    def send(tau: list[float], ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench_tau3(w.wrench, tau)
        n = len(commands)
        pub.publish(w)
        assert len(commands) == n + 1 and len(delivered) == n + 1
        out = commands[-1]
        assert list(out.name) == NAMES
        assert convert.stamp_to_ns(out.header.stamp) == ns
        assert convert.stamp_to_ns(delivered[-1].header.stamp) == ns
        thrust, angle = np.array(out.effort), np.array(out.position)
        assert np.all(np.abs(angle) <= SERVO_LIMIT + 1e-9)
        assert np.all(thrust <= MAX_FORWARD + 1e-12) and np.all(-thrust <= MAX_REVERSE + 1e-12)
        return thrust, angle, convert.wrench_to_tau3(delivered[-1].wrench)

    for i, tau in enumerate(([0.5, -0.3, 0.05], [-1.0, 0.0, 0.0], [0.0, 1.2, -0.1],
                             [0.0, 0.0, 0.1], [0.0, 0.0, 0.0])):
        thrust, angle, got = send(tau, 1_000_000_000 + i)
        assert got == pytest.approx(tau, abs=1e-9)
        assert tau_of(POSITIONS, thrust, angle) == pytest.approx(tau, abs=1e-9)
    assert node.infeasible == 0

    # Far beyond the azimuths: the delivered force is parallel to the request and smaller.
    huge = np.array([20.0, -10.0, 1.0])
    thrust, angle, got = send(huge.tolist(), 2_000_000_000)
    assert node.infeasible == 1
    assert np.linalg.norm(got) < np.linalg.norm(huge)
    assert got / huge == pytest.approx(np.full(3, got[0] / huge[0]), rel=1e-9)
    assert 0.0 < got[0] / huge[0] < 1.0
    assert tau_of(POSITIONS, thrust, angle) == pytest.approx(got, abs=1e-9)
    at_limit = np.isclose(thrust, MAX_FORWARD) | np.isclose(-thrust, MAX_REVERSE)
    assert at_limit.any()  # scaled until one azimuth is at its limit

    # A non-finite request is refused, nothing published.
    n = len(commands)
    w = WrenchStamped()
    w.wrench.torque.z = math.inf
    pub.publish(w)
    assert node.rejected == 1 and len(commands) == n


def test_azimuth_allocation_refuses_layout_that_cannot_yaw(context):
    centre = {f'azimuths.{n}.position': [0.0, 0.0] for n in NAMES}
    with pytest.raises(AllocationError, match='yaw') as info:
        AzimuthAllocationNode(node_name='allocation', context=context,
                              parameter_overrides=overrides(centre))
    assert 'allocation' in str(info.value)
    assert 'surge' not in str(info.value).split('cannot produce')[1].split('(')[0]


# --- 5. PWM mapper ------------------------------------------------------------------------


def test_pwm_mapper_duties_watchdog_safe_state_and_refusals(context, executor, spin):
    node = add(executor, PwmMapperNode(node_name='pwm', context=context,
                                       parameter_overrides=overrides({'command_timeout': 0.1})))
    channels = [f'{n}/{k}' for n in NAMES for k in ('motor', 'servo')]
    neutral = [NEUTRAL_DUTY] * len(channels)
    assert node.channels == channels
    assert node.neutral and node.duty == pytest.approx(neutral)  # starts neutral
    p = probe(context, executor, 'allocation')
    pub = p.create_topic_publisher(topics.AZIMUTH_COMMANDS)
    duties: list[JointState] = []
    p.create_topic_subscription(topics.PWM_DUTY, duties.append)
    LinkBus.of(context).connect()
    c = node.calibration

    thrust = [0.3, -0.45, 1.5]
    angle = [0.4, -1.0, 1.98968]
    pub.publish(azimuth_msg(thrust, angle, stamp_ns=1_234_000_000))
    assert len(duties) == 1 and not node.neutral
    out = duties[-1]
    assert list(out.name) == channels
    assert convert.stamp_to_ns(out.header.stamp) == 1_234_000_000
    d = np.array(out.effort)
    assert np.all((d >= DUTY_MIN) & (d <= DUTY_MAX))
    expected = [v for f, a in zip(thrust, angle) for v in (c.thrust_to_duty(f),
                                                            c.angle_to_duty(a))]
    assert d.tolist() == pytest.approx(expected, abs=1e-12)
    # The same numbers from the profile's tables by hand: 0.3 N half-way from 7.0 % (0 N) to
    # 8.2 % (0.6 N), -0.45 N at 5.5 %, 1.5 N at 9.4 %; servo 0.4 rad on 6.85 .. 9.4 %.
    assert d[0::2].tolist() == pytest.approx([7.6, 5.5, 9.4], abs=1e-12)
    assert d[1] == pytest.approx(6.85 + 0.4 / 1.98968 * 2.55, abs=1e-12)
    assert d[5] == pytest.approx(9.4, abs=1e-12)

    # Beyond the tables: clipped to the PWM range.
    pub.publish(azimuth_msg([5.0, -5.0, 0.0], [3.0, -3.0, 0.0]))
    assert np.array(duties[-1].effort).tolist() == pytest.approx(
        [9.4, 9.4, 4.3, 4.3, NEUTRAL_DUTY, NEUTRAL_DUTY], abs=1e-12)

    # safe_state(): neutral at once.
    node.safe_state()
    assert np.array(duties[-1].effort).tolist() == pytest.approx(neutral)
    assert node.neutral

    # Refused (counted, nothing published): NaN thrust, NaN angle, unknown azimuth, lengths.
    pub.publish(azimuth_msg(thrust, angle))
    n, before = len(duties), list(node.duty)
    pub.publish(azimuth_msg([math.nan, 0.1, 0.1], angle))
    pub.publish(azimuth_msg(thrust, [0.0, math.inf, 0.0]))
    pub.publish(azimuth_msg([0.1], [0.0], names=['az_mid']))
    pub.publish(JointState(name=NAMES, effort=thrust, position=[0.0]))
    assert node.rejected == 4 and len(duties) == n and node.duty == before

    # Commands stop: neutral by itself after command_timeout, once.
    assert node.timeouts == 0 and not node.neutral
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(duties) == n + 1
    assert np.array(duties[-1].effort).tolist() == pytest.approx(neutral)
    assert node.neutral
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert node.timeouts == 1 and len(duties) == n + 1  # not repeated


# --- 6. simulated Arduino -----------------------------------------------------------------


def test_sim_arduino_round_trip_with_pwm_mapper(context, executor):
    pwm = add(executor, PwmMapperNode(node_name='pwm', context=context,
                                      parameter_overrides=overrides({'command_timeout': 10.0})))
    arduino = add(executor, SimArduinoNode(
        node_name='arduino', context=context,
        parameter_overrides=overrides({'command_timeout': 10.0})))
    p = probe(context, executor, 'allocation')
    pub = p.create_topic_publisher(topics.AZIMUTH_COMMANDS)
    applied: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, applied.append)
    LinkBus.of(context).connect()
    assert pwm.calibration == arduino.calibration

    rng = np.random.default_rng(5)
    cases = [([0.3, -0.45, 1.5], [0.4, -1.0, 1.98968]),
             ([-1.0, 0.6, 1e-3], [-1.98968, 0.0, -0.2]),
             ([-2e-3, 1.2, -0.7], [1.0, 1.5, -1.5])]
    cases += [(list(rng.uniform(-1.0, 1.5, 3)), list(rng.uniform(-1.98968, 1.98968, 3)))
              for _ in range(20)]
    for thrust, angle in cases:
        n = len(applied)
        pub.publish(azimuth_msg(thrust, angle))
        assert len(applied) == n + 1
        out = applied[-1]
        assert list(out.name) == NAMES
        np.testing.assert_allclose(out.effort, thrust, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(out.position, angle, rtol=0.0, atol=1e-9)
    assert arduino.refused == 0 and not arduino.neutral
    # Zero thrust is the middle of the dead band and comes back as zero.
    pub.publish(azimuth_msg([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
    assert list(applied[-1].effort) == [0.0, 0.0, 0.0] and arduino.neutral


def test_sim_arduino_refuses_out_of_range_duties_and_watchdog(context, executor, spin):
    node = add(executor, SimArduinoNode(
        node_name='arduino', context=context,
        parameter_overrides=overrides({'command_timeout': 0.1})))
    p = probe(context, executor, 'pwm')
    pub = p.create_topic_publisher(topics.PWM_DUTY)
    applied: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, applied.append)
    LinkBus.of(context).connect()
    c = node.calibration

    good = {f'{n}/{k}': d for n in NAMES for k, d in (('motor', 8.2), ('servo', 9.4))}
    pub.publish(duty_msg(good))
    assert len(applied) == 1 and not node.neutral
    assert list(applied[-1].effort) == pytest.approx([0.6] * 3, abs=1e-12)
    assert list(applied[-1].position) == pytest.approx([1.98968] * 3, abs=1e-12)

    for bad in (3.0, 12.0, 4.2, 9.5, math.nan, math.inf):
        n = node.refused
        pub.publish(duty_msg({**good, 'az_bow/motor': bad}))
        assert node.refused == n + 1, bad
        pub.publish(duty_msg({**good, 'az_stbd_aft/servo': bad}))
        assert node.refused == n + 2, bad
    pub.publish(duty_msg({'az_mid/motor': 7.0}))
    assert node.refused == 13 and len(applied) == 1
    # The limits themselves are valid duties.
    pub.publish(duty_msg({**good, 'az_bow/motor': 4.3, 'az_port_aft/motor': 9.4}))
    assert len(applied) == 2 and list(applied[-1].effort) == pytest.approx([-1.0, 1.5, 0.6])

    # Duty cycles stop: neutral by itself after command_timeout.
    assert node.timeouts == 0
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(applied) == 3 and node.neutral
    assert list(applied[-1].effort) == [c.duty_to_thrust(c.neutral_thrust_duty)] * 3 == [0.0] * 3
    assert list(applied[-1].position) == pytest.approx([0.0] * 3, abs=1e-12)


# --- 7. simulator and simulated motion capture --------------------------------------------


def test_saucer_simulator_and_sim_mocap(context, executor):
    sim = add(executor, SaucerSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides({'rate': 100.0})))
    mocap = add(executor, SimMocapNode(
        node_name='mocap', context=context, parameter_overrides=[
            Parameter('rate', value=50.0), Parameter('dropout_windows', value=[0.5, 1.0]),
            Parameter('position_noise', value=0.002), Parameter('heading_noise', value=0.005)]))
    clock = SimClock(sim, mocap)
    p = probe(context, executor, 'arduino')
    cmd_pub = p.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
    truth: dict[int, Odometry] = {}
    poses: dict[int, PoseStamped] = {}
    p.create_topic_subscription(
        topics.SIM_ODOMETRY, lambda m: truth.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(
        topics.MOCAP_POSE, lambda m: poses.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    LinkBus.of(context).connect()
    assert not sim._loops[0].running  # never started: stepped by hand

    forward = azimuth_msg([1.0, 1.0, 1.0], [0.0, 0.0, 0.0])
    steps = 150  # 1.5 s
    for k in range(steps):
        if k % 5 == 0:
            cmd_pub.publish(forward)  # well within command_timeout (0.25 s)
        clock.advance(0.01)
        sim.step()
    assert sim.steps == steps and len(truth) == steps
    stamps = sorted(truth)
    assert np.diff(stamps).tolist() == [10_000_000] * (steps - 1)
    assert stamps[-1] == clock.ns

    # Three azimuths pushing ahead at 0 rad: the vessel accelerates east, straight.
    x = np.array([truth[s].pose.pose.position.x for s in stamps])
    u = np.array([truth[s].twist.twist.linear.x for s in stamps])
    assert x[-1] > 0.1 and np.all(np.diff(x[5:]) > 0.0)
    assert u[-1] > 0.1 and np.all(np.diff(u[5:]) > 0.0)
    for s in stamps:
        eta = convert.pose_to_eta(truth[s].pose.pose)
        assert abs(eta[1]) < 1e-9 and abs(eta[2]) < 1e-9
    assert sim.actuators.tau() == pytest.approx([3.0, 0.0, 0.0], abs=1e-3)  # 3 x 1 N

    # Motion capture: every 20 ms from the first sample, none inside [0.5, 1.0) s.
    start = stamps[0]
    slots = [s for s in stamps if (s - start) % 20_000_000 == 0]
    in_window = [s for s in slots if 0.5 <= (s - start) * 1e-9 < 1.0]
    assert len(slots) == 75 and 24 <= len(in_window) <= 26
    assert sorted(poses) == [s for s in slots if s not in in_window]
    assert mocap.published == len(poses) and mocap.dropped == len(in_window)
    assert mocap.published + mocap.dropped == len(slots)
    # Measured with noise around the truth.
    err = np.array([convert.pose_to_eta(poses[s].pose) - convert.pose_to_eta(truth[s].pose.pose)
                    for s in sorted(poses)])
    assert np.all(err[:, :2] != 0.0) and np.all(err[:, 2] != 0.0)
    assert np.abs(err[:, :2]).max() < 5 * 0.002 and np.abs(err[:, 2]).max() < 5 * 0.005
    assert err[:, :2].std() == pytest.approx(0.002, rel=0.3)
    assert err[:, 2].std() == pytest.approx(0.005, rel=0.3)
    assert all(poses[s].header.frame_id == topics.WORLD_FRAME for s in poses)
