"""Simulated 3-DOF surface vessel with azimuth thrusters (``models.vessel3dof``).

The vessel (``vessel.*``) and its azimuths (``azimuth_names``, ``azimuths.<name>.*``) come from
the profile: the CS Saucer's manual model in ``saucer_core.yaml``, another vessel in its own
profile. Each step of 1/``rate``: the azimuth actuators move toward the latest
``sim/azimuth_command`` (first-order thrust, rate-limited servos; neutral when commands stop
for ``command_timeout``, as the Arduino's outputs would), the vessel is integrated with their
force under the scenario's current and force bias, and the truth goes out on ``sim/odometry``
(which the simulated motion capture measures). The current can vary slowly: a sinusoid of
``current_amplitude`` and ``current_period`` on top of ``current``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import threading
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import JointState

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.models.vessel3dof import (AzimuthActuators, current_at, Vessel3Dof,
                                           Vessel3DofParams)
from enbarr_core.allocation.layout_params import declare_azimuths
from enbarr_core.models.vessel3dof_params import VESSEL_SPECS, vessel_from_params
from enbarr_core.framework.node import EnbarrNode, sim_steps
from enbarr_core.framework.params import ParamSpec

MAX_CATCH_UP = 10

SPECS = [
    ParamSpec('rate', 100.0, 'Integration rate', 'Hz', 1.0, 2000.0, read_only=True),
    *VESSEL_SPECS,
    ParamSpec('current', [0.0, 0.0], 'Water current in odom (east, north)', 'm/s', -5.0, 5.0),
    ParamSpec('current_amplitude', [0.0, 0.0], 'Slow variation of the current (east, north)',
              'm/s', -5.0, 5.0),
    ParamSpec('current_period', 60.0, 'Period of the current variation', 's', 1e-3, 1e6),
    ParamSpec('bias', [0.0, 0.0, 0.0], 'Constant force bias in odom (X east, Y north, N)',
              'N, N m', -100.0, 100.0),
    ParamSpec('command_timeout', 0.25, 'Azimuths go neutral when commands stop this long', 's',
              0.001, 10.0),
    ParamSpec('initial', [0.0, 0.0, 0.0], 'Start pose (x, y, psi) in odom', 'm, rad', -1e6,
              1e6),
]


@dataclass(frozen=True)
class Vessel3DofSimulatorSettings:
    """Settings of ``Vessel3DofSimulatorNode`` (see ``SPECS``)."""

    rate: float                              # [Hz]
    vessel: Vessel3DofParams                 # model
    current: tuple[float, float]             # world (east, north) [m/s]
    current_amplitude: tuple[float, float]   # [m/s]
    current_period: float                    # [s]
    bias: tuple[float, float, float]         # world force bias [N, N, N m]
    command_timeout: float                   # [s]
    initial: tuple[float, float, float]      # start pose [m, m, rad]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> Vessel3DofSimulatorSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        for k, n in (('current', 2), ('current_amplitude', 2), ('bias', 3), ('initial', 3)):
            if len(v[k]) != n:
                raise ValueError(f'{k}: expected {n} values, got {len(v[k])}')
        return cls(v['rate'], vessel_from_params(v), tuple(v['current']),  # type: ignore
                   tuple(v['current_amplitude']), v['current_period'],  # type: ignore
                   tuple(v['bias']), v['command_timeout'], tuple(v['initial']))  # type: ignore


class Vessel3DofSimulatorNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'simulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._lock = threading.Lock()
        self.azimuths = declare_azimuths(self)
        self._index = {a.name: i for i, a in enumerate(self.azimuths)}
        self.actuators = AzimuthActuators(self.azimuths)
        self.settings: Vessel3DofSimulatorSettings
        self.bind_settings(SPECS, Vessel3DofSimulatorSettings.from_params, self._apply)
        v = self.settings
        self.eta = np.array(v.initial, dtype=float)
        self.nu = np.zeros(3)
        self.period_ns = round(1e9 / v.rate)
        self.time_ns = 0
        self.steps = 0
        self.time_skips = 0
        self._cmd_thrust = np.zeros(len(self.azimuths))
        self._cmd_angle = np.zeros(len(self.azimuths))
        self._cmd_ns: int | None = None
        self._odom_pub = self.create_topic_publisher(topics.SIM_ODOMETRY)
        self.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, self._on_command)
        self.create_rate_loop(v.rate, self.step)

    def _apply(self, v: Vessel3DofSimulatorSettings) -> None:
        with self._lock:
            self.model = Vessel3Dof(v.vessel)
            self.settings = v
            self._timeout_ns = int(v.command_timeout * 1e9)
            self._current = tuple(float(c) for c in v.current)
            self._current_amplitude = tuple(float(a) for a in v.current_amplitude)
            self._bias = list(v.bias)

    def _on_command(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.effort) or len(msg.name) != len(msg.position):
            return
        thrust, angle = self._cmd_thrust.copy(), self._cmd_angle.copy()
        for name, f, a in zip(msg.name, msg.effort, msg.position):
            i = self._index.get(name)
            if i is None or not (math.isfinite(f) and math.isfinite(a)):
                return
            thrust[i], angle[i] = f, a
        self._cmd_thrust, self._cmd_angle = thrust, angle
        self._cmd_ns = self.now_ns()

    def current_at(self, t_s: float) -> tuple[float, float]:
        """Return the current (east, north) [m/s] at simulated time ``t_s`` [s]."""
        return current_at(t_s, self._current, self._current_amplitude,
                          self.settings.current_period)

    def step(self) -> None:
        """Advance to the clock's present (as RovSimulatorNode.step) and publish the truth."""
        now = self.now_ns()
        if self.time_ns == 0:
            self.time_ns = now - self.period_ns
        n, dt, skipped = sim_steps(self.time_ns, now, self.period_ns, MAX_CATCH_UP)
        if n == 0:
            return
        self.time_skips += skipped
        stale = self._cmd_ns is None or now - self._cmd_ns > self._timeout_ns
        thrust = np.zeros_like(self._cmd_thrust) if stale else self._cmd_thrust
        angle = self.actuators.angle if stale else self._cmd_angle
        bias = self._bias
        start = now - round(n * dt * 1e9)
        with self._lock:
            for k in range(1, n + 1):
                self.actuators.step(thrust, angle, dt)
                current = self.current_at((start + k * dt * 1e9) * 1e-9)
                self.eta, self.nu = self.model.step(self.eta, self.nu, self.actuators.tau(),
                                                    dt, current=current, bias=bias)
        self.time_ns = now
        self.steps += n
        msg = new(Odometry)
        convert.ns_to_stamp(self.time_ns, msg.header.stamp)
        msg.header.frame_id = topics.WORLD_FRAME
        msg.child_frame_id = topics.BODY_FRAME
        convert.set_pose_eta(msg.pose.pose, self.eta)
        convert.set_twist_nu3(msg.twist.twist, self.nu)
        self._odom_pub.publish(msg)
