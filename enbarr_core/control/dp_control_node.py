"""DP control node: the operator modes and the DP controller (estimate + reference -> force).

Two things live here, and only these: the DP controller (``control.dp_control``) turning
the observer's estimate (``observer/odometry``, ``observer/bias``) and the guidance reference
(``guidance/reference``, from the guidance node) into ``force_command``; and the operator
modes (``control.modes``) turning ``joy`` into the mode and, in manual, the force.

The modes are kept in the controller node, not in a node of their own, because every one of
their rules acts on the controller: entry into automatic or guidance is bumpless (the
controller's integral is set so that its first output equals the force of the moment, which
only the node that sent that force knows); a stale estimate while automatic (the estimates
arrive here anyway) falls back to manual; and the manual force and the controller's force
leave on ``force_command`` from one publisher, so nothing downstream has to choose between
two force sources. The guidance node only follows the ``mode`` published here.

Mode rules (buttons named in the profile's ``joy.*`` in the layout of its joystick driver,
``enbarr_core.control.joy_layouts``): the sticks command surge, sway and yaw
force in manual; the automatic button holds the pose where the vessel is; the guidance button
follows the path (refused while the guidance node announces no path on
``guidance/path_available``); the manual button returns to manual. Every mode change is
published on ``mode`` (latched) and logged; a refused request is logged with its reason,
which ``/diagnostics`` also carries (``last_refusal``: the operator station shows it).
Losing the joystick (loss rule ``timeout``: no ``joy`` sample for ``joy_timeout``; rule
``connection``, for drivers that publish only on change: ``joy/connected`` False, or no True
heartbeat for ``joy_timeout``; see ``control.modes``), the observer dead-reckoning longer
than ``estimate_max_age`` while automatic, or no reference applied for ``estimate_max_age``
outside manual (no guidance node, or one that cannot make a reference), returns to manual
with zero force.

Ordering: this node owns the modes and switches at once; the guidance node learns the new
mode through the executor while estimates and references travel over the in-process link bus,
so for one or two samples after a change a reference of the previous law can still arrive.
It is applied as it is, with no mode check: outside manual the previous law was hold (the
pose where the vessel was) or the path being followed, and either is continuous with what
was being tracked, so the first samples of the new mode track a reference the vessel is
already on, and the new law takes over on the next estimate. Entry stays bumpless (the
integral is reset to the force of the moment at the switch). In manual a reference is
ignored. A reference is applied with the estimate of the same stamp (kept for a few samples,
whichever of the two arrives first), with dt from the estimate before it; tau is stamped with
it. A malformed reference (not one point of ``base_link``) is counted in ``bad_references``
and dropped.

Collision avoidance at the force level (``avoidance.enabled`` and ``avoidance.level`` force;
the guidance node then leaves its reference unfiltered but still holds while blind): outside
manual, every force the controller computes goes through the high-order control barrier
function filter of ``guidance.force_cbf`` with the latest ``obstacles`` (carried along their
velocities to the estimate's stamp), the controller's vessel model and the thrust box
``avoidance.force_max``. What it did goes out on ``control/avoidance`` (the encoding of
``guidance/avoidance``). When no force in the box keeps every obstacle's condition, the
filter's brake is sent, counted, and the reason is on ``/diagnostics``. Obstacles older than
``avoidance.staleness`` keep being filtered against (carried along their velocities), and
``/diagnostics`` says so: stopping is the guidance node's blind hold, which sees the same
staleness. The manual force is never filtered: the operator always has the vessel.

Gains (3-element diagonals and scalars) and the vessel model come from the profile (they have
no default: a node started without them refuses, naming the parameter), are validated
together and applied live over ``gain_ramp_time``, so the force never jumps.

Hostile input. One joystick at a time (``framework.sources``): while ``joy`` has
more than one publisher every sample is refused and counted as ``contested``, so the
joystick-loss rule applies (manual, zero force after ``joy_timeout``) and ``/diagnostics``
says ERROR naming the publishers. Time (``framework.stamps``): estimates, biases, references
and joystick samples each pass their own gate: stamped more than ``max_future`` ahead of the
clock, or not later than the last one taken, they are refused and counted, so none becomes
the controller's dt or the force's stamp. A ``Joy`` with a zero stamp (a driver that does not
stamp) is timed by its arrival. The force stream stays ordered whatever its source (estimate,
joystick, the clock on a fall-back): a force that answers a sample older than the last force
sent is stamped 1 ns after it, since downstream refuses forces that are not newer. More than
5 % of an input refused in a second makes the node DEGRADED. ``joy_timeout`` and
``estimate_max_age`` must cover two periods of their input, and ``max_future`` stay under
one; values that do not are refused with the measured period (and a start value that breaks
the rule is reported once the period is known).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
import math
import threading
import time
from typing import Any

from geometry_msgs.msg import WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Joy, PointCloud2
from std_msgs.msg import Bool, Float64, String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import avoidance, convert, topics
from enbarr_interfaces.obstacles import cloud_stamp_ns, from_cloud, ObstacleEncodingError

from enbarr_core.control.dp_control import DpControlSettings, DpController
from enbarr_core.control.modes import JoyMapping, ModeManager, Transition
from enbarr_core.control.joy_layouts import INDEX_PARAMETERS, LAYOUTS, mapping_from_params
from enbarr_interfaces.modes import Mode
from enbarr_core.framework.health import (
    DEGRADED, future_tolerance_problem, InputHealth, IntervalMeter, OK, too_short_for_rate,
    worst)
from enbarr_core.framework.node import EnbarrNode, WATCHDOG_PERIOD
from enbarr_core.framework.params import ParamSpec, validate_as_parameters
from enbarr_core.framework.sources import SourceGuard
from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict
from enbarr_core.guidance.cbf import moved, obstacle_rows
from enbarr_core.guidance.force_cbf import ForceCbfSettings, ForceOutput, ForceSafetyFilter
from enbarr_core.guidance import avoidance_params
from enbarr_core.guidance.guidance_node import msg_to_reference
from enbarr_core.models.vessel3dof_params import (
    vector3, VESSEL_PARAMETERS, VESSEL_SPECS, vessel_from_params)

_XYN = '(surge, sway, yaw)'
_ESTIMATES_KEPT = 8  # estimates kept to pair with their reference
SPECS = [
    ParamSpec('kp', [0.0, 0.0, 0.0], f'Proportional gains {_XYN}', 'N/m, N m/rad', 0.0,
              1e4, required=True),
    ParamSpec('ki', [0.0, 0.0, 0.0], f'Integral gains {_XYN}', 'N/(m s), N m/(rad s)',
              0.0, 1e4, required=True),
    ParamSpec('kd', [0.0, 0.0, 0.0], f'Derivative gains {_XYN}', 'N s/m, N m s/rad', 0.0,
              1e4, required=True),
    ParamSpec('integral_limit', [0.0, 0.0, 0.0], f'Integral clamp {_XYN}', 'N, N m',
              0.0, 1e4, required=True),
    ParamSpec('tau_max', [0.0, 0.0, 0.0], f'Force limits {_XYN}', 'N, N m', 0.0, 1e4,
              required=True),
    ParamSpec('gain_ramp_time', 1.0, 'Time a gain change takes to act fully', 's', 0.0, 60.0),
    ParamSpec('bias_feedforward', True, "Cancel the observer's bias estimate"),
    *VESSEL_SPECS,
    ParamSpec('manual_tau_max', [0.0, 0.0, 0.0], f'Force at full stick {_XYN}',
              'N, N m', 0.0, 1e4, required=True),
    ParamSpec('estimate_max_age', 1.5, 'Automatic needs a pose accepted within this time', 's',
              0.01, 60.0),
    ParamSpec('joy_timeout', 0.5, 'No joystick sample (loss rule timeout) or joy/connected '
              'heartbeat (rule connection) for this long: manual, zero force', 's', 0.01, 60.0),
    ParamSpec('max_future', 0.01, 'Estimates, references and joystick samples stamped further '
              "ahead of the clock than this are refused (at least the observer's)", 's',
              0.0, 0.5),
    ParamSpec('joy.layout', '', 'Joystick driver layout: ' + ', '.join(LAYOUTS)
              + ' (empty: the joy.axis_*/joy.button_* indices)', read_only=True),
    *(ParamSpec(f'joy.{dof}', '', f'Axis name for {dof} in joy.layout ({sense}; '
                "'-name' flips it)") for dof, sense in (
        ('surge', 'up = ahead'), ('sway', 'left = port'), ('yaw', 'left = counter-clockwise'))),
    *(ParamSpec(f'joy.{mode}', '', f'Button name to {mode} in joy.layout')
      for mode in ('automatic', 'guidance', 'manual')),
    ParamSpec('joy.loss', '', 'Joystick-loss rule: timeout (no sample for joy_timeout) or '
              "connection (joy/connected heartbeat); empty: the layout's", read_only=True),
    *(ParamSpec(f'joy.{name}', -1, f'Joy index of {name} without joy.layout (-1: unset)', '',
                -1, 64) for name in INDEX_PARAMETERS),
    ParamSpec('joy.deadzone', 0.05, 'Stick dead zone', '', 0.0, 0.99),
    # Collision avoidance at the force level (guidance.force_cbf). enabled, level,
    # safety_radius, vessel_radius and staleness are the guidance node's too: a profile gives
    # them once, in its common parameters.
    avoidance_params.ENABLED, avoidance_params.LEVEL, avoidance_params.SAFETY_RADIUS,
    avoidance_params.VESSEL_RADIUS,
    ParamSpec('avoidance.staleness', 0.5, 'Obstacles older than this against the estimate are '
              'reported stale on /diagnostics', 's', 0.02, 10.0),
    ParamSpec('avoidance.force_max', [2.0, 2.0], 'Force box (surge, sway) the force-level '
              'filter keeps within: what the thrusters give in every direction, at most '
              'tau_max', 'N', 1e-3, 1e4),
    ParamSpec('avoidance.a1', 1.0, 'Force-level barrier: class-K rate of h (psi_1 = '
              'h_dot + a1 h)', '1/s', 0.01, 10.0),
    ParamSpec('avoidance.a2', 1.0, 'Force-level barrier: class-K rate of psi_1 '
              '(psi_1_dot >= -a2 psi_1)', '1/s', 0.01, 10.0),
    ParamSpec('avoidance.pass_gain', 1.0, 'Force-level barrier: tangential force along a '
              'blocking obstacle per unit of force lost to it (0: stop in front of it)', '',
              0.0, 10.0),
]
_PARAMETER = {'Kp': 'kp', 'Ki': 'ki', 'Kd': 'kd', **VESSEL_PARAMETERS}


#: How far back a force's stamp may be and still be stamped after the last one sent [ns].
_REORDER_NS = 1_000_000_000


@dataclass(frozen=True)
class ForceAvoidanceSettings:
    """The force-level collision avoidance of ``DpControlNode`` (``avoidance.*``)."""

    filter: ForceCbfSettings | None   # None: this node does not filter (off, or level guidance)
    staleness: float                  # obstacles older than this: reported stale [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any], control: DpControlSettings
                    ) -> ForceAvoidanceSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        level = avoidance_params.level_of(v)
        staleness = float(v['avoidance.staleness'])
        if not (v['avoidance.enabled'] and level == 'force'):
            return cls(None, staleness)
        box = [float(x) for x in v['avoidance.force_max']]
        if len(box) != 2:
            raise ValueError(f'avoidance.force_max: expected [surge, sway], got {box}')
        for j, (b, limit) in enumerate(zip(box, control.tau_max[:2])):
            if b > limit:
                raise ValueError(f'avoidance.force_max[{j}]: {b} N is more than tau_max[{j}] '
                                 f'{limit} N (the controller never sends it)')
        if v['avoidance.vessel_radius'] <= 0.0:
            raise ValueError('avoidance.vessel_radius: give the hull radius (> 0) to enable '
                             'the force-level avoidance')
        settings = ForceCbfSettings(
            M=tuple(control.M), D=tuple(control.D), Dn=tuple(control.Dn),  # type: ignore
            tau_max=(box[0], box[1], float(control.tau_max[2])),
            safety_radius=float(v['avoidance.safety_radius']),
            vessel_radius=float(v['avoidance.vessel_radius']),
            a1=float(v['avoidance.a1']), a2=float(v['avoidance.a2']),
            pass_gain=float(v['avoidance.pass_gain']))
        try:
            settings.validate()
        except ValueError as err:
            raise ValueError(f'avoidance.{err}') from err
        return cls(settings, staleness)


@dataclass(frozen=True)
class DpControlNodeSettings:
    """Settings of ``DpControlNode`` (see ``SPECS``)."""

    control: DpControlSettings              # gains, limits, model
    mapping: JoyMapping                     # joystick axes and buttons
    loss_rule: str                          # joystick-loss rule (modes.LOSS_RULES)
    manual_tau_max: tuple[float, ...]       # force at full stick [N, N, N m]
    estimate_max_age: float                 # [s]
    joy_timeout: float                      # [s]
    max_future: float                       # [s]
    avoidance: ForceAvoidanceSettings = ForceAvoidanceSettings(None, 0.5)

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> DpControlNodeSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        vessel = vessel_from_params(v)
        control = DpControlSettings(
            Kp=vector3(v, 'kp'), Ki=vector3(v, 'ki'),
            Kd=vector3(v, 'kd'), integral_limit=vector3(v, 'integral_limit'),
            tau_max=vector3(v, 'tau_max'), M=vessel.M, D=vessel.D, Dn=vessel.Dn,
            gain_ramp_time=v['gain_ramp_time'], bias_feedforward=v['bias_feedforward'])
        validate_as_parameters(control, _PARAMETER)
        mapping, loss_rule = mapping_from_params(v, v['joy.deadzone'])
        return cls(control, mapping, loss_rule, vector3(v, 'manual_tau_max'),
                   v['estimate_max_age'], v['joy_timeout'], v['max_future'],
                   ForceAvoidanceSettings.from_params(v, control))

    def rate_problem(self, estimate_period: float | None,
                     joy_period: float | None) -> str | None:
        """Why these settings do not fit the measured input periods [s] (None: fine)."""
        estimates, joy = topics.OBSERVER_ODOMETRY.name, topics.JOY.name
        lost = 'one lost sample would return to manual'
        return (too_short_for_rate('estimate_max_age', self.estimate_max_age, estimates,
                                   estimate_period, lost)
                or too_short_for_rate('joy_timeout', self.joy_timeout, joy, joy_period, lost)
                or future_tolerance_problem(self.max_future, estimate_period, estimates)
                or future_tolerance_problem(self.max_future, joy_period, joy))


@dataclass(frozen=True)
class _Estimate:
    t_ns: int                # stamp
    last_ns: int | None      # stamp of the estimate before it
    eta: np.ndarray
    nu: np.ndarray
    stamp: Any               # the message's stamp, for tau


class DpControlNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'dp_control', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.controller: DpController | None = None
        self.manager: ModeManager | None = None
        self.settings: DpControlNodeSettings
        self.health = InputHealth()
        self.estimate_period = IntervalMeter()  # of the estimates taken
        self.joy_period = IntervalMeter()       # of the joystick samples taken
        self._gates = {name: StampGate() for name in (
            'observer/odometry', 'observer/bias', 'guidance/reference', 'joy')}
        # Force-level avoidance: the filter (None: off), the latest obstacles (rows at their
        # stamp and that stamp, one object swapped whole: they arrive on another thread than
        # the estimates), what the last step did and what the diagnostics window saw.
        self.force_filter: ForceSafetyFilter | None = None
        self._obstacles: tuple[np.ndarray, int | None] = (obstacle_rows(()), None)
        self.force_output: ForceOutput | None = None
        self.force_counts = {'engaged': 0, 'infeasible': 0, 'stale': 0,
                             'obstacles_refused': 0}
        self._force_problem: str | None = None
        self.bind_settings(SPECS, self._build, self._apply)
        self.tau = np.zeros(3)
        self.reference = None
        self.refusals = 0
        self.last_refusal = ''   # '<mode>: <reason>' of the last refused request
        self.bad_references = 0
        self.path_available = False
        self._eta: np.ndarray | None = None
        self._bias = np.zeros(3)
        self._age = math.inf
        self._last_ns: int | None = None
        self._estimate_ns: int | None = None  # node clock when the last estimate arrived
        self._estimates: deque[_Estimate] = deque(maxlen=_ESTIMATES_KEPT)
        self._pending: tuple[int, Any] | None = None  # a reference waiting for its estimate
        self._reference_ns: int | None = None  # node clock at mode entry or last reference
        self._tau_lock = threading.Lock()  # force from the chain thread and the executor's
        self._tau_ns: int | None = None    # stamp of the last force sent
        self._tau_pub = self.create_topic_publisher(topics.FORCE_COMMAND)
        self._mode_pub = self.create_topic_publisher(topics.MODE)
        self._avoid_pub = self.create_topic_publisher(topics.CONTROL_AVOIDANCE)
        self.create_topic_subscription(topics.OBSTACLES, self._on_obstacles)
        self.create_topic_subscription(topics.OBSERVER_AGE, self._on_age)
        self.create_topic_subscription(topics.OBSERVER_BIAS, self._on_bias)
        self.create_topic_subscription(topics.OBSERVER_ODOMETRY, self._on_estimate)
        self.create_topic_subscription(topics.GUIDANCE_REFERENCE, self._on_reference)
        self.create_topic_subscription(topics.GUIDANCE_PATH_AVAILABLE, self._on_path_available)
        # One argument: the EventsExecutor of bringup (rclpy 7.1) passes no MessageInfo.
        self._joy_sub = self.create_topic_subscription(topics.JOY, self._on_joy)
        self.joy_guard = SourceGuard(self, self._joy_sub)
        self.create_topic_subscription(topics.JOY_CONNECTED, self._on_joy_connected)
        self._joy_last: tuple[int, tuple[float, ...], tuple[int, ...]] | None = None
        self.create_periodic(WATCHDOG_PERIOD, self._supervise)
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Announce the starting mode (latched: guidance follows it), then run.

        Not in the constructor: a node built only to be checked, or in a run that the vessel
        guard refuses, must not switch the mode of a vessel already running on the graph.
        """
        super().start()
        self._mode_pub.publish(String(data=self.manager.mode.value))

    def _build(self, v: Mapping[str, Any]) -> DpControlNodeSettings:
        """Build the settings and refuse those that do not fit the measured input periods."""
        settings = DpControlNodeSettings.from_params(v)
        problem = settings.rate_problem(self.estimate_period.period, self.joy_period.period)
        if problem:
            raise ValueError(problem)
        return settings

    def _apply(self, s: DpControlNodeSettings) -> None:
        for gate in self._gates.values():
            gate.policy = StampPolicy(max_future=s.max_future)
        if self.controller is None:
            self.controller = DpController(s.control)
            self.manager = ModeManager(s.mapping, s.manual_tau_max, s.joy_timeout, s.loss_rule)
        else:
            self.controller.settings = s.control  # ramped by the controller
            self.manager.mapping = s.mapping
            self.manager.tau_max = np.asarray(s.manual_tau_max, dtype=float)
            self.manager.joy_timeout = s.joy_timeout
        f = s.avoidance.filter
        if f is None:
            self.force_filter = None
        elif self.force_filter is None:
            self.force_filter = ForceSafetyFilter(f)
        else:   # live: the passing side of an engagement is kept
            self.force_filter.settings = f
        self.settings = s

    @property
    def mode(self) -> Mode:
        """The operator mode now."""
        return self.manager.mode

    def _fresh(self) -> bool:
        """Tell whether a pose was accepted recently and the observer still publishes."""
        limit = self.settings.estimate_max_age
        return (self._eta is not None and self._age <= limit and self._estimate_ns is not None
                and self.now_ns() - self._estimate_ns <= limit * 1e9)

    def _now_s(self) -> float:
        return self.now_ns() * 1e-9

    def _admit(self, name: str, stamp_ns: int, count_accepted: bool = True) -> bool:
        """Offer a sample of input ``name`` to its time gate; count a refusal (and a take)."""
        verdict = self._gates[name].offer(stamp_ns, self.now_ns())
        if verdict is StampVerdict.ACCEPTED:
            if count_accepted:
                self.health.accepted(name)
            return True
        self.health.refused(name, verdict.value)
        self.get_logger().warn(f'{name} refused ({verdict.value}): stamped '
                               + ('ahead of the clock' if verdict is StampVerdict.FUTURE
                                  else 'before the last one taken'),
                               throttle_duration_sec=1.0)
        return False

    def _on_age(self, msg: Float64) -> None:
        self._age = msg.data

    def _on_bias(self, msg: WrenchStamped) -> None:
        if self._admit('observer/bias', convert.stamp_to_ns(msg.header.stamp)):
            self._bias = convert.wrench_to_tau3(msg.wrench)

    def _on_path_available(self, msg: Bool) -> None:
        self.path_available = msg.data

    def _on_joy(self, msg: Joy) -> None:
        if self.joy_guard.contested():
            self.health.refused('joy', 'contested')
            self.get_logger().error(self.joy_guard.status()[1], throttle_duration_sec=2.0)
            # Stop now, not joy_timeout later: someone else is on the joystick topic.
            tr = self.manager.joystick_contested()
            if tr is not None:
                self._transition(tr)
                self._publish_tau(self.manager.tau_manual, self.get_clock().now().to_msg())
            return
        now = self.get_clock().now()
        stamp = msg.header.stamp
        t = convert.stamp_to_ns(stamp)
        if t == 0:  # not stamped: timed by its arrival
            t, stamp = now.nanoseconds, now.to_msg()
        else:
            last = self._joy_last
            if (last is not None and t == last[0] and tuple(msg.axes) == last[1]
                    and tuple(msg.buttons) == last[2]):
                # The last sample republished with its stamp (ds4_driver's autorepeat): a sign
                # of life, not a new sample (nor a stale one).
                self.manager.on_repeat(now.nanoseconds * 1e-9)
                return
            if not self._admit('joy', t, count_accepted=False):
                return
            self._joy_last = (t, tuple(msg.axes), tuple(msg.buttons))
        before = self.manager.rejected_samples
        unconnected = self.manager.unconnected_samples
        transitions = self.manager.on_joy(list(msg.axes), list(msg.buttons),
                                          now.nanoseconds * 1e-9, self._fresh(),
                                          self.path_available)
        if self.manager.unconnected_samples > unconnected:
            self.health.refused('joy', 'not_connected')
            self.get_logger().warn(
                f'joystick sample not taken: the driver is not connected (loss rule '
                f'connection: {topics.JOY_CONNECTED.name} False or silent for joy_timeout)',
                throttle_duration_sec=2.0)
            return
        if self.manager.rejected_samples > before:
            self.health.refused('joy', 'malformed')
            self.get_logger().warn('joystick sample refused (non-finite or out-of-range axes, '
                                   'or too few axes/buttons)', throttle_duration_sec=1.0)
            return  # as if it never arrived: no force republished on its behalf
        self.health.accepted('joy')
        if self.manager.loss_rule == 'timeout':  # the rate that joy_timeout must cover
            self.joy_period.add(t)
        for tr in transitions:
            self._transition(tr)
        if self.manager.mode is Mode.MANUAL:
            self._publish_tau(self.manager.tau_manual, stamp)

    def _on_joy_connected(self, msg: Bool) -> None:
        """Take the joystick driver's connection state (the heartbeat of the connection rule)."""
        now = self.get_clock().now()
        if self.manager.loss_rule == 'connection' and msg.data:
            self.joy_period.add(now.nanoseconds)  # the heartbeat's period: joy_timeout's rate
        tr = self.manager.on_connection(msg.data, now.nanoseconds * 1e-9)
        if tr is not None:
            self.get_logger().error('joystick disconnected: manual, zero force')
            self._transition(tr)
            self._publish_tau(self.manager.tau_manual, now.to_msg())

    def _reference_fresh(self) -> bool:
        """Tell whether a reference was applied (or the mode entered) recently."""
        return (self._reference_ns is not None and self.now_ns()
                - self._reference_ns <= self.settings.estimate_max_age * 1e9)

    def _supervise(self) -> None:
        t = self.manager.check(self._now_s(), self._fresh(), self._reference_fresh())
        if t is not None:
            self._transition(t)
            self._publish_tau(self.manager.tau_manual, self.get_clock().now().to_msg())

    def _transition(self, t: Transition) -> None:
        if not t.accepted:
            self.refusals += 1
            self.last_refusal = f'{t.requested.value}: {t.reason}'
            self.get_logger().warn(f'{t.requested.value} mode refused: {t.reason}')
            return
        self._pending = None
        self._reference_ns = self.now_ns()  # the guidance node's grace
        if t.requested is not Mode.MANUAL:
            self.controller.reset(tau_now=self.tau)  # bumpless: continue from the force now
        self.get_logger().info(f'mode {t.previous.value} -> {t.requested.value} ({t.reason})')
        self._mode_pub.publish(String(data=t.requested.value))

    def _on_estimate(self, msg: Odometry) -> None:
        t = convert.stamp_to_ns(msg.header.stamp)
        if not self._admit('observer/odometry', t):
            return
        self.estimate_period.add(t)
        last, self._last_ns = self._last_ns, t
        self._eta = eta = convert.pose_to_eta(msg.pose.pose)
        self._estimate_ns = self.now_ns()
        self._estimates.append(_Estimate(t, last, eta, convert.twist_to_nu3(msg.twist.twist),
                                         msg.header.stamp))
        if self._pending is not None and self._pending[0] == t:
            (pending, ref), self._pending = self._pending[1], None
            self._apply_reference(pending, ref)

    def _on_reference(self, msg: MultiDOFJointTrajectory) -> None:
        if self.manager.mode is Mode.MANUAL:  # the operator has the force
            return
        try:
            ref = msg_to_reference(msg)
        except ValueError as err:
            self.bad_references += 1
            self.health.refused('guidance/reference', 'malformed')
            self.get_logger().error(str(err), throttle_duration_sec=1.0)
            return
        if self._admit('guidance/reference', convert.stamp_to_ns(msg.header.stamp)):
            self._apply_reference(msg, ref)

    def _apply_reference(self, msg: MultiDOFJointTrajectory, ref: Any) -> None:
        if self.manager.mode is Mode.MANUAL:
            return
        t = convert.stamp_to_ns(msg.header.stamp)
        estimate = next((e for e in reversed(self._estimates) if e.t_ns == t), None)
        if estimate is None:  # its estimate has not arrived yet: wait for it
            self._pending = (t, (msg, ref))
            return
        if estimate.last_ns is None or t <= estimate.last_ns:
            return
        self.reference = ref
        self._reference_ns = self.now_ns()
        tau = self.controller.step(estimate.eta, estimate.nu, self._bias, ref,
                                   (t - estimate.last_ns) * 1e-9).tau
        if self.force_filter is not None:
            tau = self._filter_force(estimate, tau)
        self._publish_tau(tau, estimate.stamp)

    def _filter_force(self, estimate: _Estimate, tau: np.ndarray) -> np.ndarray:
        """Pass the controller's force through the force-level barrier filter."""
        assert self.force_filter is not None
        rows, obstacles_ns = self._obstacles
        if obstacles_ns is None:  # nothing seen yet: the guidance node holds, blind
            self._force_problem = 'force-level avoidance: no obstacles message yet'
            self._publish_force(estimate.t_ns, 0.0, None, 0, None, stale=True)
            return tau
        age = (estimate.t_ns - obstacles_ns) * 1e-9
        stale = age > self.settings.avoidance.staleness
        if stale:
            self.force_counts['stale'] += 1
            self._force_problem = (f'force-level avoidance: obstacles {age:.2f} s old (limit '
                                   f'{self.settings.avoidance.staleness:g} s)')
        rows = moved(rows, age)
        start = time.perf_counter()
        out = self.force_filter.step(estimate.eta, estimate.nu, tau, rows)
        elapsed = time.perf_counter() - start
        self.force_output = out
        self.force_counts['engaged'] += out.engaged
        if out.infeasible:
            self.force_counts['infeasible'] += 1
            self._force_problem = f'force-level avoidance {out.reason}'
            self.get_logger().warn(f'force-level avoidance: {out.reason}',
                                   throttle_duration_sec=1.0)
        self._publish_force(estimate.t_ns, elapsed, out, len(rows), obstacles_ns, stale=stale)
        return out.tau

    def _publish_force(self, t: int, elapsed: float, out: ForceOutput | None, count: int,
                       obstacles_ns: int | None, *, stale: bool) -> None:
        values = {'solve_time': elapsed, 'active': out.active if out else 0,
                  'infeasible': float(bool(out and out.infeasible)),
                  'min_barrier': out.min_barrier if out else math.nan,
                  'engaged': float(bool(out and out.engaged)), 'blind': float(stale),
                  'obstacles': count}
        self._avoid_pub.publish(avoidance.to_msg(values, t, obstacles_ns))

    def _on_obstacles(self, msg: PointCloud2) -> None:
        if self.force_filter is None:
            return
        try:
            obstacles = from_cloud(msg)
        except ObstacleEncodingError as err:   # kept stale: the guidance node then holds
            self.force_counts['obstacles_refused'] += 1
            self.get_logger().warn(str(err), throttle_duration_sec=1.0)
            return
        self._obstacles = (obstacle_rows(obstacles), cloud_stamp_ns(msg))

    def _publish_tau(self, tau: np.ndarray, stamp: Any) -> None:
        with self._tau_lock:  # the chain thread and the executor both send forces
            t = convert.stamp_to_ns(stamp)
            # Keep the stream ordered (see the module doc); a stamp more than a second back is
            # a clock that went back (a restarted simulation): the stream starts over.
            if self._tau_ns is not None and self._tau_ns - _REORDER_NS <= t <= self._tau_ns:
                t = self._tau_ns + 1
                stamp = convert.ns_to_stamp(t)
            self._tau_ns = t
            self.tau = tau
            w = new(WrenchStamped)
            w.header.stamp = stamp
            w.header.frame_id = topics.BODY_FRAME
            convert.set_wrench_tau3(w.wrench, tau)
            self._tau_pub.publish(w)

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``; closes the input-health window."""
        level, message, totals = self.health.report(1.0)
        problem = self.settings.rate_problem(self.estimate_period.period,
                                             self.joy_period.period)
        rates = (OK, 'ok')
        if problem:
            rates = (DEGRADED, problem)
            self.report_problem(f'parameter {problem}')
        force = (OK, 'ok')
        if self._force_problem is not None:   # anything the window saw, then cleared
            force, self._force_problem = (DEGRADED, self._force_problem), None
        level, message = worst((level, message), rates, self.joy_guard.status(), force)
        out = self.force_output
        return level, (self.manager.mode.value if level == OK else message), {
            'force_avoidance': 'on' if self.force_filter is not None else 'off',
            'force_avoidance_engaged': bool(out and out.engaged),
            'force_avoidance_min_barrier': 'none' if out is None else out.min_barrier,
            **{f'force_avoidance_{k}': v for k, v in self.force_counts.items()},
            'mode': self.manager.mode.value, 'refusals': self.refusals,
            'last_refusal': self.last_refusal,
            'joy_rejected': self.manager.rejected_samples,
            'joy_loss_rule': self.manager.loss_rule, 'joy_connected': self.manager.connected,
            'joy_unconnected_samples': self.manager.unconnected_samples,
            'bad_references': self.bad_references, **totals}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
