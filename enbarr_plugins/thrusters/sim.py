"""Simulated thruster control: what a PWM/ESC plugin does, against the simulated vehicle.

Takes ``thruster_commands`` (-1..1 per named thruster), turns them into thrust with each
thruster's limits and a first-order motor lag, and hands the thrust to the simulator
(``sim/thrust``). ``thruster_output`` reports what was applied. Like a real ESC driver it
goes neutral when commands stop for ``command_timeout`` (a crashed controller or a dropped
link) and on ``safe_state`` (every bringup exit path). The checks a command passes (names,
finite values, clipping, the time policy) are those of every thruster plugin
(``thrusters/common.py``).

Two clocks, on purpose. The motor lag is part of the simulated plant: it runs on the node's
ROS clock, like the simulator that integrates the thrust (with ``use_sim_time``, and in
``enbarr scenario``, that is the simulated clock, so a transient does not depend on how fast
the machine runs). The command watchdog stands for the ESC's own firmware and stays on the
monotonic wall clock (``framework.driver.CommandWatchdog``): a real ESC goes neutral when its
signal stops for that long in real time, whatever a simulated clock says.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from sensor_msgs.msg import JointState

from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_plugins.thrusters.common import MAX_FUTURE_SPEC, ThrusterDriver

SPECS = [
    ParamSpec('time_constant', 0.05, 'First-order thrust response time constant', 's', 0.0,
              5.0),
    MAX_FUTURE_SPEC,
]


@dataclass(frozen=True)
class SimThrustersSettings:
    """Settings of ``SimThrustersNode`` (see ``SPECS``)."""

    time_constant: float  # [s]
    max_future: float     # time policy of thruster_commands [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimThrustersSettings:
        """Build from the declared parameters' values."""
        return cls(time_constant=v['time_constant'], max_future=v['max_future'])


class SimThrustersNode(ThrusterDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_control', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._fwd = np.array([t.max_forward for t in self.thrusters])
        self._rev = np.array([t.max_reverse for t in self.thrusters])
        self.settings: SimThrustersSettings
        self.bind_settings(SPECS, SimThrustersSettings.from_params, self._apply)
        self.thrust = np.zeros(len(self.names))    # produced [N]
        self._last_apply_ns: int | None = None
        self._thrust_pub = self.create_topic_publisher(topics.SIM_THRUST)
        self.subscribe_commands()

    def _apply(self, settings: SimThrustersSettings) -> None:
        self.settings = settings
        self.commands.set_max_future(settings.max_future)

    def apply(self, cmd: np.ndarray, now_ns: int) -> None:
        """Apply ``cmd`` (normalized) at ``now_ns`` on the node's clock; caller holds the lock.

        The lag advances by the clock time since the previous output (none if the clock went
        back: a restarted simulation), and the outputs are stamped ``now_ns``.
        """
        target = np.where(cmd >= 0.0, cmd * self._fwd, cmd * self._rev)
        tc = self.settings.time_constant
        last, self._last_apply_ns = self._last_apply_ns, now_ns
        # The lag is skipped only from rest (thrust cut by write_neutral, or never set): a
        # command of 0 is not a cut, the motor spins down and the next command goes on from
        # the thrust of that moment.
        if tc > 0.0 and last is not None and self.thrust.any():
            # First-order motor: f += (f* - f)(1 - exp(-dt / T)), exact for a held f*.
            alpha = 1.0 - math.exp(-max(now_ns - last, 0) * 1e-9 / tc)
            self.thrust = self.thrust + alpha * (target - self.thrust)
        else:
            self.thrust = target
        self.command = cmd
        self.neutral = not cmd.any()
        self.publish_output(cmd, now_ns)
        thrust = new(JointState)
        thrust.name, thrust.effort = self.names, self.thrust.tolist()
        convert.ns_to_stamp(now_ns, thrust.header.stamp)
        thrust.header.frame_id = topics.BODY_FRAME
        self._thrust_pub.publish(thrust)

    def write_neutral(self) -> None:
        """Command every thruster to neutral now (motor thrust cut, not ramped)."""
        self.neutral = True
        self.thrust = np.zeros(len(self.names))  # cut: the lag starts again from rest
        self.apply(np.zeros(len(self.names)), self.now_ns())
