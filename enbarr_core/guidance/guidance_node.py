"""Guidance node: ``observer/odometry`` + ``mode`` (+ ``obstacles``) -> ``guidance/reference``.

The guidance block of the manual's graph (observer -> guidance -> controller -> allocation).
It follows the operator mode the controller publishes (``mode``, latched): entering
automatic it holds the pose of the latest estimate (:class:`HoldPose`); entering guidance it
goes to the waypoint when ``path.waypoints`` holds one (:class:`GoToWaypoint`), else follows
the path with line of sight (:class:`LosPath`); in manual it publishes nothing. On every
estimate outside manual it publishes the reference for that estimate on
``guidance/reference`` (a one-point ``MultiDOFJointTrajectory``, see ``reference_to_msg``),
stamped with the estimate's stamp. It announces on ``guidance/path_available`` (latched)
whether it has a path, which the controller needs to refuse guidance without one.

Collision avoidance (``avoidance.*``, off by default): the law's reference goes through the
control-barrier-function safety filter of ``guidance.cbf`` with the latest ``obstacles``
(carried along their velocities from their stamp to the estimate's), and what it did goes out
on ``guidance/avoidance`` (``enbarr_interfaces.avoidance``). Blind (no obstacles message, its
stamp older than ``avoidance.staleness`` against the estimate's, or
``observer/measurement_age`` above it: lidar unplugged or stalled, pose lost) the node holds
the pose of the estimate it was at, with the reason in the log and on ``/diagnostics``, and
the law's clock stops; fresh again, the law resumes and the filter starts from the hold. In
manual nothing is published, avoidance or not: the operator always has the vessel. With
``avoidance.level`` force the barrier functions act on the DP controller's force instead
(``control.dp_control_node``): this node then passes the law's reference through unfiltered
but keeps every other safeguard (the blind hold and its reasons, ``guidance/avoidance``).

Another guidance law replaces this node with one ``plugin:`` line of the profile, as long as
it speaks the same three topics.

Time (``framework.stamps``): an estimate stamped more than ``max_future`` ahead of
the clock, or not later than the last one taken, is refused and counted: it neither becomes
the law's dt nor the stamp of a reference. More than 5 % refused in a second makes the node
DEGRADED on ``/diagnostics``; ``max_future`` must stay under the measured estimate period.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import time
from typing import Any

from geometry_msgs.msg import Transform, Twist
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Bool, Float64, String
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from enbarr_interfaces import avoidance, convert, topics
from enbarr_interfaces.obstacles import cloud_stamp_ns, from_cloud, ObstacleEncodingError
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces.links import LinkPublisher
from enbarr_interfaces.modes import Mode
from enbarr_core.framework.health import (
    DEGRADED, future_tolerance_problem, InputHealth, IntervalMeter, OK, worst)
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import StampGate, StampPolicy
from enbarr_core.guidance.cbf import (
    blind_reason, CbfOutput, CbfSettings, obstacle_lists, SafetyFilter)
from enbarr_core.guidance import avoidance_params
from enbarr_core.guidance.guidance import GoToWaypoint, HoldPose, LosPath, Reference


SPECS = [
    ParamSpec('path.waypoints', [0.0], 'Guidance: x, y of one waypoint to go to, or x0, y0, '
              'x1, y1, ... of a path to follow (odom); [0.0]: none', 'm', -1e6, 1e6),
    ParamSpec('path.speed', 0.2, 'Reference speed along the path', 'm/s', 1e-3, 10.0),
    ParamSpec('path.accel', 0.05, 'Acceleration limit when going to a single waypoint',
              'm/s^2', 1e-4, 10.0),
    ParamSpec('path.lookahead', 0.5, 'Line-of-sight lookahead distance', 'm', 1e-3, 100.0),
    ParamSpec('path.acceptance_radius', 0.1, 'Waypoint acceptance radius', 'm', 1e-3, 100.0),
    ParamSpec('max_future', 0.01, 'Estimates stamped further ahead of the clock than this are '
              "refused (at least the observer's)", 's', 0.0, 0.5),
    ParamSpec('path.heading', 'fixed', 'Heading along the path: fixed (keep the heading held '
              'when guidance starts) or course (face the direction of travel)'),
    # Collision avoidance (guidance.cbf): off unless the profile turns it on.
    avoidance_params.ENABLED, avoidance_params.LEVEL, avoidance_params.SAFETY_RADIUS,
    avoidance_params.VESSEL_RADIUS,
    ParamSpec('avoidance.tracking_margin', 0.2, 'How far the vessel may lag the desired '
              'position: added to the zone the desired position keeps out of', 'm', 0.0, 10.0),
    ParamSpec('avoidance.gamma', 0.5, 'Barrier decay rate: dB/dt >= -gamma B', '1/s', 0.01,
              10.0),
    ParamSpec('avoidance.max_speed', 0.3, 'Speed limit of the desired position (above '
              'path.speed / cos(pi/16), so that the nominal speed passes unchanged)', 'm/s',
              0.01, 10.0),
    ParamSpec('avoidance.staleness', 0.5, 'Obstacles older than this against the estimate, or '
              'no pose for this long: stop and hold', 's', 0.02, 10.0),
    ParamSpec('avoidance.pull_gain', 0.5, 'Rate at which the desired position returns to the '
              "law's reference", '1/s', 0.01, 10.0),
    ParamSpec('avoidance.pass_gain', 1.0, 'Tangential speed along a blocking obstacle per unit '
              'of speed lost to it (0: stop in front of it)', '', 0.0, 10.0),
]

#: The one joint of a reference trajectory: the vessel's body.
REFERENCE_JOINT = topics.BODY_FRAME


def reference_to_msg(ref: Reference, header: Any) -> MultiDOFJointTrajectory:
    """Build the ``guidance/reference`` message of ``ref`` for the estimate of ``header``.

    One point of joint ``base_link``, stamped with the estimate's stamp, in ``odom``:
    ``transforms[0]`` = eta_d (x, y [m], yaw quaternion), ``velocities[0]`` = nu_d (body frame
    [m/s, rad/s], as Odometry's twist), ``accelerations[0]`` = nu_d_dot [m/s^2, rad/s^2]. A
    pose component that is not fed back (``position_mask`` False) is NaN in the transform
    (all four quaternion components for yaw): there is no position reference for that DOF.
    """
    # Built with ``fastmsg.new`` (once per estimate: the generated constructors of these five
    # messages cost more than the guidance law).
    pose, velocity, acceleration = new(Transform), new(Twist), new(Twist)
    convert.set_transform_eta(pose, [float(v) if used else math.nan
                                     for v, used in zip(ref.eta_d, ref.position_mask)])
    convert.set_twist_nu3(velocity, ref.nu_d)
    convert.set_twist_nu3(acceleration, ref.nu_d_dot)
    point = new(MultiDOFJointTrajectoryPoint)
    point.transforms, point.velocities = [pose], [velocity]
    point.accelerations = [acceleration]
    out = new(MultiDOFJointTrajectory)
    out.joint_names, out.points = [REFERENCE_JOINT], [point]
    out.header.stamp = header.stamp
    out.header.frame_id = topics.WORLD_FRAME
    return out


def msg_to_reference(msg: MultiDOFJointTrajectory) -> Reference:
    """Read a ``guidance/reference`` message (see ``reference_to_msg``).

    A NaN pose component is a DOF that is not fed back (mask False, eta_d NaN there).
    ValueError when the message is not one point of ``base_link`` with one transform, one
    velocity and one acceleration.
    """
    if list(msg.joint_names) != [REFERENCE_JOINT] or len(msg.points) != 1:
        raise ValueError(f'guidance/reference: expected one point of joint {REFERENCE_JOINT!r}, '
                         f'got joints {list(msg.joint_names)} and {len(msg.points)} points')
    point = msg.points[0]
    if not (len(point.transforms) == len(point.velocities) == len(point.accelerations) == 1):
        raise ValueError('guidance/reference: expected one transform, velocity and '
                         'acceleration in the point')
    eta_d = convert.transform_to_eta(point.transforms[0])
    mask = tuple(not math.isnan(v) for v in eta_d)
    return Reference(eta_d, convert.twist_to_nu3(point.velocities[0]),
                     convert.twist_to_nu3(point.accelerations[0]),
                     mask)  # type: ignore[arg-type]


@dataclass(frozen=True)
class AvoidanceSettings:
    """The ``avoidance.*`` parameters (see ``SPECS``)."""

    enabled: bool
    staleness: float            # obstacles or pose older than this: blind [s]
    cbf: CbfSettings
    level: str = 'guidance'     # avoidance_params.AVOIDANCE_LEVELS: 'force' filters nothing here

    @property
    def filters(self) -> bool:
        """Whether this node's safety filter changes the reference."""
        return self.enabled and self.level == 'guidance'

    @classmethod
    def from_params(cls, v: Mapping[str, Any], path_speed: float) -> AvoidanceSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        cbf = CbfSettings(
            safety_radius=v['avoidance.safety_radius'],
            vessel_radius=v['avoidance.vessel_radius'],
            tracking_margin=v['avoidance.tracking_margin'], gamma=v['avoidance.gamma'],
            max_speed=v['avoidance.max_speed'], pull_gain=v['avoidance.pull_gain'],
            pass_gain=v['avoidance.pass_gain'])
        try:
            cbf.validate()
        except ValueError as err:
            raise ValueError(f'avoidance.{err}') from err
        enabled = bool(v['avoidance.enabled'])
        level = avoidance_params.level_of(v)
        if enabled and cbf.vessel_radius <= 0.0:
            raise ValueError('avoidance.vessel_radius: give the hull radius (> 0) to enable '
                             'avoidance')
        if enabled and level == 'guidance' and path_speed > cbf.identity_speed:
            raise ValueError(f'avoidance.max_speed: {cbf.max_speed} m/s would slow the path '
                             f'speed {path_speed} m/s everywhere (need path.speed <= '
                             f'max_speed cos(pi/16))')
        return cls(enabled, float(v['avoidance.staleness']), cbf, level)


@dataclass(frozen=True)
class GuidanceSettings:
    """Settings of ``GuidanceNode`` (see ``SPECS``)."""

    waypoints: tuple[tuple[float, float], ...]  # () none, one: go to it, more: a path [m]
    speed: float               # reference speed [m/s]
    accel: float               # acceleration limit to a single waypoint [m/s^2]
    lookahead: float           # line-of-sight lookahead [m]
    acceptance_radius: float   # waypoint acceptance radius [m]
    heading: str               # 'fixed' or 'course'
    max_future: float = 0.01   # estimates stamped further ahead of the clock are refused [s]
    avoidance: AvoidanceSettings = AvoidanceSettings(False, 0.5, CbfSettings())

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> GuidanceSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if v['path.heading'] not in ('fixed', 'course'):  # checked with or without a path
            raise ValueError(f'path.heading: expected fixed or course, got '
                             f'{v["path.heading"]!r}')
        w = list(v['path.waypoints'])
        waypoints: list[tuple[float, float]] = []
        if w != [0.0]:
            if len(w) % 2 or len(w) < 2:
                raise ValueError('path.waypoints: expected x, y of a waypoint or x0, y0, x1, '
                                 'y1, ... of a path')
            waypoints = [(float(x), float(y)) for x, y in zip(w[::2], w[1::2])]
        s = cls(tuple(waypoints), v['path.speed'], v['path.accel'], v['path.lookahead'],
                v['path.acceptance_radius'], v['path.heading'], v['max_future'],
                AvoidanceSettings.from_params(v, v['path.speed']))
        if len(waypoints) > 1:  # a path: check it now (a single waypoint is checked on use)
            try:
                s.path_law()
            except ValueError as err:
                raise ValueError(f'path: {err}') from err
        return s

    def rate_problem(self, estimate_period: float | None) -> str | None:
        """Why these settings do not fit estimates every ``estimate_period`` [s] (or None)."""
        return future_tolerance_problem(self.max_future, estimate_period,
                                        topics.OBSERVER_ODOMETRY.name)

    def path_law(self) -> LosPath:
        """Line-of-sight following of the path (two or more waypoints)."""
        return LosPath(self.waypoints, self.speed, self.lookahead, self.acceptance_radius,
                       heading=self.heading)


class GuidanceNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'guidance', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: GuidanceSettings
        self.mode = Mode.MANUAL
        self.law: HoldPose | GoToWaypoint | LosPath | None = None
        self.reference: Reference | None = None
        self.failures = 0
        self._eta: np.ndarray | None = None
        self._last_ns: int | None = None
        self.health = InputHealth()
        self.estimate_period = IntervalMeter()
        self._gate = StampGate()
        # Collision avoidance: the latest obstacles (rows at their stamp), the observer's
        # measurement age, the filter, and the hold taken while blind.
        self.filter: SafetyFilter | None = None
        # (rows, stamp of their scan): one object, swapped whole, because the obstacles
        # arrive on another thread than the estimates that read them.
        # The obstacles as rows of floats (cbf.obstacle_lists): the filter reads them as
        # floats at every estimate, and they change only once a scan.
        self._obstacles: tuple[list[list[float]], int | None] = ([], None)
        self._measurement_age: float | None = None
        self.blind: HoldPose | None = None
        self.blind_reason: str | None = None
        self.avoidance_output: CbfOutput | None = None
        self.counts = {'blind': 0, 'infeasible': 0, 'qp_solves': 0, 'obstacles_refused': 0}
        self._ref_pub = self.create_topic_publisher(topics.GUIDANCE_REFERENCE)
        self._avoid_pub = self.create_topic_publisher(topics.GUIDANCE_AVOIDANCE)
        self._path_pub = self.create_topic_publisher(topics.GUIDANCE_PATH_AVAILABLE)
        self.bind_settings(SPECS, self._build, self._apply)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_estimate)
        self.create_topic_subscription(topics.MODE, self._on_mode)
        self.create_topic_subscription(topics.OBSTACLES, self._on_obstacles)
        self.create_topic_subscription(topics.OBSERVER_AGE, self._on_measurement_age)
        self.create_periodic(1.0, self._report)

    def _build(self, v: Mapping[str, Any]) -> GuidanceSettings:
        """Build the settings and refuse those that do not fit the measured estimate period."""
        settings = GuidanceSettings.from_params(v)
        problem = settings.rate_problem(self.estimate_period.period)
        if problem:
            raise ValueError(problem)
        return settings

    def _apply(self, settings: GuidanceSettings) -> None:
        self._gate.policy = StampPolicy(max_future=settings.max_future)
        self.settings = settings
        if self.filter is not None:   # live: the state (p_d, engaged) is kept
            self.filter.settings = settings.avoidance.cbf
        if not settings.avoidance.enabled:
            self.blind = self.blind_reason = None
        if self.started:  # the first value goes out at start: constructing publishes nothing
            self._publish_path_available()

    def _publish_path_available(self) -> None:
        self._path_pub.publish(Bool(data=bool(self.settings.waypoints)))

    def start(self) -> None:
        """Announce whether a path is set (latched), then run."""
        super().start()
        self._publish_path_available()

    def _on_mode(self, msg: String) -> None:
        try:
            mode = Mode(msg.data)
        except ValueError:
            self.get_logger().warn(f'unknown mode {msg.data!r} ignored')
            return
        if mode is self.mode:
            return
        self.mode, self.law = mode, None
        self.blind = self.blind_reason = None
        self.filter = SafetyFilter(self.settings.avoidance.cbf)
        if mode is Mode.MANUAL:
            return
        if self._eta is None:
            self.failures += 1
            self.get_logger().error(f'{mode.value}: no estimate yet, no reference')
            return
        s = self.settings
        try:
            if mode is Mode.AUTOMATIC:
                self.law = HoldPose(self._eta)
            elif len(s.waypoints) == 1:  # go to the waypoint, heading held
                self.law = GoToWaypoint(self._eta, s.waypoints[0], s.speed, s.accel,
                                        arrival_radius=s.acceptance_radius)
            elif s.waypoints:
                self.law = s.path_law()
            else:
                self.failures += 1
                self.get_logger().error('guidance: no path configured, no reference')
        except ValueError as err:
            self.failures += 1
            self.get_logger().error(f'{mode.value}: {err}')

    def _on_estimate(self, msg: Odometry) -> None:
        t = self.admit_stamp('observer/odometry', msg.header.stamp, self._gate, self.health)
        if t is None:
            return
        self.estimate_period.add(t)
        last, self._last_ns = self._last_ns, t
        self._eta = eta = convert.pose_to_eta(msg.pose.pose)
        if self.law is None or last is None:
            return
        dt = (t - last) * 1e-9
        if self.settings.avoidance.enabled and self.filter is not None:
            ref = self._avoid(eta, t, dt)
        else:
            ref = self.law.reference(eta, dt)
        self.reference = ref
        self._ref_pub.publish(reference_to_msg(ref, msg.header))

    def _avoid(self, eta: np.ndarray, t: int, dt: float) -> Reference:
        """Filter the law's reference (a hold at the estimate while blind)."""
        assert self.law is not None and self.filter is not None
        av = self.settings.avoidance
        rows, obstacles_ns = self._obstacles
        reason = blind_reason(t, obstacles_ns, self._measurement_age, av.staleness)
        if reason is not None:
            if self.blind is None:   # the law's clock stops: it resumes where it was
                self.blind = HoldPose(eta)
                self.counts['blind'] += 1
                self.get_logger().warn(f'collision avoidance blind, holding: {reason}')
            self.blind_reason = reason
            ref = self.blind.reference(eta, dt)
            self.avoidance_output = None
            self._publish_avoidance(t, 0.0, None, len(rows), obstacles_ns, blind=True)
            return ref
        if self.blind is not None:
            self.get_logger().info('collision avoidance sees again: resuming')
            self.filter.engage_at(np.array(self.blind.eta[:2]))   # from the hold, no step
            self.blind = self.blind_reason = None
        nominal = self.law.reference(eta, dt)
        assert obstacles_ns is not None   # else blind
        if not av.filters:   # the force level: the DP controller filters its force
            self.avoidance_output = None
            self._publish_avoidance(t, 0.0, None, len(rows), obstacles_ns, blind=False)
            return nominal
        start = time.perf_counter()
        # The obstacles carried to the estimate's time inside the step (cbf.moved).
        out = self.filter.step(eta, nominal, rows, dt, age=(t - obstacles_ns) * 1e-9)
        elapsed = time.perf_counter() - start
        self.avoidance_output = out
        self.counts['qp_solves'] += out.solved
        if out.infeasible:
            self.counts['infeasible'] += 1
            self.get_logger().warn(f'collision avoidance: {out.reason}',
                                   throttle_duration_sec=1.0)
        self._publish_avoidance(t, elapsed, out, len(rows), obstacles_ns, blind=False)
        return out.reference

    def _publish_avoidance(self, t: int, elapsed: float, out: CbfOutput | None, count: int,
                           obstacles_ns: int | None, *, blind: bool) -> None:
        if isinstance(self._avoid_pub, LinkPublisher) and not self._avoid_pub.has_readers():
            return   # one message per estimate: not built for nobody
        values = {'solve_time': elapsed, 'active': out.active if out else 0,
                  'infeasible': float(bool(out and out.infeasible)),
                  'min_barrier': out.min_barrier if out else math.nan,
                  'engaged': float(bool(out and out.engaged)), 'blind': float(blind),
                  'obstacles': count}
        self._avoid_pub.publish(avoidance.to_msg(values, t, obstacles_ns))

    def _on_obstacles(self, msg: PointCloud2) -> None:
        try:
            obstacles = from_cloud(msg)
        except ObstacleEncodingError as err:   # kept stale: avoidance then holds
            self.counts['obstacles_refused'] += 1
            self.get_logger().warn(str(err), throttle_duration_sec=1.0)
            return
        self._obstacles = (obstacle_lists(obstacles), cloud_stamp_ns(msg))

    def _on_measurement_age(self, msg: Float64) -> None:
        self._measurement_age = float(msg.data)

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``; closes the input-health window."""
        ref = self.reference
        cross_track = ref.cross_track if ref is not None else None
        own = (DEGRADED, f'{self.mode.value}: {self.failures} failures') if self.failures \
            else (OK, 'ok')
        level, message, totals = self.health.report(1.0)
        problem = self.settings.rate_problem(self.estimate_period.period)
        rates = (OK, 'ok')
        if problem:
            rates = (DEGRADED, problem)
            self.report_problem(f'parameter {problem}')
        avoid = (OK, 'ok')
        if self.blind_reason is not None:
            avoid = (DEGRADED, f'holding: {self.blind_reason}')
        elif self.avoidance_output is not None and self.avoidance_output.infeasible:
            avoid = (DEGRADED, f'avoidance {self.avoidance_output.reason}')
        level, message = worst(own, (level, message), rates, avoid)
        out = self.avoidance_output
        return level, (self.mode.value if level == OK else message), {
            'mode': self.mode.value, 'failures': self.failures,
            'finished': ref is not None and ref.finished,
            'cross_track': 'none' if cross_track is None else cross_track,
            'avoidance': 'on' if self.settings.avoidance.enabled else 'off',
            'avoidance_level': self.settings.avoidance.level,
            'avoidance_blind': self.blind_reason or 'no',
            'avoidance_engaged': bool(out and out.engaged),
            'avoidance_min_barrier': 'none' if out is None else out.min_barrier,
            **{f'avoidance_{k}': v for k, v in self.counts.items()}, **totals}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
