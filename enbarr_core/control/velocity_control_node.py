"""Velocity control loop: ``trajectory_request`` + ``imu/data`` -> ``force_command``.

A PID with anti-windup and model-based feed-forward (``enbarr_core.control.velocity_control``)
behind a reference model that turns a step in the goal into a reachable velocity trajectory. It
runs once per filtered IMU sample, with dt from the sample stamps. Rates p, q, r are measured
by the gyro; roll and pitch feed the leveling term. Linear velocity is not measured by an IMU:
unless ``velocity_topic`` names an ``nav_msgs/Odometry`` source (a DVL, an acoustic or visual
odometry), surge, sway and heave run on the feed-forward alone. A velocity goal stamped more
than ``goal_timeout`` before the IMU sample counts as zero.
Every gain is a parameter; a new value acts on the next sample without a jump in tau.

The failsafes' action (``failsafe/action``, ``control.failsafe_node``) is applied here when it
changes: ``surface`` forces depth hold (stabilize without a fresh depth) with a climb of
``failsafe.climb_rate`` as the goal, ``stabilize`` and ``manual`` force those modes, ``neutral``
puts out zero force from the next sample; while one of these acts, pilot mode requests are
refused with the reason. Per sample it costs two attribute tests.

Time policy (``framework.stamps``): ``imu/data`` and ``trajectory_request`` stamps pass one
gate each before they are used: a stamp more than ``max_future`` ahead of the node's clock, or
not later than the last accepted one of its input, is refused and counted. So one early IMU
sample cannot become the loop's time base (and stall it until the clock catches up), and one
early goal cannot outlive ``goal_timeout``. ``/diagnostics`` reports the node degraded when it
refuses more than 5 % of an input's samples in a second or resets its integrators, and
``max_gap`` / ``goal_timeout`` must cover two measured periods of ``imu/data`` /
``trajectory_request`` (a live change below that is refused with the figure; a start value
below it is reported once the period is measured).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import Parameter
from sensor_msgs.msg import Imu
from std_msgs.msg import String

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_interfaces.topics import TopicSpec

from enbarr_core.control.pilot_hold import (
    DepthHold, DepthHoldSettings, HeadingHold, HeadingHoldSettings)
from enbarr_core.control.failsafes import MANUAL as FS_MANUAL, NEUTRAL, NONE, SURFACE
from enbarr_core.control.failsafes import STABILIZE as FS_STABILIZE
from enbarr_core.control.pilot_modes import (
    DEPTH_HOLD, EXECUTOR, MANUAL, manual_force, manual_problem, MODES, PilotModes, STABILIZE)
from enbarr_core.control.velocity_control import (
    VelocityControlSettings, VelocityController, VelocityReference)
from enbarr_core.estimation.depth_estimator import DepthEstimator, DepthEstimatorSettings
from enbarr_core.framework.checks import floats
from enbarr_core.framework.health import (
    ERROR, future_tolerance_problem, InputHealth, IntervalMeter, too_short_for_rate, worst)
from enbarr_core.framework.kinematics import quat_to_euler, quat_to_rotmat
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.models.rigid_body_params import VEHICLE_SPECS
from enbarr_core.framework.stamps import (
    SAME_CLOCK_MAX_FUTURE, StampGate, StampPolicy, StampVerdict)

#: The failsafe actions that take the pilot mode from the pilot.
FORCING = (NEUTRAL, SURFACE, FS_STABILIZE, FS_MANUAL)
#: Window of the diagnostics report [s].
REPORT_PERIOD = 1.0
#: Standard gravity [m/s^2]: the specific force minus this is the vertical acceleration (the
#: depth estimator's bias state takes up the local difference).
G = 9.80665

_DOF = 'surge, sway, heave, roll, pitch, yaw'
SPECS = [
    # The gains, limits and reference model are tuned for a vehicle: vessel data, given by
    # the profile (required: no default here to be silently wrong for another vehicle).
    ParamSpec('kp', [0.0], f'Proportional gains ({_DOF})', 'N/(m/s), N m/(rad/s)', 0.0, 1e4,
              required=True),
    ParamSpec('ki', [0.0], f'Integral gains ({_DOF})', 'N/m, N m/rad', 0.0, 1e4,
              required=True),
    ParamSpec('kd', [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], f'Derivative gains on measurement ({_DOF})',
              'N/(m/s^2), N m/(rad/s^2)', 0.0, 1e3),
    ParamSpec('integral_limit', [0.0], f'Clamp of the integral contribution ({_DOF})',
              'N, N m', 0.0, 1e4, required=True),
    ParamSpec('tau_max', [0.0], f'Output limits ({_DOF})', 'N, N m', 1e-6, 1e5, required=True),
    ParamSpec('reference_time_constant', [0.0],
              f'Time constants of the goal reference model ({_DOF})', 's', 1e-3, 60.0,
              required=True),
    ParamSpec('max_accel', [0.0], f'Acceleration limits of the reference model ({_DOF})',
              'm/s^2, rad/s^2', 1e-3, 100.0, required=True),
    ParamSpec('level_gain', 0.0, 'Roll/pitch leveling: rate setpoint -k * angle', '1/s', 0.0,
              100.0, required=True),
    ParamSpec('derivative_filter', 0.02, 'Time constant of the derivative filter', 's', 1e-4,
              10.0),
    ParamSpec('goal_timeout', 1.0, 'A velocity goal older than this counts as zero', 's',
              0.01, 60.0),
    ParamSpec('max_gap', 0.5, 'IMU gaps longer than this reset the integrators', 's', 1e-3,
              60.0),
    ParamSpec('max_future', SAME_CLOCK_MAX_FUTURE,
              'imu/data and goals stamped further ahead of the node '
              'clock are refused (time policy)', 's', 0.0, 1.0),
    ParamSpec('velocity_topic', '', 'nav_msgs/Odometry source of linear body velocity; empty: '
              'feed-forward only on surge, sway, heave', read_only=True),
    *VEHICLE_SPECS,  # the feed-forward model: vessel data from the profile, required
    # Pilot modes (control.pilot_modes, control.pilot_hold, estimation.depth_estimator)
    ParamSpec('pilot.mode', 'velocity', 'Pilot mode at start: ' + ', '.join(MODES)
              + ' (then requested on io_request, executor pilot_mode)', read_only=True),
    ParamSpec('pilot.full_stick', [0.5, 0.5, 0.5, 1.0, 1.0, 1.0],
              f'Velocity goal at full stick ({_DOF}): manual maps goal / full_stick to '
              'tau_max', 'm/s, rad/s', 1e-3, 100.0),
    ParamSpec('pilot.depth_timeout', 0.5, 'A depth older than this refuses depth_hold, and '
              'falls back to stabilize from it', 's', 0.01, 10.0),
    ParamSpec('depth_hold.gain', 1.0, 'Climb rate per metre of depth error', '1/s', 1e-3,
              100.0),
    ParamSpec('depth_hold.integral_gain', 0.3, 'Climb rate per metre-second of depth error',
              '1/s^2', 0.0, 100.0),
    ParamSpec('depth_hold.integral_limit', 0.2, 'Limit of the integral climb rate', 'm/s',
              0.0, 10.0),
    ParamSpec('depth_hold.max_climb', 0.5, "Climb rate at full heave stick, and the hold's "
              'limit', 'm/s', 1e-3, 10.0),
    ParamSpec('depth_hold.deadband', 0.05, 'Heave stick fraction that counts as centred', '',
              0.0, 0.99),
    ParamSpec('depth_hold.stop_time', 0.4, 'On release or entering depth_hold the climb-rate '
              'goal runs down to zero, critically damped with this time constant, before the '
              'depth is taken (the vehicle travels 2 x climb rate x this)', 's', 0.02, 10.0),
    ParamSpec('heading_hold.gain', 2.0, 'Yaw rate per radian of heading error', '1/s', 1e-3,
              100.0),
    ParamSpec('heading_hold.max_rate', 0.6, "Yaw rate at full yaw stick, and the hold's "
              'limit', 'rad/s', 1e-3, 10.0),
    ParamSpec('heading_hold.deadband', 0.05, 'Yaw stick fraction that counts as centred', '',
              0.0, 0.99),
    ParamSpec('heading_hold.settle_rate', 0.05, 'The heading is taken once the yaw rate is '
              'below this', 'rad/s', 1e-4, 10.0),
    ParamSpec('heading_hold.settle_time', 0.5, '... or this long after the stick centred',
              's', 1e-3, 10.0),
    ParamSpec('failsafe.climb_rate', 0.25, 'Climb rate of the surface failsafe action',
              'm/s', 0.01, 2.0),
    ParamSpec('depth_estimator.accel_noise', 0.05, 'Vertical acceleration noise (std)',
              'm/s^2', 1e-6, 10.0),
    ParamSpec('depth_estimator.bias_walk', 0.002, 'Accelerometer bias random walk',
              'm/s^2/sqrt(s)', 1e-9, 1.0),
    ParamSpec('depth_estimator.initial_bias_std', 0.1, 'Accelerometer bias std at start',
              'm/s^2', 1e-6, 10.0),
]


@dataclass(frozen=True)
class VelocityControlNodeSettings:
    """Settings of ``VelocityControlNode`` (see ``SPECS``); vectors are [X Y Z K M N]."""

    controller: VelocityControlSettings        # gains, limits and feed-forward model
    reference_time_constant: tuple[float, ...]  # [s]
    max_accel: tuple[float, ...]                # [m/s^2, rad/s^2]
    goal_timeout: float                         # [s]
    max_gap: float                              # [s]
    max_future: float                           # time policy of imu/data and goals [s]
    velocity_topic: str
    pilot_mode: str = 'velocity'                # at start
    full_stick: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0, 1.0, 1.0)
    depth_timeout: float = 0.5                  # [s]
    depth_hold: DepthHoldSettings = DepthHoldSettings(1.0, 0.5, 0.05, 0.3, 0.2)
    heading_hold: HeadingHoldSettings = HeadingHoldSettings(2.0, 0.6, 0.05, 0.05, 0.5)
    depth_estimator: DepthEstimatorSettings = DepthEstimatorSettings(0.05, 0.002, 0.1, 0.5)
    climb_rate: float = 0.25                    # [m/s] of the surface failsafe action

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> VelocityControlNodeSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        inertia = floats('vehicle.inertia', v['vehicle.inertia'], (3, 9))
        if len(inertia) == 9:
            inertia = (inertia[0], inertia[4], inertia[8])
        m = v['vehicle.mass']
        rigid = (m, m, m, *inertia)
        added = floats('vehicle.added_mass', v['vehicle.added_mass'], 6)
        controller = VelocityControlSettings(
            kp=floats('kp', v['kp'], 6), ki=floats('ki', v['ki'], 6),
            kd=floats('kd', v['kd'], 6),
            integral_limit=floats('integral_limit', v['integral_limit'], 6, finite=False),
            tau_max=floats('tau_max', v['tau_max'], 6, finite=False),
            d_lin=floats('vehicle.d_lin', v['vehicle.d_lin'], 6),
            d_quad=floats('vehicle.d_quad', v['vehicle.d_quad'], 6),
            inertia=tuple(a + b for a, b in zip(rigid, added)), level_gain=v['level_gain'],
            derivative_filter=v['derivative_filter'])
        controller.validate()
        pilot: dict[str, Any] = {}
        if 'pilot.mode' in v:   # the pilot modes' parameters (optional for a bare loop)
            if v['pilot.mode'] not in MODES:
                raise ValueError(f'pilot.mode: {v["pilot.mode"]!r} is not one of '
                                 f'{", ".join(MODES)}')
            depth = DepthHoldSettings(
                v['depth_hold.gain'], v['depth_hold.max_climb'], v['depth_hold.deadband'],
                v['depth_hold.integral_gain'], v['depth_hold.integral_limit'],
                v['depth_hold.stop_time'])
            heading = HeadingHoldSettings(
                v['heading_hold.gain'], v['heading_hold.max_rate'],
                v['heading_hold.deadband'], v['heading_hold.settle_rate'],
                v['heading_hold.settle_time'])
            estimator = DepthEstimatorSettings(
                v['depth_estimator.accel_noise'], v['depth_estimator.bias_walk'],
                v['depth_estimator.initial_bias_std'], v['max_gap'])
            for part, prefix in ((depth, 'depth_hold.'), (heading, 'heading_hold.'),
                                 (estimator, 'depth_estimator.')):
                try:
                    part.validate()
                except ValueError as err:
                    raise ValueError(f'{prefix}{err}') from err
            pilot = {'pilot_mode': v['pilot.mode'],
                     'full_stick': floats('pilot.full_stick', v['pilot.full_stick'], 6),
                     'depth_timeout': v['pilot.depth_timeout'], 'depth_hold': depth,
                     'heading_hold': heading, 'depth_estimator': estimator,
                     'climb_rate': v['failsafe.climb_rate']}
        return cls(controller=controller,
                   reference_time_constant=floats(
                       'reference_time_constant', v['reference_time_constant'], 6),
                   max_accel=floats('max_accel', v['max_accel'], 6),
                   goal_timeout=v['goal_timeout'], max_gap=v['max_gap'],
                   max_future=v['max_future'], velocity_topic=v['velocity_topic'], **pilot)

    def check_rates(self, imu_period: float | None, goal_period: float | None) -> None:
        """Raise ValueError when a tolerance is too short for a measured input period [s]."""
        for problem in (
                too_short_for_rate('max_gap', self.max_gap, 'imu/data', imu_period,
                                   'every lost sample, or every sample, would count as a gap'),
                too_short_for_rate('goal_timeout', self.goal_timeout, 'trajectory_request',
                                   goal_period, 'the goal would count as zero between goals'),
                future_tolerance_problem(self.max_future, imu_period, 'imu/data')):
            if problem:
                raise ValueError(problem)


class VelocityControlNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'velocity_control', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.controller: VelocityController | None = None
        self.reference: VelocityReference | None = None
        self.output = None
        self._goal = np.zeros(6)
        self._goal_ns: int | None = None
        self._last_ns: int | None = None
        self._linear = np.full(3, math.nan)
        self.rejected = 0
        self.health = InputHealth()
        self.imu_gate = StampGate()
        self.goal_gate = StampGate()
        self.imu_period = IntervalMeter()
        self.goal_period = IntervalMeter()
        self.settings: VelocityControlNodeSettings
        self.modes: PilotModes | None = None
        self.depth_hold: DepthHold | None = None
        self.heading_hold: HeadingHold | None = None
        self.depth_estimator: DepthEstimator | None = None
        self._depth_ns: int | None = None    # stamp of the last depth taken
        self.last_reason = ''
        self._was_manual = False
        # The failsafes' action (control.failsafe_node): only a change costs anything here.
        self.failsafe = NONE
        self._neutral = False
        self._surface_goal: np.ndarray | None = None
        self.bind_settings(SPECS, self._build, self._apply)
        self._pub = self.create_topic_publisher(topics.FORCE_COMMAND)
        self._mode_pub = self.create_topic_publisher(topics.PILOT_MODE)
        self._reason_pub = self.create_topic_publisher(topics.PILOT_MODE_REASON)
        self.create_topic_subscription(topics.TRAJECTORY_REQUEST, self._on_goal)
        self.create_topic_subscription(topics.IMU, self._on_imu)
        self.create_topic_subscription(topics.DEPTH, self._on_depth)
        self.create_topic_subscription(topics.IO_REQUEST, self._on_io)
        self.create_topic_subscription(topics.FAILSAFE_ACTION, self._on_failsafe)

    def start(self) -> None:
        """Start, and say the pilot mode (latched: a console that joins later learns it)."""
        super().start()
        self._publish_mode()
        self.create_periodic(REPORT_PERIOD, self._report)
        velocity_topic = self.settings.velocity_topic
        if velocity_topic:
            self.create_topic_subscription(TopicSpec(
                velocity_topic, Odometry, topics.SENSOR_QOS, 'm/s', topics.BODY_FRAME,
                'linear body velocity source'), self._on_velocity)

    def _apply(self, settings: VelocityControlNodeSettings) -> None:
        self.settings = settings
        if self.controller is None:
            self.controller = VelocityController(settings.controller)
            # a depth hold that falls back to stabilize keeps the heave force it had learnt
            self.controller.freeze_lost_integral = True
        else:
            self.controller.settings = settings.controller
        reference = VelocityReference(settings.reference_time_constant, settings.max_accel)
        if self.reference is not None:  # keep the trajectory in progress: no jump
            reference.nu_ref = self.reference.nu_ref
        self.reference = reference
        if self.modes is None:
            self.modes = PilotModes(settings.pilot_mode, settings.depth_timeout)
        self.modes.depth_timeout = settings.depth_timeout
        if self.depth_hold is None or self.heading_hold is None:
            self.depth_hold = DepthHold(settings.depth_hold)
            self.heading_hold = HeadingHold(settings.heading_hold)
        else:   # new gains: the targets held and the integral stay (bumpless)
            self.depth_hold.settings = settings.depth_hold
            self.heading_hold.settings = settings.heading_hold
        if self.depth_estimator is None:
            self.depth_estimator = DepthEstimator(settings.depth_estimator)
        else:
            self.depth_estimator.settings = settings.depth_estimator
        self._goal_timeout_ns = int(settings.goal_timeout * 1e9)
        self._max_gap_ns = int(settings.max_gap * 1e9)
        self.imu_gate.policy = self.goal_gate.policy = StampPolicy(settings.max_future)

    def _build(self, v: Mapping[str, Any]) -> VelocityControlNodeSettings:
        settings = VelocityControlNodeSettings.from_params(v)
        settings.check_rates(self.imu_period.period, self.goal_period.period)
        return settings

    def _now(self) -> int:
        return self.now_ns()

    def _on_goal(self, msg: TwistStamped) -> None:
        nu = convert.twist_to_nu(msg.twist)
        if not convert.all_finite(nu):
            self.health.refused('trajectory_request', 'non_finite')
            return
        t = convert.stamp_to_ns(msg.header.stamp)
        verdict = self.goal_gate.offer(t, self._now())
        if verdict is not StampVerdict.ACCEPTED:
            self.health.refused('trajectory_request', verdict.value)
            return
        self.health.accepted('trajectory_request')
        self.goal_period.add(t)
        self._goal, self._goal_ns = nu, t

    def _on_depth(self, msg: PoseWithCovarianceStamped) -> None:
        assert self.depth_estimator is not None
        t = convert.stamp_to_ns(msg.header.stamp)
        if self._depth_ns is not None and t <= self._depth_ns:
            self.health.refused('depth', 'not_newer')
            return
        depth, variance = -msg.pose.pose.position.z, msg.pose.covariance[14]
        if not self.depth_estimator.update(depth, variance, t):
            self.health.refused('depth', 'non_finite')
            return
        self.health.accepted('depth')
        self._depth_ns = t

    def depth_age(self, now_ns: int) -> float | None:
        """Age of the last depth taken at ``now_ns`` [s]; None when none was."""
        return None if self._depth_ns is None else (now_ns - self._depth_ns) * 1e-9

    def _on_io(self, msg: Parameter) -> None:
        if msg.name != EXECUTOR:
            return   # another executor's request
        assert self.modes is not None
        mode = msg.value.string_value
        if self.failsafe in FORCING:
            self._say(f'{mode!r} refused: failsafe {self.failsafe} active', warn=True)
            self._publish_mode()
            return
        before = self.modes.mode
        # The depth's age on the loop's time line (the IMU's stamps), as the fallback sees it
        now = self._last_ns if self._last_ns is not None else self.now_ns()
        out = self.modes.request(mode, self.depth_age(now),
                                 manual_problem(self.settings.controller.tau_max))
        if out.reason:
            self._say(out.reason, warn=True)
        elif out.changed:
            self.get_logger().info(f'pilot mode {before} -> {out.mode}')
            self._entered(out.mode)
        self._publish_mode()

    def _on_failsafe(self, msg: String) -> None:
        """Apply the failsafes' action: force a mode and goal, or neutral thrusters."""
        action = msg.data
        if action == self.failsafe:
            return
        assert self.modes is not None
        self.failsafe = action
        self._neutral = action == NEUTRAL
        self._surface_goal = None
        mode = self.modes.mode
        if action == SURFACE:
            # Depth hold climbs at a set rate from the depth sensor; without a fresh depth,
            # stabilize climbs on the feed-forward. The heading is held either way.
            now = self._last_ns if self._last_ns is not None else self.now_ns()
            depth_ok = self.modes.depth_problem(self.depth_age(now)) is None
            mode = DEPTH_HOLD if depth_ok else STABILIZE
            goal = np.zeros(6)
            goal[2] = self.settings.climb_rate   # depth hold: the climb rate it asks for
            self._surface_goal = goal
        elif action == FS_STABILIZE and mode == DEPTH_HOLD:
            mode = STABILIZE
        elif action == FS_MANUAL and manual_problem(self.settings.controller.tau_max) is None:
            mode = MANUAL
        if mode != self.modes.mode:
            before, self.modes.mode = self.modes.mode, mode
            self._say(f'{before} -> {mode}: failsafe {action}', warn=True)
            self._entered(mode)
        else:   # one call site, one severity (rclpy's logger refuses a change)
            self._say(f'failsafe {action}' if action != NONE
                      else 'failsafe cleared: the pilot has the modes again', warn=True)
        self._publish_mode()

    def _entered(self, mode: str) -> None:
        """Start a mode from where the vehicle is (bumpless): the holds take their targets."""
        assert self.depth_hold is not None and self.heading_hold is not None
        self.depth_hold.release()
        self.heading_hold.target = None
        if mode != MANUAL and self.controller is not None and self._was_manual:
            self.controller.reset()
        self._was_manual = mode == MANUAL

    def _say(self, reason: str, warn: bool) -> None:
        self.last_reason = reason
        (self.get_logger().warn if warn else self.get_logger().info)(reason)
        out = String()
        out.data = reason
        self._reason_pub.publish(out)

    def _publish_mode(self) -> None:
        if self.modes is None:
            return
        out = String()
        out.data = self.modes.mode
        self._mode_pub.publish(out)

    def _on_velocity(self, msg: Odometry) -> None:
        v = convert.vector3_to_array(msg.twist.twist.linear)
        if convert.all_finite(v):
            self._linear = v

    def _on_imu(self, msg: Imu) -> None:
        t = convert.stamp_to_ns(msg.header.stamp)
        # The time policy: early, repeated or out-of-order stamps are dropped, the state kept.
        verdict = self.imu_gate.offer(t, self._now())
        if verdict is not StampVerdict.ACCEPTED:
            self.rejected += 1
            self.health.refused('imu/data', verdict.value)
            return
        self.imu_period.add(t)
        last, self._last_ns = self._last_ns, t
        if last is None or not 0 < t - last <= self._max_gap_ns:
            # The first sample, a gap, or the clock went back (the gate started over).
            if last is not None:
                self.health.refused('imu/data', 'gap')
                self.health.reset('integrator')
            self.controller.reset()
            self.reference.reset()
            return
        self.health.accepted('imu/data')
        # The goal's age on the IMU's time line (both stamped by the same ROS clock).
        goal = self._goal if (self._goal_ns is not None
                              and t - self._goal_ns <= self._goal_timeout_ns) else np.zeros(6)
        omega = convert.vector3_to_array(msg.angular_velocity)
        q = convert.quaternion_to_array(msg.orientation)
        roll, pitch, yaw = quat_to_euler(q)
        nu = np.concatenate((self._linear, omega))
        dt = (t - last) * 1e-9
        if self._surface_goal is not None:
            goal = self._surface_goal
        tau = self._pilot(t, dt, goal, nu, q, roll, pitch, yaw,
                          convert.vector3_to_array(msg.linear_acceleration))
        if self._neutral:   # thrusters neutral from the next sample on (ArduSub's disarm)
            self.controller.reset()
            tau = np.zeros(6)
        w = new(WrenchStamped)
        w.header.stamp = msg.header.stamp
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench(w.wrench, tau)
        self._pub.publish(w)

    def _pilot(self, t: int, dt: float, goal: np.ndarray, nu: np.ndarray, q: np.ndarray,
               roll: float, pitch: float, yaw: float, specific_force: np.ndarray) -> np.ndarray:
        """Return the force of the pilot mode (``control.pilot_modes``) for one IMU sample."""
        assert self.modes is not None and self.depth_estimator is not None
        assert self.depth_hold is not None and self.heading_hold is not None
        s = self.settings
        # Only once a depth has started the estimator: a vehicle without a depth sensor pays
        # nothing per IMU sample for it.
        if self.depth_estimator.started and convert.all_finite(specific_force) \
                and convert.all_finite(q):
            up = float((quat_to_rotmat(q) @ specific_force)[2]) - G
            self.depth_estimator.predict(up, t)
        fallback = self.modes.check(self.depth_age(t))
        if fallback.changed:
            self._say(fallback.reason, warn=True)
            self._entered(fallback.mode)
            self._publish_mode()
        mode = self.modes.mode
        nu_ref, nu_ref_dot = self.reference.step(goal, dt)
        if mode in (STABILIZE, DEPTH_HOLD):   # the holds overwrite axes: not the model's own
            nu_ref, nu_ref_dot = nu_ref.copy(), nu_ref_dot.copy()
        if mode == MANUAL:
            self.output = None
            return np.array(manual_force(tuple(goal.tolist()), s.full_stick,
                                         s.controller.tau_max))
        if mode in (STABILIZE, DEPTH_HOLD):
            nu_ref[5] = self.heading_hold.step(goal[5] / s.heading_hold.max_rate, yaw,
                                               float(nu[5]), dt)
            nu_ref_dot[5] = 0.0
        if mode == DEPTH_HOLD:
            z = -self.depth_estimator.depth
            nu_ref[2] = self.depth_hold.step(goal[2] / s.depth_hold.max_climb, z, dt,
                                             self.depth_estimator.vertical_velocity)
            nu_ref_dot[2] = self.depth_hold.goal_accel   # a stop's deceleration, else 0
            nu = nu.copy()
            nu[2] = self.depth_estimator.vertical_velocity  # level: body heave ~ world w
        if mode in (STABILIZE, DEPTH_HOLD):
            # The reference model carries on from the holds' goals, so leaving a hold (or a
            # fallback) moves the goal on smoothly from there instead of stepping it.
            self.reference.nu_ref, self.reference.nu_ref_dot = nu_ref, nu_ref_dot
        self.output = self.controller.step(nu_ref, nu, dt, nu_d_dot=nu_ref_dot, roll=roll,
                                           pitch=pitch)
        return self.output.tau

    def _report(self) -> None:
        level, message, values = self.health.report(REPORT_PERIOD)
        try:
            self.settings.check_rates(self.imu_period.period, self.goal_period.period)
        except ValueError as err:  # a start value the measured rates show to be wrong
            level, message = worst((level, message), (ERROR, str(err)))
        modes = self.modes
        pilot = {} if modes is None else {
            'pilot_mode': modes.mode, 'pilot_refused': modes.refused,
            'pilot_fallbacks': modes.fallbacks, 'pilot_reason': self.last_reason or 'none',
            'depth': 'none' if self.depth_estimator is None or not self.depth_estimator.started
            else f'{self.depth_estimator.depth:.3f}'}
        self.publish_diagnostics(level, message, {'rejected': self.rejected, **pilot,
                                                  **values})
