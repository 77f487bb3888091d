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
from sensor_msgs.msg import JointState, Joy
from std_msgs.msg import Float64, Float64MultiArray, String

from enbarr_core.allocation.pwm_mapper_node import duty_message
from enbarr_core.bringup.profile import load_profile
from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.nodes import add, probe, TIMEOUT



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


def overrides(extra: dict[str, Any] | None = None) -> list[Parameter]:
    """The common saucer parameters (plus ``extra``) as parameter overrides."""
    return [Parameter(k, value=v) for k, v in {**COMMON, **(extra or {})}.items()]


class SimClock:
    """Simulated ROS time on the given nodes' clocks (what ``enbarr scenario`` does): their
    timers fire, and their ``now()`` moves, only when the test advances it.
    """

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
    """A DpControlNode on a simulated clock, its joystick (ROS), observer (links) and
    outputs.
    """

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
        a repeated sample is harmless: held buttons do not trigger again).
        """
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
