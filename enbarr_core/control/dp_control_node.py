"""DP control node: the operator modes (DualShock 4), guidance and the DP controller.

``joy`` drives the mode rules of ``algorithms.modes`` (manual: the sticks command surge,
sway and yaw force; triangle: automatic, holding the pose where the vessel is; square:
guidance at ``path.speed``, to the waypoint when ``path.waypoints`` holds one, else along the
path with line of sight; cross: manual). Every
mode change is published on ``mode`` (latched), logged and, into automatic or guidance,
bumpless: the controller's integral is set so its first output equals the force of the
moment. A refused request is logged with its reason. Losing the joystick, or the observer
dead-reckoning longer than ``estimate_max_age`` while automatic, returns to manual with zero
force.

On every ``observer/odometry`` sample the node computes tau (stamped with the sample) on
``force_command`` and, outside manual, the guidance reference on
``guidance/reference``. Gains (3-element diagonals and scalars) are parameters validated
together and applied live over ``gain_ramp_time``, so the force never jumps.
"""

from __future__ import annotations

import math
from typing import Any

from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Joy
from std_msgs.msg import Float64, String

from enbarr_interfaces import convert, topics

from enbarr_core.control.dp_control import DpControlSettings, DpController, saucer_dp_settings
from enbarr_core.guidance.guidance import GoToWaypoint, HoldPose, LosPath
from enbarr_core.control.modes import Ds4Mapping, Mode, ModeManager, Transition
from enbarr_core.framework.node import EnbarrNode, WATCHDOG_PERIOD
from enbarr_core.framework.params import ParamSpec

_D = saucer_dp_settings()
_M = Ds4Mapping()
_XYN = '(surge, sway, yaw)'
SPECS = [
    ParamSpec('Kp', list(_D.Kp), f'Proportional gains {_XYN}', 'N/m, N m/rad', 0.0, 1e4),
    ParamSpec('Ki', list(_D.Ki), f'Integral gains {_XYN}', 'N/(m s), N m/(rad s)', 0.0, 1e4),
    ParamSpec('Kd', list(_D.Kd), f'Derivative gains {_XYN}', 'N s/m, N m s/rad', 0.0, 1e4),
    ParamSpec('integral_limit', list(_D.integral_limit), f'Integral clamp {_XYN}', 'N, N m',
              0.0, 1e4),
    ParamSpec('tau_max', list(_D.tau_max), f'Force limits {_XYN}', 'N, N m', 1e-6, 1e4),
    ParamSpec('gain_ramp_time', _D.gain_ramp_time, 'Time a gain change takes to act fully',
              's', 0.0, 60.0),
    ParamSpec('bias_feedforward', _D.bias_feedforward, 'Cancel the observer\'s bias estimate'),
    ParamSpec('vessel.M', list(_D.M), 'Inertia M (manual eq. 1.2)', 'kg, kg m^2', 1e-6, 1e6),
    ParamSpec('vessel.D', list(_D.D), 'Linear damping D (manual eq. 1.4)', 'N s/m, N m s', 0.0,
              1e6),
    ParamSpec('vessel.Dn', list(_D.Dn), 'Nonlinear damping coefficients (manual eq. 1.5)',
              'N s^2/m^2, N m s^2', 0.0, 1e6),
    ParamSpec('manual_tau_max', [1.5, 1.5, 0.2], f'Force at full stick {_XYN}', 'N, N m', 0.0,
              1e4),
    ParamSpec('estimate_max_age', 1.5, 'Automatic needs a pose accepted within this time', 's',
              0.01, 60.0),
    ParamSpec('joy_timeout', 0.5, 'No joystick sample for this long: manual, zero force', 's',
              0.01, 60.0),
    ParamSpec('joy.axis_surge', _M.axis_surge, 'Joy axis for surge (up = +1)', '', 0, 64),
    ParamSpec('joy.axis_sway', _M.axis_sway, 'Joy axis for sway (left = +1)', '', 0, 64),
    ParamSpec('joy.axis_yaw', _M.axis_yaw, 'Joy axis for yaw (left = +1)', '', 0, 64),
    ParamSpec('joy.button_automatic', _M.button_automatic, 'Button to automatic (triangle)',
              '', 0, 64),
    ParamSpec('joy.button_guidance', _M.button_guidance, 'Button to guidance (square)', '', 0,
              64),
    ParamSpec('joy.button_manual', _M.button_manual, 'Button to manual (cross)', '', 0, 64),
    ParamSpec('joy.deadzone', _M.deadzone, 'Stick dead zone', '', 0.0, 0.99),
    ParamSpec('path.waypoints', [0.0], 'Guidance: x, y of one waypoint to go to, or x0, y0, '
              'x1, y1, ... of a path to follow (odom); [0.0]: none', 'm', -1e6, 1e6),
    ParamSpec('path.speed', 0.2, 'Reference speed along the path', 'm/s', 1e-3, 10.0),
    ParamSpec('path.accel', 0.05, 'Acceleration limit when going to a single waypoint',
              'm/s^2', 1e-4, 10.0),
    ParamSpec('path.lookahead', 0.5, 'Line-of-sight lookahead distance', 'm', 1e-3, 100.0),
    ParamSpec('path.acceptance_radius', 0.1, 'Waypoint acceptance radius', 'm', 1e-3, 100.0),
    ParamSpec('path.heading', 'fixed', 'Heading along the path: fixed (keep the heading held '
              'when guidance starts; the round hull moves alike in surge and sway) or course '
              '(face the direction of travel)'),
]


def build(v: dict[str, Any]) -> dict[str, Any]:
    for k in ('Kp', 'Ki', 'Kd', 'integral_limit', 'tau_max', 'vessel.M', 'vessel.D',
              'vessel.Dn', 'manual_tau_max'):
        if len(v[k]) != 3:
            raise ValueError(f'{k}: expected 3 values (surge, sway, yaw), got {len(v[k])}')
    control = DpControlSettings(
        Kp=tuple(v['Kp']), Ki=tuple(v['Ki']), Kd=tuple(v['Kd']),
        integral_limit=tuple(v['integral_limit']), tau_max=tuple(v['tau_max']),
        M=tuple(v['vessel.M']), D=tuple(v['vessel.D']), Dn=tuple(v['vessel.Dn']),
        gain_ramp_time=v['gain_ramp_time'], bias_feedforward=v['bias_feedforward'])
    control.validate()
    mapping = Ds4Mapping(v['joy.axis_surge'], v['joy.axis_sway'], v['joy.axis_yaw'],
                         v['joy.button_automatic'], v['joy.button_guidance'],
                         v['joy.button_manual'], v['joy.deadzone'])
    mapping.validate()
    if v['path.heading'] not in ('fixed', 'course'):  # checked with or without a path
        raise ValueError(f'path.heading: expected fixed or course, got {v["path.heading"]!r}')
    w = v['path.waypoints']
    waypoints: list[tuple[float, float]] = []
    if w != [0.0]:
        if len(w) % 2 or len(w) < 2:
            raise ValueError('path.waypoints: expected x, y of a waypoint or x0, y0, x1, y1, '
                             '... of a path')
        waypoints = list(zip(w[::2], w[1::2]))
        if len(waypoints) > 1:  # a path: check it now (a single waypoint is checked on use)
            LosPath(waypoints, v['path.speed'], v['path.lookahead'],
                    v['path.acceptance_radius'], heading=v['path.heading'])
    return {**v, 'control': control, 'mapping': mapping, 'waypoints': waypoints}


class DpControlNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'dp_control', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.controller: DpController | None = None
        self.manager: ModeManager | None = None
        self.settings: dict[str, Any] = {}
        self.bind_settings(SPECS, build, self._apply)
        self.guidance: HoldPose | LosPath | None = None
        self.tau = np.zeros(3)
        self.reference = None
        self.refusals = 0
        self._eta: np.ndarray | None = None
        self._bias = np.zeros(3)
        self._age = math.inf
        self._last_ns: int | None = None
        self._estimate_ns: int | None = None  # node clock when the last estimate arrived
        self._tau_pub = self.create_topic_publisher(topics.FORCE_COMMAND)
        self._ref_pub = self.create_topic_publisher(topics.GUIDANCE_REFERENCE)
        self._mode_pub = self.create_topic_publisher(topics.MODE)
        self.create_topic_subscription(topics.OBSERVER_AGE, self._on_age)
        self.create_topic_subscription(topics.OBSERVER_BIAS, self._on_bias)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_estimate)
        self.create_topic_subscription(topics.JOY, self._on_joy)
        self.create_timer(WATCHDOG_PERIOD, self._supervise)
        self.create_timer(1.0, self._report)
        self._mode_pub.publish(String(data=self.manager.mode.value))

    def _apply(self, v: dict[str, Any]) -> None:
        if self.controller is None:
            self.controller = DpController(v['control'])
            self.manager = ModeManager(v['mapping'], v['manual_tau_max'], v['joy_timeout'])
        else:
            self.controller.settings = v['control']  # ramped by the controller
            self.manager.mapping = v['mapping']
            self.manager.tau_max = np.asarray(v['manual_tau_max'], dtype=float)
            self.manager.joy_timeout = v['joy_timeout']
        self.settings = v

    @property
    def mode(self) -> Mode:
        return self.manager.mode

    def _fresh(self) -> bool:
        """A pose was accepted recently, and the observer itself is still publishing."""
        limit = self.settings['estimate_max_age']
        return (self._eta is not None and self._age <= limit and self._estimate_ns is not None
                and self.get_clock().now().nanoseconds - self._estimate_ns <= limit * 1e9)

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_age(self, msg: Float64) -> None:
        self._age = msg.data

    def _on_bias(self, msg: WrenchStamped) -> None:
        self._bias = convert.wrench_to_tau3(msg.wrench)

    def _on_joy(self, msg: Joy) -> None:
        before = self.manager.rejected_samples
        transitions = self.manager.on_joy(list(msg.axes), list(msg.buttons), self._now_s(),
                                          self._fresh(), bool(self.settings['waypoints']))
        if self.manager.rejected_samples > before:
            self.get_logger().warn('joystick sample refused (non-finite or out-of-range axes, '
                                   'or too few axes/buttons)', throttle_duration_sec=1.0)
            return  # as if it never arrived: no force republished on its behalf
        for t in transitions:
            self._transition(t)
        if self.manager.mode is Mode.MANUAL:
            self._publish_tau(self.manager.tau_manual, msg.header.stamp)

    def _supervise(self) -> None:
        t = self.manager.check(self._now_s(), self._fresh())
        if t is not None:
            self._transition(t)
            self._publish_tau(self.manager.tau_manual, self.get_clock().now().to_msg())

    def _transition(self, t: Transition) -> None:
        if not t.accepted:
            self.refusals += 1
            self.get_logger().warn(f'{t.requested.value} mode refused: {t.reason}')
            return
        if t.requested is Mode.AUTOMATIC:
            self.guidance = HoldPose(self._eta)
        elif t.requested is Mode.GUIDANCE:
            s = self.settings
            if len(s['waypoints']) == 1:  # go to the waypoint, heading held
                self.guidance = GoToWaypoint(self._eta, s['waypoints'][0], s['path.speed'],
                                             s['path.accel'],
                                             arrival_radius=s['path.acceptance_radius'])
            else:
                self.guidance = LosPath(s['waypoints'], s['path.speed'], s['path.lookahead'],
                                        s['path.acceptance_radius'], heading=s['path.heading'])
        else:
            self.guidance = None
        if t.requested is not Mode.MANUAL:
            self.controller.reset(tau_now=self.tau)  # bumpless: continue from the force now
        self.get_logger().info(f'mode {t.previous.value} -> {t.requested.value} ({t.reason})')
        self._mode_pub.publish(String(data=t.requested.value))

    def _on_estimate(self, msg: Odometry) -> None:
        eta = convert.pose_to_eta(msg.pose.pose)
        nu = convert.twist_to_nu3(msg.twist.twist)
        t = convert.stamp_to_ns(msg.header.stamp)
        last, self._last_ns = self._last_ns, t
        self._eta = eta
        self._estimate_ns = self.get_clock().now().nanoseconds
        if self.manager.mode is Mode.MANUAL or self.guidance is None:
            return  # manual force goes out with each joystick sample
        if last is not None and t > last:
            dt = (t - last) * 1e-9
            self.reference = ref = self.guidance.reference(eta, dt)
            self.tau = self.controller.step(eta, nu, self._bias, ref, dt).tau
            out = Odometry()
            out.header = msg.header
            out.child_frame_id = topics.BODY_FRAME
            convert.set_pose_eta(out.pose.pose, ref.eta_d)
            convert.set_twist_nu3(out.twist.twist, ref.nu_d)
            self._ref_pub.publish(out)
            self._publish_tau(self.tau, msg.header.stamp)

    def _publish_tau(self, tau: np.ndarray, stamp: Any) -> None:
        self.tau = tau
        w = WrenchStamped()
        w.header.stamp = stamp
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench_tau3(w.wrench, tau)
        self._tau_pub.publish(w)

    def _report(self) -> None:
        self.publish_diagnostics(0, self.manager.mode.value, {
            'refusals': self.refusals, 'joy_rejected': self.manager.rejected_samples})
