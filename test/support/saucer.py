"""Fixtures of the CS Saucer node tests: parameters, messages, a simulated clock, DP harness."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from rclpy.time import Time
from rclpy.time_source import TimeSource
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, Joy
from std_msgs.msg import Bool, Float64, Float64MultiArray, String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from enbarr_core.allocation.pwm_mapper_node import duty_message
from enbarr_core.bringup.profile import load_profile
from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_core.control.joy_layouts import mapping_from_params
from enbarr_interfaces.modes import Mode
from enbarr_core.guidance.guidance_node import GuidanceNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.nodes import add, probe, TIMEOUT



T0_NS = 1_000_000_000  # simulated clocks start at 1 s


SERVO_LIMIT = math.radians(114.0)


PROFILE = load_profile('saucer_sim')
COMMON = dict(PROFILE.parameters)  # layout, pwm tables, vessel, joystick layout
CORE = load_profile('saucer_core', allow_fragment=True)  # the nodes' own parameters


def node_parameters(node: str, profile: Any = CORE) -> dict[str, Any]:
    """What the profile gives node ``node``: the common parameters and its own."""
    spec = next(n for n in profile.nodes if n.name == node)
    return {**profile.parameters, **spec.parameters}


VESSEL = {k: v for k, v in COMMON.items() if k.startswith('vessel.')}


NAMES = list(COMMON['azimuth_names'])


POSITIONS = np.array([COMMON[f'azimuths.{n}.position'] for n in NAMES])


MAX_FORWARD = np.array([COMMON[f'azimuths.{n}.max_forward'] for n in NAMES])


MAX_REVERSE = np.array([COMMON[f'azimuths.{n}.max_reverse'] for n in NAMES])


DUTY_MIN, DUTY_MAX = 4.3, 9.4


NEUTRAL_DUTY = 6.85  # middle of the 6.7 .. 7.0 % dead band; servo 0 rad at 6.85 %


MAPPING, LOSS_RULE = mapping_from_params(COMMON)  # the profile's named layout, as indices
TRIANGLE, SQUARE, CROSS = (MAPPING.button_automatic, MAPPING.button_guidance,
                           MAPPING.button_manual)


def overrides(extra: dict[str, Any] | None = None, node: str | None = None) -> list[Parameter]:
    """The common saucer parameters, node ``node``'s own from the profile (if given), plus
    ``extra``, as parameter overrides.
    """
    base = node_parameters(node) if node else COMMON
    return [Parameter(k, value=v) for k, v in {**base, **(extra or {})}.items()]


class SimClock:
    """Simulated ROS time on the given nodes' clocks (what ``enbarr scenario`` does): their
    timers fire, and their ``now()`` moves, only when the test advances it. The time source
    is rclpy's own, fed by the test instead of ``/clock`` (public API only).
    """

    def __init__(self, *nodes: Any, t0_ns: int = T0_NS) -> None:
        self.source = TimeSource()  # no node: it subscribes to no /clock
        self.source.ros_time_is_active = True
        self.ns = 0
        for n in nodes:
            self.attach(n)
        self.set(t0_ns)

    def attach(self, node: Any) -> None:
        """Put ``node``'s clock on this time too (at once at the present simulated time)."""
        self.source.attach_clock(node.get_clock())

    def set(self, ns: int) -> None:
        self.ns = int(ns)
        self.source.clock_callback(Clock(clock=Time(nanoseconds=self.ns).to_msg()))

    def advance(self, seconds: float) -> int:
        self.set(self.ns + round(seconds * 1e9))
        return self.ns


def joy_msg(surge: float = 0.0, sway: float = 0.0, yaw: float = 0.0,
            pressed: tuple[int, ...] = ()) -> Joy:
    axes = [0.0] * 8
    axes[MAPPING.axis_surge], axes[MAPPING.axis_sway], axes[MAPPING.axis_yaw] = (
        s * v for s, v in zip(MAPPING.signs, (surge, sway, yaw)))  # the profile's layout
    buttons = [0] * 18
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


def duty_msg(duties: list[float]) -> Float64MultiArray:
    """A ``pwm/duty_cycle`` message: one duty [%] per channel, in the profile's order."""
    return duty_message(duties)


def tau_of(positions: np.ndarray, thrust: Any, angle: Any) -> np.ndarray:
    """[X, Y, N] of azimuth thrusts, computed here from the geometry (not by the code under
    test): f = T (cos a, sin a) at (x, y), N = x f_y - y f_x.
    """
    T, a = np.asarray(thrust, float), np.asarray(angle, float)
    fx, fy = T * np.cos(a), T * np.sin(a)
    return np.array([fx.sum(), fy.sum(), (positions[:, 0] * fy - positions[:, 1] * fx).sum()])


class DpHarness:
    """A DpControlNode and a GuidanceNode on a simulated clock, their joystick (ROS),
    observer (links) and outputs.
    """

    def __init__(self, context: Any, executor: Any, spin: Callable[..., bool],
                 extra: dict[str, Any] | None = None,
                 guidance_extra: dict[str, Any] | None = None) -> None:
        self.executor, self.spin = executor, spin
        self.guidance = add(executor, GuidanceNode(
            node_name='guidance', context=context,
            parameter_overrides=overrides(guidance_extra, node='guidance')))
        self.node = node = add(executor, DpControlNode(
            node_name='dp_control', context=context,
            parameter_overrides=overrides(extra, node='dp_control')))
        self.clock = SimClock(node, self.guidance)
        p = probe(context, executor, 'operator')
        self.probe = p
        self.joy_pub = p.create_publisher(Joy, topics.JOY.name, topics.JOY.qos)
        self.connected_pub = p.create_topic_publisher(topics.JOY_CONNECTED)
        self.modes: list[str] = []
        p.create_subscription(String, topics.MODE.name, lambda m: self.modes.append(m.data),
                              topics.MODE.qos)
        self.odom_pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self.age_pub = p.create_topic_publisher(topics.OBSERVER_AGE)
        self.bias_pub = p.create_topic_publisher(topics.OBSERVER_BIAS)
        self.taus: list[np.ndarray] = []
        self.tau_stamps: list[int] = []
        self.refs: list[MultiDOFJointTrajectory] = []
        p.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        p.create_topic_subscription(topics.GUIDANCE_REFERENCE, self.refs.append)
        LinkBus.of(context).connect()
        for n in (self.guidance, node):  # as bringup does: the first mode goes out at start
            n.start()
        # Count every joystick sample the node's mode manager sees (accepted or not).
        self.joy_seen = 0
        real = node.manager.on_joy

        def counting(*args: Any, **kwargs: Any) -> Any:
            self.joy_seen += 1
            return real(*args, **kwargs)

        node.manager.on_joy = counting
        self.t_odom = T0_NS
        assert spin(executor, lambda: self.joy_pub.get_subscription_count() > 0, TIMEOUT)
        self.wait_mode('manual')
        self.wait_path_available(bool(self.guidance.settings.waypoints))

    def _on_tau(self, msg: WrenchStamped) -> None:
        self.taus.append(convert.wrench_to_tau3(msg.wrench))
        self.tau_stamps.append(convert.stamp_to_ns(msg.header.stamp))

    def heartbeat(self, connected: bool = True) -> None:
        """Publish the joystick's connection state and wait until the node took it now."""
        now = self.clock.ns * 1e-9
        m = self.node.manager
        self.connected_pub.publish(Bool(data=connected))
        assert self.spin(self.executor, lambda: m.connected == connected and (
            not connected or m.heartbeat_at == now), TIMEOUT), 'joy/connected not taken'

    def joy(self, msg: Joy) -> None:
        """Publish ``msg`` until the node has handled it (the joystick topic is best effort;
        a repeated sample is harmless: held buttons do not trigger again). Under the
        profile's ``connection`` loss rule a heartbeat goes first, as a driver's would.
        """
        if self.node.manager.loss_rule == 'connection':
            self.heartbeat()
        seen = self.joy_seen
        deadline = time.monotonic() + TIMEOUT
        while self.joy_seen == seen and time.monotonic() < deadline:
            self.joy_pub.publish(msg)
            self.spin(self.executor, lambda: self.joy_seen > seen, 0.5)
        assert self.joy_seen > seen, 'the joystick sample never reached dp_control'

    def estimate(self, eta: Any, nu: Any = (0.0, 0.0, 0.0), age: float = 0.0) -> None:
        """One observer output, as the observer publishes it (age, bias, then odometry)."""
        self.t_odom += 20_000_000
        # Stamped at the clock, as an observer in the process stamps (nodes refuse stamps
        # ahead of their clock): the clock moves up to the estimate when behind it.
        if self.t_odom > self.clock.ns:
            self.clock.set(self.t_odom)
        self.age_pub.publish(Float64(data=age))
        self.bias_pub.publish(WrenchStamped())
        self.odom_pub.publish(odometry_msg(self.t_odom, eta, nu))

    def wait_mode(self, mode: str) -> None:
        """Until ``mode`` is published and the guidance node follows it."""
        assert self.spin(self.executor, lambda: self.modes and self.modes[-1] == mode
                         and self.guidance.mode is Mode(mode),
                         TIMEOUT), f'mode {mode} never published: {self.modes}'

    def wait_path_available(self, available: bool) -> None:
        """Until the controller has heard whether the guidance node has a path."""
        assert self.spin(self.executor, lambda: self.node.path_available is available,
                         TIMEOUT), f'path_available never became {available}'
