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

from collections.abc import Mapping, Sequence
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
    ParamSpec('full_speed', 320.0, 'Shaft speed at full throttle, reported on '
              'thruster_sensors (set it from the thruster data sheet at the supply voltage)',
              'rad/s', 1.0, 10000.0),
    ParamSpec('fouled', [''], 'Fault injection, name:factor per fouled thruster: the rotor '
              'turns at factor times its speed (0 blocked, 0.5 tangled) and thrust goes with '
              "the speed squared; [''] none"),
]


def parse_fouled(entries: Sequence[str], names: Sequence[str]) -> dict[str, float]:
    """``name:factor`` entries -> {name: factor}; ValueError naming the bad entry."""
    out: dict[str, float] = {}
    for i, entry in enumerate(entries):
        if entry == '':
            continue
        name, sep, value = entry.partition(':')
        try:
            factor = float(value) if sep else math.nan
        except ValueError:
            factor = math.nan
        if name not in names:
            raise ValueError(f'fouled[{i}] = {entry!r}: no thruster named {name!r} '
                             f'(thrusters: {", ".join(names)})')
        if not 0.0 <= factor <= 1.0:
            raise ValueError(f'fouled[{i}] = {entry!r}: want name:factor, factor in 0..1')
        out[name] = factor
    return out


@dataclass(frozen=True)
class SimThrustersSettings:
    """Settings of ``SimThrustersNode`` (see ``SPECS``)."""

    time_constant: float         # [s]
    max_future: float            # time policy of thruster_commands [s]
    full_speed: float            # [rad/s]
    fouled: dict[str, float]     # name -> speed factor (fault injection)

    @classmethod
    def from_params(cls, v: Mapping[str, Any], names: Sequence[str]
                    ) -> SimThrustersSettings:
        """Build from the declared parameters' values."""
        return cls(time_constant=v['time_constant'], max_future=v['max_future'],
                   full_speed=v['full_speed'], fouled=parse_fouled(v['fouled'], names))


class SimThrustersNode(ThrusterDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'thruster_control', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._fwd = np.array([t.max_forward for t in self.thrusters])
        self._rev = np.array([t.max_reverse for t in self.thrusters])
        self.settings: SimThrustersSettings
        self._factor = np.ones(len(self.names))   # speed factor of each rotor (fouling)
        self.bind_settings(SPECS, lambda v: SimThrustersSettings.from_params(v, self.names),
                           self._apply)
        self.thrust = np.zeros(len(self.names))    # what a clean rotor would produce [N]
        self._last_apply_ns: int | None = None
        self._thrust_pub = self.create_topic_publisher(topics.SIM_THRUST)
        self._sensors_pub = self.create_topic_publisher(topics.THRUSTER_SENSORS)
        self.subscribe_commands()

    def _apply(self, settings: SimThrustersSettings) -> None:
        self.settings = settings
        self.commands.set_max_future(settings.max_future)
        self._factor = np.array([settings.fouled.get(n, 1.0) for n in self.names])

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
        # A fouled rotor turns at factor k of a clean one's speed; thrust goes with the speed
        # squared (T = K_T rho D^4 n|n|), so it gives k^2 of the thrust.
        k = self._factor
        thrust = new(JointState)
        thrust.name, thrust.effort = self.names, (k * k * self.thrust).tolist()
        convert.ns_to_stamp(now_ns, thrust.header.stamp)
        thrust.header.frame_id = topics.BODY_FRAME
        self._thrust_pub.publish(thrust)
        # The clean rotor's speed from its thrust: n = sign(T) sqrt(|T| / T_max) n_full
        limit = np.where(self.thrust >= 0.0, self._fwd, self._rev)
        fraction = np.sqrt(np.abs(self.thrust) / limit)
        sensors = new(JointState)
        sensors.name = self.names
        sensors.velocity = (np.sign(self.thrust) * fraction * k
                            * self.settings.full_speed).tolist()
        sensors.effort = [math.nan] * len(self.names)
        sensors.header.stamp = thrust.header.stamp
        sensors.header.frame_id = topics.BODY_FRAME
        self._sensors_pub.publish(sensors)

    def write_neutral(self) -> None:
        """Command every thruster to neutral now (motor thrust cut, not ramped)."""
        self.neutral = True
        self.thrust = np.zeros(len(self.names))  # cut: the lag starts again from rest
        self.apply(np.zeros(len(self.names)), self.now_ns())
