"""Simulated thruster control: what a PWM/ESC plugin does, against the simulated vehicle.

Takes ``thruster_commands`` (-1..1 per named thruster), turns them into thrust with each
thruster's limits and a first-order motor lag, and hands the thrust to the simulator
(``sim/thrust``). ``thruster_output`` reports what was applied. Like a real ESC driver it
goes neutral when commands stop for ``command_timeout`` (a crashed controller or a dropped
link) and on ``safe_state`` (every bringup exit path). Commands outside -1..1 are clipped and
counted; a command with NaN/Inf or an unknown thruster name is refused and counted.

Time policy (``framework.stamps``): a command stamped more than ``max_future`` ahead of the
node's clock, or not later than the last applied one (an old command overtaking a newer one),
is refused and counted, never applied; its stamp is the sensor time the latency log measures
from. ``/diagnostics`` reports the node degraded when more than 5 % of a second's commands
are refused.

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

from enbarr_core.framework.driver import REPORT_PERIOD, ActuatorDriver
from enbarr_core.framework.health import InputHealth, worst
from enbarr_core.framework.node import LatencyLog
from enbarr_core.framework.params import ParamSpec
from enbarr_core.framework.stamps import (
    SAME_CLOCK_MAX_FUTURE, StampGate, StampPolicy, StampVerdict)
from enbarr_core.allocation.layout_params import declare_thrusters
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

SPECS = [
    ParamSpec('time_constant', 0.05, 'First-order thrust response time constant', 's', 0.0,
              5.0),
    ParamSpec('max_future', SAME_CLOCK_MAX_FUTURE,
              'Commands stamped further ahead of the node clock are '
              'refused (time policy)', 's', 0.0, 1.0),
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


class SimThrustersNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_control', **kwargs: Any) -> None:
        self.neutral = True
        self.gate = StampGate()
        self.health = InputHealth()
        self._health_values: dict[str, int] = {}
        super().__init__(node_name, timeout_message='thruster commands stopped: thrusters '
                         'neutral', **kwargs)
        self.thrusters = declare_thrusters(self)
        self.names = [t.name for t in self.thrusters]
        self._index = {n: i for i, n in enumerate(self.names)}
        self._fwd = np.array([t.max_forward for t in self.thrusters])
        self._rev = np.array([t.max_reverse for t in self.thrusters])
        self.settings: SimThrustersSettings
        self.bind_settings(SPECS, SimThrustersSettings.from_params, self._apply)
        self.latency = LatencyLog()  # IMU sample stamp -> command applied
        self.command = np.zeros(len(self.names))   # applied, normalized
        self.thrust = np.zeros(len(self.names))    # produced [N]
        self.refused = 0
        self.clipped = 0
        self._last_apply_ns: int | None = None
        self._output_pub = self.create_topic_publisher(topics.THRUSTER_OUTPUT)
        self._thrust_pub = self.create_topic_publisher(topics.SIM_THRUST)
        self.create_topic_subscription(topics.THRUSTER_COMMANDS, self._on_command)

    def _apply(self, settings: SimThrustersSettings) -> None:
        self.settings = settings
        self.gate.policy = StampPolicy(settings.max_future)

    def _on_command(self, msg: JointState) -> None:
        now_ns = self.now_ns()
        taken = accept_command(self, msg, now_ns)
        if taken is None:
            return
        cmd, stamp_ns = taken
        with self.commanding():
            self._output(cmd, now_ns)
        self.latency.add(now_ns - stamp_ns)

    def _output(self, cmd: np.ndarray, now_ns: int) -> None:
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
        stamp = convert.ns_to_stamp(now_ns)
        out = new(JointState)
        out.name, out.effort = self.names, cmd.tolist()
        out.header.stamp = stamp
        out.header.frame_id = topics.BODY_FRAME
        self._output_pub.publish(out)
        thrust = new(JointState)
        thrust.name, thrust.effort = self.names, self.thrust.tolist()
        thrust.header.stamp = stamp
        thrust.header.frame_id = topics.BODY_FRAME
        self._thrust_pub.publish(thrust)

    def is_neutral(self) -> bool:
        """Whether every thruster is commanded to zero."""
        return self.neutral

    def write_neutral(self) -> None:
        """Command every thruster to neutral now (motor thrust cut, not ramped)."""
        self.neutral = True
        self.thrust = np.zeros(len(self.names))  # cut: the lag starts again from rest
        self._output(np.zeros(len(self.names)), self.now_ns())

    def status(self) -> tuple[int, str]:
        """Return the driver's status, degraded while commands are refused.

        Closes the health window: called once per report, before ``status_values``.
        """
        level, message, self._health_values = self.health.report(REPORT_PERIOD)
        return worst(super().status(), (level, message))

    def status_values(self) -> dict[str, Any]:
        """Return the driver counters plus refused and clipped commands."""
        return {**super().status_values(), 'refused': self.refused, 'clipped': self.clipped,
                **self._health_values}

def accept_command(node: Any, msg: JointState, now_ns: int) -> tuple[np.ndarray, int] | None:
    """Apply the checks of ``thruster_commands`` that every thruster plugin makes.

    ``node`` has ``names``, ``_index`` (name -> position), ``gate`` (``StampGate``), ``health``
    (``InputHealth``) and the counters ``refused`` and ``clipped``. Returns the command
    (normalized, in ``names`` order, clipped to -1..1) and its stamp [ns], or None when it is
    refused (unknown name, non-finite value, a name without a value, or the time policy),
    counted in ``refused`` and ``health`` by reason.
    """
    if len(msg.name) != len(msg.effort):
        node.refused += 1
        node.health.refused('thruster_commands', 'invalid')
        return None
    # Python floats until the checks pass (numpy on 6-8 values costs more than the checks).
    values = [0.0] * len(node.names)
    for name, value in zip(msg.name, msg.effort):
        i = node._index.get(name)
        if i is None or not math.isfinite(value):
            node.refused += 1
            node.health.refused('thruster_commands', 'invalid')
            node.get_logger().warn(f'refused thruster command {name}={value}',
                                   throttle_duration_sec=1.0)
            return None
        values[i] = value
    stamp_ns = convert.stamp_to_ns(msg.header.stamp)
    verdict = node.gate.offer(stamp_ns, now_ns)
    if verdict is not StampVerdict.ACCEPTED:
        node.refused += 1
        node.health.refused('thruster_commands', verdict.value)
        return None
    node.health.accepted('thruster_commands')
    if values and (max(values) > 1.0 or min(values) < -1.0):
        node.clipped += 1
        values = [min(max(v, -1.0), 1.0) for v in values]
    return np.array(values, dtype=float), stamp_ns
