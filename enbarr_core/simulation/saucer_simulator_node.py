"""Simulated CS Saucer: the 3-DOF model of the manual (section 1.4) with three azimuths.

Each step of 1/``rate``: the azimuth actuators move toward the latest ``sim/azimuth_command``
(first-order thrust, rate-limited servos; neutral when commands stop for ``command_timeout``,
as the Arduino's outputs would), the vessel is integrated with their force under the
scenario's current and force bias, and the truth goes out on ``sim/odometry`` (which the
simulated motion capture measures). The current can vary slowly: a sinusoid of
``current_amplitude`` and ``current_period`` on top of ``current``.
"""

from __future__ import annotations

import math
import threading
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import JointState

from enbarr_interfaces import convert, topics

from enbarr_core.models.vessel3dof import AzimuthActuators, Vessel3Dof, Vessel3DofParams
from enbarr_core.allocation.layout_params import declare_azimuths
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.node import EnbarrNode, sim_steps
from enbarr_core.framework.params import ParamSpec

MAX_CATCH_UP = 10

SPECS = [
    ParamSpec('rate', 100.0, 'Integration rate', 'Hz', 1.0, 2000.0, read_only=True),
    ParamSpec('vessel.M', [9.51, 9.51, 0.116], 'Inertia M (manual eq. 1.2)', 'kg, kg m^2',
              1e-6, 1e6),
    ParamSpec('vessel.D', [1.96, 1.96, 0.168], 'Linear damping D (manual eq. 1.4)',
              'N s/m, N m s', 0.0, 1e6),
    ParamSpec('vessel.Dn', [7.095, 7.095, 7.095], 'Nonlinear damping D_n(nu) = diag(Dn |nu|) '
              '(manual eq. 1.5)', 'N s^2/m^2, N m s^2', 0.0, 1e6),
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


class SaucerSimulatorNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'simulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._lock = threading.Lock()
        self.azimuths = declare_azimuths(self)
        self._index = {a.name: i for i, a in enumerate(self.azimuths)}
        self.actuators = AzimuthActuators(self.azimuths)
        self.settings: dict[str, Any] = {}
        self.bind_settings(SPECS, self._build, self._apply)
        v = self.settings
        if len(v['initial']) != 3:
            raise ConfigurationError(f'node {node_name!r}: initial needs x, y, psi',
                                     parameter='initial')
        self.eta = np.array(v['initial'], dtype=float)
        self.nu = np.zeros(3)
        self.period_ns = round(1e9 / v['rate'])
        self.time_ns = 0
        self.steps = 0
        self.time_skips = 0
        self._cmd_thrust = np.zeros(len(self.azimuths))
        self._cmd_angle = np.zeros(len(self.azimuths))
        self._cmd_ns: int | None = None
        self._odom_pub = self.create_topic_publisher(topics.SIM_ODOMETRY)
        self.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, self._on_command)
        self.create_rate_loop(v['rate'], self.step)

    @staticmethod
    def _build(v: dict[str, Any]) -> dict[str, Any]:
        Vessel3DofParams.from_mapping({k: v[f'vessel.{k}'] for k in ('M', 'D', 'Dn')})
        for k, n in (('current', 2), ('current_amplitude', 2), ('bias', 3)):
            if len(v[k]) != n:
                raise ValueError(f'{k}: expected {n} values, got {len(v[k])}')
        return v

    def _apply(self, v: dict[str, Any]) -> None:
        with self._lock:
            self.model = Vessel3Dof(Vessel3DofParams.from_mapping(
                {k: v[f'vessel.{k}'] for k in ('M', 'D', 'Dn')}))
            self.settings = v
            self._timeout_ns = int(v['command_timeout'] * 1e9)

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
        self._cmd_ns = self.get_clock().now().nanoseconds

    def current_at(self, t_s: float) -> np.ndarray:
        s = self.settings
        phase = math.sin(2.0 * math.pi * t_s / s['current_period'])
        return np.array(s['current']) + phase * np.array(s['current_amplitude'])

    def step(self) -> None:
        """Advance to the clock's present (as RovSimulatorNode.step) and publish the truth."""
        now = self.get_clock().now().nanoseconds
        if self.time_ns == 0:
            self.time_ns = now - self.period_ns
        n, dt, skipped = sim_steps(self.time_ns, now, self.period_ns, MAX_CATCH_UP)
        if n == 0:
            return
        self.time_skips += skipped
        stale = self._cmd_ns is None or now - self._cmd_ns > self._timeout_ns
        thrust = np.zeros_like(self._cmd_thrust) if stale else self._cmd_thrust
        angle = self.actuators.angle if stale else self._cmd_angle
        bias = self.settings['bias']
        start = now - round(n * dt * 1e9)
        with self._lock:
            for k in range(1, n + 1):
                self.actuators.step(thrust, angle, dt)
                current = self.current_at((start + k * dt * 1e9) * 1e-9)
                self.eta, self.nu = self.model.step(self.eta, self.nu, self.actuators.tau(),
                                                    dt, current=current, bias=bias)
        self.time_ns = now
        self.steps += n
        msg = Odometry()
        convert.ns_to_stamp(self.time_ns, msg.header.stamp)
        msg.header.frame_id = topics.WORLD_FRAME
        msg.child_frame_id = topics.BODY_FRAME
        convert.set_pose_eta(msg.pose.pose, self.eta)
        convert.set_twist_nu3(msg.twist.twist, self.nu)
        self._odom_pub.publish(msg)
