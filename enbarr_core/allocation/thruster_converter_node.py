"""Thruster converter: ``force_command`` (tau) -> ``thruster_commands`` (-1..1 each).

The README's ``vector_trajectory_converter.py``, for any layout: the allocation matrix comes
from each thruster's position and direction (``layout_params.THRUSTERS``), the weighted
pseudo-inverse gives the smallest thrust, and saturation scales all thrusters together so the
delivered force keeps the requested direction (``allocation.fixed``). A layout that cannot
produce a controlled degree of freedom is refused at start with the DOF named.

Time policy (``framework.stamps``): a ``force_command`` stamped more than ``max_future`` ahead
of the node's clock, or not later than the last accepted one, is refused and counted (its
stamp would travel on to the thrusters as the command's time); ``/diagnostics`` reports the
node degraded when more than 5 % of a second's commands are refused.

Failed thrusters (``failure_params``): the parameter ``failed_thrusters`` (``name`` or
``name:dead``) and ERROR statuses on ``/diagnostics`` with a ``failed_thruster`` value take a
thruster out of the allocation at run time; it is commanded zero, the others re-solved, and
``/diagnostics`` says DEGRADED with the thrusters out and the DOFs lost.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.allocation.failure_params import FailureInput
from enbarr_core.allocation.fixed import DOF_NAMES, Thruster, ThrustAllocator
from enbarr_core.allocation.layout_params import THRUSTERS
from enbarr_core.framework.errors import AllocationError
from enbarr_core.framework.health import InputHealth, worst
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import (
    SAME_CLOCK_MAX_FUTURE, StampGate, StampPolicy, StampVerdict)

SPECS = [
    ParamSpec('controlled_dofs', list(DOF_NAMES),
              'Degrees of freedom the thrusters must produce', read_only=True),
    ParamSpec('max_future', SAME_CLOCK_MAX_FUTURE,
              'force_command stamped further ahead of the node clock '
              'is refused (time policy)', 's', 0.0, 1.0),
]
#: Window of the diagnostics report [s].
REPORT_PERIOD = 1.0


@dataclass(frozen=True)
class ThrusterConverterSettings:
    """Settings of ``ThrusterConverterNode`` (``SPECS`` and the thruster layout)."""

    thrusters: tuple[Thruster, ...]
    controlled_dofs: tuple[int, ...]  # indices into DOF_NAMES
    max_future: float                 # time policy of force_command [s]

    @classmethod
    def from_params(cls, names: Sequence[str],
                    v: Mapping[str, Any]) -> ThrusterConverterSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        unknown = [d for d in v['controlled_dofs'] if d not in DOF_NAMES]
        if unknown:
            raise ValueError(f'controlled_dofs: unknown {unknown}; expected some of '
                             f'{DOF_NAMES}')
        return cls(THRUSTERS.from_params(names, v),
                   tuple(DOF_NAMES.index(d) for d in v['controlled_dofs']), v['max_future'])


class ThrusterConverterNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_converter', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        names = THRUSTERS.names(self)
        self.gate = StampGate()
        self.health = InputHealth()
        self.settings: ThrusterConverterSettings = self.bind_settings(
            THRUSTERS.specs(self, names) + SPECS,
            lambda v: ThrusterConverterSettings.from_params(names, v),
            self._apply).settings  # every parameter but max_future is read only
        s = self.settings
        try:
            self.allocator = ThrustAllocator(s.thrusters, controlled_dofs=s.controlled_dofs)
        except AllocationError as err:
            raise AllocationError(f'node {node_name!r}: {err}') from err
        self.saturated = 0
        self.rejected = 0
        self.result = None
        self._names = [t.name for t in s.thrusters]
        self.failures = FailureInput(self, self.allocator, tuple(self._names), False,
                                     tuple(DOF_NAMES[k] for k in s.controlled_dofs))
        self._pub = self.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.create_topic_subscription(topics.FORCE_COMMAND, self._on_wrench)
        self.create_periodic(REPORT_PERIOD, self._report)

    def _apply(self, settings: ThrusterConverterSettings) -> None:
        self.settings = settings
        self.gate.policy = StampPolicy(settings.max_future)

    def safe_state(self) -> None:
        """Command every thruster to zero: the last word on ``thruster_commands`` is neutral.

        The thruster plugin goes neutral by itself, but in a split profile it is another
        process, and a bag whose last command is not the neutral the thrusters show would
        be a lie about how the run ended.
        """
        cmd = new(JointState)
        cmd.name, cmd.effort = self._names, [0.0] * len(self._names)
        cmd.header.stamp = self.get_clock().now().to_msg()
        cmd.header.frame_id = topics.BODY_FRAME
        self._pub.publish(cmd)

    def _on_wrench(self, msg: WrenchStamped) -> None:
        tau = convert.wrench_to_tau(msg.wrench)
        if not convert.all_finite(tau):
            self.rejected += 1
            self.health.refused('force_command', 'non_finite')
            return
        verdict = self.gate.offer(convert.stamp_to_ns(msg.header.stamp),
                                  self.now_ns())
        if verdict is not StampVerdict.ACCEPTED:
            self.rejected += 1
            self.health.refused('force_command', verdict.value)
            return
        self.health.accepted('force_command')
        self.result = r = self.allocator.allocate(tau)
        self.saturated += r.saturated
        cmd = new(JointState)
        cmd.name, cmd.effort = self._names, r.command.tolist()
        cmd.header.stamp = msg.header.stamp
        cmd.header.frame_id = topics.BODY_FRAME
        self._pub.publish(cmd)

    def _report(self) -> None:
        level, message, values = self.health.report(REPORT_PERIOD)
        out_level, out_message, out_values = self.failures.status()
        level, message = worst((level, message), (out_level, out_message))
        self.publish_diagnostics(level, message, {'saturated': self.saturated,
                                                  'rejected': self.rejected, **values,
                                                  **out_values})
