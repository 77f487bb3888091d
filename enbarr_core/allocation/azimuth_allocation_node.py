"""Azimuth thrust allocation: ``force_command`` (tau = [X, Y, N]) -> thrust and angle.

Publishes per-azimuth thrust and angle on ``azimuth_commands`` and the force actually
deliverable on ``allocation/delivered``: the smallest thrust within the servo travel and
thrust limits (``allocation.azimuth``); when tau is not achievable the thrusts are scaled
together (direction kept) and the shortfall is reported: a warning, the ``infeasible`` counter
and ``allocation/delivered``. The previous angles are passed back each time so servos do not
flip 180 degrees needlessly.

Time (``framework.stamps``): a force stamped more than ``max_future`` ahead of the
clock, or not later than the last one allocated, is refused and counted (dp_control keeps its
force stream ordered); more than 5 % refused in a second makes the node DEGRADED.
``max_future`` must stay under the measured force period.

Failed azimuths (``failure_params``): the parameter ``failed_thrusters`` (``name``,
``name:dead`` or ``name:stuck:<deg>``) and ERROR statuses on ``/diagnostics`` with a
``failed_thruster`` value change the allocation at run time: a dead azimuth gets zero thrust,
a stuck one thrust along its stuck angle (which it is commanded), the others are re-solved,
and ``/diagnostics`` says DEGRADED with the azimuths out and the DOFs lost.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.allocation.azimuth import AzimuthAllocator, DOF_NAMES_3
from enbarr_core.allocation.failure_params import FailureInput
from enbarr_core.allocation.layout_params import AZIMUTHS
from enbarr_core.framework.errors import AllocationError
from enbarr_core.framework.health import (
    DEGRADED, future_tolerance_problem, InputHealth, IntervalMeter, OK, worst)
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict
from enbarr_core.models.vessel3dof import AzimuthSpec


@dataclass(frozen=True)
class AzimuthAllocationSettings:
    """Settings of ``AzimuthAllocationNode``: the azimuth layout (read only)."""

    azimuths: tuple[AzimuthSpec, ...]

    @classmethod
    def from_params(cls, names: Sequence[str],
                    v: Mapping[str, Any]) -> AzimuthAllocationSettings:
        """Build from the declared parameters' values (ValueError naming the azimuth)."""
        return cls(AZIMUTHS.from_params(names, v))


MAX_FUTURE = ParamSpec('max_future', 0.01, 'Forces stamped further ahead of the clock than '
                       "this are refused (at least the observer's)", 's', 0.0, 0.5)


class AzimuthAllocationNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'allocation', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        names = AZIMUTHS.names(self)
        self.settings: AzimuthAllocationSettings = self.bind_settings(
            AZIMUTHS.specs(self, names),
            lambda v: AzimuthAllocationSettings.from_params(names, v),
            lambda _: None).settings  # every parameter is read only
        specs = self.settings.azimuths
        try:
            self.allocator = AzimuthAllocator(specs)
        except AllocationError as err:
            raise AllocationError(f'node {node_name!r}: {err}',
                                  parameter='azimuth_names') from err
        self.health = InputHealth()
        self.force_period = IntervalMeter()
        self._gate = StampGate()
        self.bind_settings([MAX_FUTURE], self._build_max_future, self._apply_max_future)
        self.names = [a.name for a in specs]
        self.failures = FailureInput(self, self.allocator, tuple(self.names), True,
                                     DOF_NAMES_3)
        self.angle = np.zeros(len(specs))
        self.result = None
        self.infeasible = 0
        self.rejected = 0
        self._pub = self.create_topic_publisher(topics.AZIMUTH_COMMANDS)
        self._delivered_pub = self.create_topic_publisher(topics.ALLOCATION_DELIVERED)
        self.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        self.create_periodic(1.0, self._report)

    def _build_max_future(self, v: Mapping[str, Any]) -> float:
        problem = future_tolerance_problem(v['max_future'], self.force_period.period,
                                           topics.FORCE_COMMAND.name)
        if problem:
            raise ValueError(problem)
        return v['max_future']

    def _apply_max_future(self, max_future: float) -> None:
        self._gate.policy = StampPolicy(max_future=max_future)

    def _on_tau(self, msg: WrenchStamped) -> None:
        tau = convert.wrench_to_tau3(msg.wrench)
        if not convert.all_finite(tau):
            self.rejected += 1
            self.health.refused('force_command', 'non_finite')
            return
        t = convert.stamp_to_ns(msg.header.stamp)
        verdict = self._gate.offer(t, self.now_ns())
        if verdict is not StampVerdict.ACCEPTED:
            self.rejected += 1
            self.health.refused('force_command', verdict.value)
            self.get_logger().warn(f'force_command refused ({verdict.value})',
                                   throttle_duration_sec=1.0)
            return
        self.health.accepted('force_command')
        self.force_period.add(t)
        self.result = r = self.allocator.allocate(tau, previous_angle=self.angle)
        self.angle = r.angle
        if not r.feasible:
            self.infeasible += 1
            self.get_logger().warn(
                f'tau {np.round(tau, 3).tolist()} not achievable: delivering '
                f'{np.round(r.scale * 100.0, 1)} % of it', throttle_duration_sec=2.0)
        out = new(JointState)
        out.name, out.effort, out.position = self.names, r.thrust.tolist(), r.angle.tolist()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = topics.BODY_FRAME
        self._pub.publish(out)
        delivered = new(WrenchStamped)
        delivered.header = out.header
        convert.set_wrench_tau3(delivered.wrench, r.tau_delivered)
        self._delivered_pub.publish(delivered)

    def safe_state(self) -> None:
        """Command zero thrust at the present angles: the last azimuth command is neutral."""
        out = new(JointState)
        out.name, out.effort = self.names, [0.0] * len(self.names)
        out.position = np.asarray(self.angle, dtype=float).tolist()
        out.header.stamp = self.get_clock().now().to_msg()
        out.header.frame_id = topics.BODY_FRAME
        self._pub.publish(out)

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``; closes the input-health window."""
        own = (DEGRADED, f'{self.infeasible} forces not achievable') if self.infeasible \
            else (OK, 'ok')
        level, message, totals = self.health.report(1.0)
        problem = future_tolerance_problem(self._gate.policy.max_future,
                                           self.force_period.period, topics.FORCE_COMMAND.name)
        rates = (OK, 'ok')
        if problem:
            rates = (DEGRADED, problem)
            self.report_problem(f'parameter {problem}')
        out_level, out_message, out_values = self.failures.status()
        level, message = worst(own, (level, message), rates, (out_level, out_message))
        return level, message, {'infeasible': self.infeasible, 'rejected': self.rejected,
                                **totals, **out_values}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
