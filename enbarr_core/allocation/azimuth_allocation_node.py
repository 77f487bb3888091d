"""Azimuth thrust allocation: ``force_command`` (tau = [X, Y, N]) -> thrust and angle.

Publishes per-azimuth thrust and angle on ``azimuth_commands`` and the force actually
deliverable on ``allocation/delivered``: the smallest thrust within the servo travel and
thrust limits (``allocation.azimuth``); when tau is not achievable the thrusts are scaled
together (direction kept) and the shortfall is reported: a warning, the ``infeasible`` counter
and ``allocation/delivered``. The previous angles are passed back each time so servos do not
flip 180 degrees needlessly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from enbarr_interfaces import convert, topics

from enbarr_core.allocation.azimuth import AzimuthAllocator
from enbarr_core.allocation.layout_params import AZIMUTHS
from enbarr_core.framework.errors import AllocationError
from enbarr_core.framework.node import EnbarrNode
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
        self.names = [a.name for a in specs]
        self.angle = np.zeros(len(specs))
        self.result = None
        self.infeasible = 0
        self.rejected = 0
        self._pub = self.create_topic_publisher(topics.AZIMUTH_COMMANDS)
        self._delivered_pub = self.create_topic_publisher(topics.ALLOCATION_DELIVERED)
        self.create_topic_subscription(topics.FORCE_COMMAND, self._on_tau)
        self.create_timer(1.0, self._report)

    def _on_tau(self, msg: WrenchStamped) -> None:
        tau = convert.wrench_to_tau3(msg.wrench)
        if not np.all(np.isfinite(tau)):
            self.rejected += 1
            return
        self.result = r = self.allocator.allocate(tau, previous_angle=self.angle)
        self.angle = r.angle
        if not r.feasible:
            self.infeasible += 1
            self.get_logger().warn(
                f'tau {np.round(tau, 3).tolist()} not achievable: delivering '
                f'{np.round(r.scale * 100.0, 1)} % of it', throttle_duration_sec=2.0)
        out = JointState(name=self.names, effort=r.thrust.tolist(), position=r.angle.tolist())
        out.header.stamp = msg.header.stamp
        out.header.frame_id = topics.BODY_FRAME
        self._pub.publish(out)
        delivered = WrenchStamped()
        delivered.header = out.header
        convert.set_wrench_tau3(delivered.wrench, r.tau_delivered)
        self._delivered_pub.publish(delivered)

    def _report(self) -> None:
        self.publish_diagnostics(1 if self.infeasible else 0, 'ok', {
            'infeasible': self.infeasible, 'rejected': self.rejected})
