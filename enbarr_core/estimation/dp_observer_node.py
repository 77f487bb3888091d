"""DP observer node: pose and delivered force in, estimate, bias and measurement age out.

``mocap/pose`` + ``allocation/delivered`` -> ``observer/odometry``, ``observer/bias`` and
``observer/measurement_age``.

A nonlinear passive observer (``estimation.dp_observer``, Fossen 2021 ch. 13) estimating pose,
velocity and a slowly varying bias. It steps on every pose (dt from the stamps) and, when
poses stop, on its own timer at ``rate``, dead-reckoning with the model and the delivered
force; ``observer/measurement_age`` tells how long it has been doing so. Poses that jump
implausibly far from the estimate, or hold NaN/Inf, are rejected and counted. The gains
(``k1``, ``k2``, ``k3``: 3-element diagonals) and the vessel model (``vessel.*``) come from the
profile and have no default (a node started without them refuses, naming the parameter);
they and ``t_b`` change live, the state kept.

Time (``docs/architecture.md``, Time; ``framework.stamps``): a pose is used only when its
stamp is at most ``max_future`` ahead of the node's clock and later than the last pose taken;
others are refused and counted, so a pose stamped in the future never becomes the time base
(one such pose once froze the estimate for as long as it was ahead). ``max_future`` (10 ms)
covers the offset between the motion-capture computer's clock and this one (milliseconds under
chrony; zero in one process, where the pose is stamped from this clock) and stays under the
pose period, so an early pose costs at most itself. Poses cross processes and networks, so
they arrive after their stamp: dead reckoning stays ``max_latency`` (0.1 s) behind the clock,
and a pose arriving later than that after its stamp, once the estimate was dead-reckoned past
it, is refused as ``late``. The force
(``allocation/delivered``) is only a value here: its stamp is judged by the same rule so that
an older force never replaces a newer one.

Diagnostics: DEGRADED when more than 5 % of the poses of the last second were refused (the
reasons counted), when the estimate was reset (a diverged state), or when it is stale; a
parameter that only makes sense against the pose rate (``stale_after`` at least two pose
periods, ``max_future`` under one) is refused with the measured period, and a start value
that breaks the rule is reported (log, ``/diagnostics``, the run's problems) once the period
is known.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import threading
from typing import Any

from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from std_msgs.msg import Float64

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.estimation.dp_observer import ObserverSettings, PassiveObserver
from enbarr_core.framework.health import (
    DEGRADED, future_tolerance_problem, InputHealth, IntervalMeter, OK, too_short_for_rate,
    worst)
from enbarr_core.framework.node import EnbarrNode, WATCHDOG_PERIOD
from enbarr_core.framework.params import ParamSpec, validate_as_parameters
from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict
from enbarr_core.models.vessel3dof_params import (
    vector3, VESSEL_PARAMETERS, VESSEL_SPECS, vessel_from_params)

_XYN = '(x, y, psi)'
SPECS = [
    ParamSpec('k1', [0.0, 0.0, 0.0], f'Position injection gains K1 {_XYN}', '1/s', 0.0,
              1e4, required=True),
    ParamSpec('k2', [0.0, 0.0, 0.0], f'Bias injection gains K2 {_XYN}',
              'N/(m s), N m/(rad s)', 0.0, 1e5, required=True),
    ParamSpec('k3', [0.0, 0.0, 0.0], f'Velocity injection gains K3 {_XYN}',
              'N/m, N m/rad', 0.0, 1e5, required=True),
    ParamSpec('t_b', [1000.0, 1000.0, 1000.0], f'Bias time constants T_b {_XYN}', 's', 1e-3,
              1e9),
    *VESSEL_SPECS,
    ParamSpec('stale_after', 2.0, 'Estimate is stale after dead-reckoning this long', 's',
              0.01, 60.0),
    ParamSpec('max_position_jump', 0.5, 'Reject poses this far from the estimate', 'm', 1e-3,
              100.0),
    ParamSpec('max_heading_jump', 0.5, 'Reject headings this far from the estimate', 'rad',
              1e-3, 3.2),
    ParamSpec('max_future', 0.01, 'Poses stamped further ahead of the clock than this are '
              'refused (clock offset of the motion-capture computer; under the pose period)',
              's', 0.0, 0.5),
    ParamSpec('max_latency', 0.1, 'Poses arriving up to this long after their stamp are used: '
              'dead reckoning stays this far behind the clock', 's', 0.0, 1.0),
    ParamSpec('rate', 50.0, 'Integration rate of dead reckoning when poses stop (checked at '
              '10 Hz, integrated in steps of 1/rate)', 'Hz', 1.0, 1000.0, read_only=True),
]


@dataclass(frozen=True)
class DpObserverNodeSettings:
    """Settings of ``DpObserverNode`` (see ``SPECS``)."""

    observer: ObserverSettings  # gains, model and measurement checks
    rate: float                 # dead-reckoning integration rate [Hz]
    max_future: float           # poses stamped further ahead of the clock are refused [s]
    max_latency: float          # dead reckoning stays this far behind the clock [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> DpObserverNodeSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        vessel = vessel_from_params(v)
        s = ObserverSettings(
            K1=vector3(v, 'k1'), K2=vector3(v, 'k2'),
            K3=vector3(v, 'k3'), T_b=vector3(v, 't_b'),
            M=vessel.M, D=vessel.D, Dn=vessel.Dn, stale_after=v['stale_after'],
            max_position_jump=v['max_position_jump'], max_heading_jump=v['max_heading_jump'])
        validate_as_parameters(s, _PARAMETER)
        return cls(observer=s, rate=v['rate'], max_future=v['max_future'],
                   max_latency=v['max_latency'])

    def rate_problem(self, pose_period: float | None) -> str | None:
        """Why these settings do not fit poses arriving every ``pose_period`` [s] (or None)."""
        return (too_short_for_rate('stale_after', self.observer.stale_after,
                                   topics.MOCAP_POSE.name, pose_period,
                                   'one lost pose would make the estimate stale')
                or future_tolerance_problem(self.max_future, pose_period,
                                            topics.MOCAP_POSE.name))


_PARAMETER = {'K1': 'k1', 'K2': 'k2', 'K3': 'k3', 'T_b': 't_b', **VESSEL_PARAMETERS}


class DpObserverNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.observer: PassiveObserver | None = None
        self.settings: DpObserverNodeSettings
        self.health = InputHealth()
        self.pose_period = IntervalMeter()  # of the poses taken
        self._pose_gate = StampGate()
        self._tau_gate = StampGate()
        self.bind_settings(SPECS, self._build, self._apply)
        self.estimate = None
        self.age = math.inf  # published measurement age [s]: clock time since the last pose
        self.rejected = 0
        self._tau = np.zeros(3)
        self._last_ns: int | None = None
        # Poses step the estimate on the chain's thread, dead reckoning on the executor's:
        # one at a time, or a step sees the other's time base move under it (a negative dt).
        self._step_lock = threading.Lock()
        self._period_ns = round(1e9 / self.settings.rate)
        self._odom_pub = self.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self._bias_pub = self.create_topic_publisher(topics.OBSERVER_BIAS)
        self._age_pub = self.create_topic_publisher(topics.OBSERVER_AGE)
        self.create_topic_subscription(topics.ALLOCATION_DELIVERED, self._on_tau)
        self.create_topic_subscription(topics.MOCAP_POSE, self._on_pose)
        self.create_periodic(WATCHDOG_PERIOD, self._dead_reckon)
        self.create_periodic(1.0, self._report)

    def _build(self, v: Mapping[str, Any]) -> DpObserverNodeSettings:
        """Build the settings and refuse those that do not fit the measured pose period."""
        settings = DpObserverNodeSettings.from_params(v)
        problem = settings.rate_problem(self.pose_period.period)
        if problem:
            raise ValueError(problem)
        return settings

    def _apply(self, settings: DpObserverNodeSettings) -> None:
        self.settings = settings
        policy = StampPolicy(max_future=settings.max_future)
        self._pose_gate.policy = self._tau_gate.policy = policy
        if self.observer is None:
            self.observer = PassiveObserver(settings.observer)
        else:
            self.observer.settings = settings.observer

    def _on_tau(self, msg: WrenchStamped) -> None:
        tau = convert.wrench_to_tau3(msg.wrench)
        if not convert.all_finite(tau):
            self.health.refused('allocation/delivered', 'non_finite')
            return
        verdict = self._tau_gate.offer(convert.stamp_to_ns(msg.header.stamp),
                                       self.now_ns())
        if verdict is not StampVerdict.ACCEPTED:
            self.health.refused('allocation/delivered', verdict.value)
            return
        self.health.accepted('allocation/delivered')
        self._tau = tau

    def _refuse_pose(self, reason: str) -> None:
        self.rejected += 1
        self.health.refused('mocap/pose', reason)
        self.get_logger().warn(f'mocap/pose refused ({reason})', throttle_duration_sec=1.0)

    def _on_pose(self, msg: PoseStamped) -> None:
        y = convert.pose_to_eta(msg.pose)
        t = convert.stamp_to_ns(msg.header.stamp)
        if not convert.all_finite(y):
            self._refuse_pose('non_finite')
            return
        verdict = self._pose_gate.offer(t, self.now_ns())
        if verdict is not StampVerdict.ACCEPTED:
            self._refuse_pose(verdict.value)
            return
        with self._step_lock:
            if self._last_ns is not None and t <= self._last_ns:
                self._refuse_pose('late')  # the estimate was dead-reckoned past it
                return
            self.health.accepted('mocap/pose')
            self.pose_period.add(t)
            if not self.observer.initialized:
                self.observer.initialize(y)
                self._last_ns = t
                return
            self._step(y, t)

    def _dead_reckon(self) -> None:
        with self._step_lock:
            self._dead_reckon_locked()

    def _dead_reckon_locked(self) -> None:
        if self._last_ns is None:
            return
        # Up to max_latency behind the clock: a pose on its way is not overtaken. The age
        # published is still the clock's: the time since the last pose taken.
        lag = round(self.settings.max_latency * 1e9)
        now = self.now_ns() - lag
        if now - self._last_ns > 1.5 * self._period_ns:
            # Poses stopped: integrate up to now in steps of 1/rate, publish the newest.
            n = -(-(now - self._last_ns) // self._period_ns)
            for k in range(1, n + 1):
                t = self._last_ns + (now - self._last_ns) // (n - k + 1)
                if not self._step(None, t, publish=(k == n), lag=lag * 1e-9):
                    return

    def _step(self, y: np.ndarray | None, t: int, publish: bool = True,
              lag: float = 0.0) -> bool:
        """Advance the estimate to ``t`` [ns], ``lag`` [s] before the clock's present.

        Return False when it diverged (and was dropped).
        """
        dt = (t - self._last_ns) * 1e-9
        self._last_ns = t
        self.estimate = e = self.observer.step(y, self._tau, dt)
        if e.diverged:
            self._last_ns = None  # the next pose starts the estimate over
            self.health.reset('estimate')
            self.get_logger().error('the estimate diverged (no longer finite): dropped, '
                                    'waiting for the next pose')
            return False
        if e.rejected_jump:
            self.rejected += 1
            self.health.refused('mocap/pose', 'jump')
            self.get_logger().warn('implausible pose jump rejected', throttle_duration_sec=1.0)
        if not publish:
            return True
        stamp = convert.ns_to_stamp(t)
        odom = new(Odometry)
        odom.header.stamp = stamp
        odom.header.frame_id = topics.WORLD_FRAME
        odom.child_frame_id = topics.BODY_FRAME
        convert.set_pose_eta(odom.pose.pose, e.eta_hat)
        convert.set_twist_nu3(odom.twist.twist, e.nu_hat)
        self.age = e.age + lag if e.age else 0.0
        age = new(Float64)
        age.data = float(self.age)
        bias = new(WrenchStamped)
        bias.header.stamp = stamp
        bias.header.frame_id = topics.WORLD_FRAME
        convert.set_wrench_tau3(bias.wrench, e.b_hat)
        self._age_pub.publish(age)      # before the odometry: the controller reads both
        self._bias_pub.publish(bias)
        self._odom_pub.publish(odom)
        return True

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``; closes the input-health window."""
        e = self.estimate
        stale = e is None or e.stale
        own = (DEGRADED, 'stale') if stale else (OK, 'ok')
        level, message, totals = self.health.report(1.0)
        problem = self.settings.rate_problem(self.pose_period.period)
        rates = (OK, 'ok')
        if problem:
            rates = (DEGRADED, problem)
            self.report_problem(f'parameter {problem}')
        level, message = worst(own, (level, message), rates)
        period = self.pose_period.period
        return level, message, {
            'rejected': self.rejected, 'age': self.age if e else 'none', **totals,
            'divergences': self.observer.divergences,
            'pose_period': 'unknown' if period is None else round(period, 6)}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
