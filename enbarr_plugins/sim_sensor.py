"""What every simulated sensor that measures the simulator's truth shares.

A simulated camera, lidar or motion capture measures the simulated vessel's true pose
(``sim/odometry``), and the truth's stamp schedules its measurements. So a truth stamped more
than ``TRUTH_MAX_FUTURE`` ahead of the node's clock, or not later than the last one taken, is
refused and counted (``EnbarrNode.admit_stamp``): it neither makes a measurement nor moves
the schedule, and the node is DEGRADED on ``/diagnostics`` while truths are refused. The
simulator stamps its truth from the clock of the same process (no offset), so 10 ms is only
slack. Each sensor keeps its own schedule (its rate, how it rounds the period) and what it
measures; this base holds the gate, the input's health and the mount on the vessel.
"""

from __future__ import annotations

from typing import Any

from nav_msgs.msg import Odometry

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import ConfigurationError, FrameError
from enbarr_core.framework.frames import Transform
from enbarr_core.framework.health import InputHealth, worst
from enbarr_core.framework.stamps import StampGate, StampPolicy
from enbarr_interfaces import topics

#: Truths stamped further ahead of the clock than this are refused [s].
TRUTH_MAX_FUTURE = 0.01


class TruthSensor(SensorDriver):
    """A sensor driver that measures ``sim/odometry``; see the module docstring."""

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.truth_gate = StampGate(StampPolicy(max_future=TRUTH_MAX_FUTURE))
        self.health = InputHealth()

    def admit_truth(self, truth: Odometry) -> int | None:
        """Return the truth's stamp [ns] when it may schedule a measurement, else None."""
        return self.admit_stamp('sim/odometry', truth.header.stamp, self.truth_gate,
                                self.health)

    def mount(self, frame_id: str, what: str) -> Transform:
        """Return the pose of ``frame_id`` in base_link.

        ``ConfigurationError`` naming ``what`` (the sensor) when the frame tree cannot place it.
        """
        try:
            return self.frame_tree.lookup(topics.BODY_FRAME, frame_id)
        except FrameError as err:
            raise ConfigurationError(f'node {self.get_name()!r}: frame_id: the frame tree '
                                     f'cannot place the {what}: {err}',
                                     parameter='frame_id') from err

    def status(self) -> tuple[int, str]:
        """Return the driver's status, DEGRADED while truths are refused."""
        level, message, _ = self.health.report(1.0)
        return worst(super().status(), (level, message))
