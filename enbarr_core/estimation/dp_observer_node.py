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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from std_msgs.msg import Float64

from enbarr_interfaces import convert, topics

from enbarr_core.estimation.dp_observer import ObserverSettings, PassiveObserver
from enbarr_core.framework.node import EnbarrNode, WATCHDOG_PERIOD
from enbarr_core.framework.params import ParamSpec
from enbarr_core.models.vessel3dof_params import (
    vector3, VESSEL_SPECS, vessel_from_params)

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
    ParamSpec('rate', 50.0, 'Integration rate of dead reckoning when poses stop (checked at '
              '10 Hz, integrated in steps of 1/rate)', 'Hz', 1.0, 1000.0, read_only=True),
]


@dataclass(frozen=True)
class DpObserverNodeSettings:
    """Settings of ``DpObserverNode`` (see ``SPECS``)."""

    observer: ObserverSettings  # gains, model and measurement checks
    rate: float                 # dead-reckoning integration rate [Hz]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> DpObserverNodeSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        vessel = vessel_from_params(v)
        s = ObserverSettings(
            K1=vector3(v, 'k1'), K2=vector3(v, 'k2'),
            K3=vector3(v, 'k3'), T_b=vector3(v, 't_b'),
            M=vessel.M, D=vessel.D, Dn=vessel.Dn, stale_after=v['stale_after'],
            max_position_jump=v['max_position_jump'], max_heading_jump=v['max_heading_jump'])
        try:
            s.validate()
        except ValueError as err:
            field = str(err).split(':')[0]
            raise ValueError(f'{_PARAMETER.get(field, field)}: {err}') from err
        return cls(observer=s, rate=v['rate'])


_PARAMETER = {'K1': 'k1', 'K2': 'k2', 'K3': 'k3', 'T_b': 't_b', 'M': 'vessel.inertia',
              'D': 'vessel.linear_damping', 'Dn': 'vessel.nonlinear_damping'}


class DpObserverNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.observer: PassiveObserver | None = None
        self.settings: DpObserverNodeSettings
        self.bind_settings(SPECS, DpObserverNodeSettings.from_params, self._apply)
        self.estimate = None
        self.rejected = 0
        self._tau = np.zeros(3)
        self._last_ns: int | None = None
        self._period_ns = round(1e9 / self.settings.rate)
        self._odom_pub = self.create_topic_publisher(topics.OBSERVER_ODOMETRY)
        self._bias_pub = self.create_topic_publisher(topics.OBSERVER_BIAS)
        self._age_pub = self.create_topic_publisher(topics.OBSERVER_AGE)
        self.create_topic_subscription(topics.ALLOCATION_DELIVERED, self._on_tau)
        self.create_topic_subscription(topics.MOCAP_POSE, self._on_pose)
        self.create_timer(WATCHDOG_PERIOD, self._dead_reckon)
        self.create_timer(1.0, self._report)

    def _apply(self, settings: DpObserverNodeSettings) -> None:
        self.settings = settings
        if self.observer is None:
            self.observer = PassiveObserver(settings.observer)
        else:
            self.observer.settings = settings.observer

    def _on_tau(self, msg: WrenchStamped) -> None:
        tau = convert.wrench_to_tau3(msg.wrench)
        if np.all(np.isfinite(tau)):
            self._tau = tau

    def _on_pose(self, msg: PoseStamped) -> None:
        y = convert.pose_to_eta(msg.pose)
        t = convert.stamp_to_ns(msg.header.stamp)
        if not np.all(np.isfinite(y)) or (self._last_ns is not None and t <= self._last_ns):
            self.rejected += 1
            return
        if not self.observer.initialized:
            self.observer.initialize(y)
            self._last_ns = t
            return
        self._step(y, t)

    def _dead_reckon(self) -> None:
        if self._last_ns is None:
            return
        now = self.get_clock().now().nanoseconds
        if now - self._last_ns > 1.5 * self._period_ns:
            # Poses stopped: integrate up to now in steps of 1/rate, publish the newest.
            n = -(-(now - self._last_ns) // self._period_ns)
            for k in range(1, n + 1):
                t = self._last_ns + (now - self._last_ns) // (n - k + 1)
                self._step(None, t, publish=(k == n))

    def _step(self, y: np.ndarray | None, t: int, publish: bool = True) -> None:
        dt = (t - self._last_ns) * 1e-9
        self._last_ns = t
        self.estimate = e = self.observer.step(y, self._tau, dt)
        if e.rejected_jump:
            self.rejected += 1
            self.get_logger().warn('implausible pose jump rejected', throttle_duration_sec=1.0)
        if not publish:
            return
        stamp = convert.ns_to_stamp(t)
        odom = Odometry()
        odom.header.stamp = stamp
        odom.header.frame_id = topics.WORLD_FRAME
        odom.child_frame_id = topics.BODY_FRAME
        convert.set_pose_eta(odom.pose.pose, e.eta_hat)
        convert.set_twist_nu3(odom.twist.twist, e.nu_hat)
        age = Float64(data=float(e.age))
        bias = WrenchStamped()
        bias.header.stamp = stamp
        bias.header.frame_id = topics.WORLD_FRAME
        convert.set_wrench_tau3(bias.wrench, e.b_hat)
        self._age_pub.publish(age)      # before the odometry: the controller reads both
        self._bias_pub.publish(bias)
        self._odom_pub.publish(odom)

    def _report(self) -> None:
        e = self.estimate
        self.publish_diagnostics(
            1 if e is None or e.stale else 0, 'stale' if e is None or e.stale else 'ok',
            {'rejected': self.rejected, 'age': e.age if e else 'none'})
