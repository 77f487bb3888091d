"""Simulated motion capture (a Qualisys-like pose measurement).

It measures the simulated vessel's pose (``sim/odometry``) and publishes it on ``mocap/pose``
at ``rate``, with white Gaussian position and heading noise and dropouts: scheduled windows
(``dropout_windows``, pairs of start and end times in seconds since the first sample) and
random single-sample losses (``dropout_probability``), as markers hidden behind the lidar or a
person do.

Time: the truth's stamp schedules the measurements; a truth stamped ahead of the clock, or
not later than the last one taken, is refused and counted (``refused``, see
``enbarr_plugins.sim_sensor``): one such truth once silenced the motion capture for as long
as it was ahead.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import PoseStamped
import numpy as np
from nav_msgs.msg import Odometry

from enbarr_core.framework.kinematics import ssa
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_plugins.sim_sensor import TruthSensor

SPECS = [
    ParamSpec('rate', 50.0, 'Measurement rate (at most the simulator rate)', 'Hz', 0.1, 1000.0,
              read_only=True),
    ParamSpec('position_noise', 0.002, 'Position noise, std per sample', 'm', 0.0, 1.0),
    ParamSpec('heading_noise', 0.005, 'Heading noise, std per sample', 'rad', 0.0, 1.0),
    ParamSpec('dropout_windows', [0.0], 'Dropouts: start, end, start, end, ... (seconds since '
              'the first sample); [0.0]: none', 's', 0.0, 1e6),
    ParamSpec('dropout_probability', 0.0, 'Probability that a sample is lost', '', 0.0, 1.0),
    ParamSpec('seed', 2, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
]


@dataclass(frozen=True)
class SimMocapSettings:
    """Settings of ``SimMocapNode`` (see ``SPECS``)."""

    rate: float                                      # [Hz]
    position_noise: float                            # std [m]
    heading_noise: float                             # std [rad]
    dropout_windows: tuple[tuple[float, float], ...]  # (start, end) since the first sample [s]
    dropout_probability: float
    seed: int

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimMocapSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        w = list(v['dropout_windows'])
        windows: tuple[tuple[float, float], ...] = ()
        if w != [0.0]:
            if len(w) % 2 or any(b <= a for a, b in zip(w[::2], w[1::2])):
                raise ValueError('dropout_windows: expected pairs of start < end times')
            windows = tuple(zip(w[::2], w[1::2]))
        return cls(v['rate'], v['position_noise'], v['heading_noise'], windows,
                   v['dropout_probability'], v['seed'])


class SimMocapNode(TruthSensor):
    """See the module docstring."""

    def __init__(self, node_name: str = 'mocap', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimMocapSettings
        self.bind_settings(SPECS, SimMocapSettings.from_params, self._apply)
        self._rng = np.random.default_rng(self.settings.seed)
        self._period_ns = round(1e9 / self.settings.rate)
        self._next_ns: int | None = None
        self._start_ns: int | None = None
        self.published = 0
        self.dropped = 0
        self._pub = self.create_topic_publisher(topics.MOCAP_POSE)
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def status_values(self) -> dict[str, Any]:
        """Return the driver's status, with the count of dropped samples."""
        return {**super().status_values(), 'dropped': self.dropped,
                'refused': self.truth_gate.refused}

    def _apply(self, v: SimMocapSettings) -> None:
        self.settings = v

    def _on_truth(self, truth: Odometry) -> None:
        t = self.admit_truth(truth)
        if t is None:
            return
        if self._next_ns is None:
            self._next_ns = self._start_ns = t
        if t < self._next_ns:
            return
        self._next_ns += self._period_ns * max(1, (t - self._next_ns) // self._period_ns + 1)
        since = (t - self._start_ns) * 1e-9
        s = self.settings
        if (s.dropout_windows and any(a <= since < b for a, b in s.dropout_windows)) or (
                s.dropout_probability > 0.0 and self._rng.random() < s.dropout_probability):
            self.dropped += 1
            return
        # eta = truth + noise in Python floats (the same draws, in the same order, and the
        # same sums as with a 3-element array, which cost more to build than the noise).
        pose = truth.pose.pose
        noise_x, noise_y = self._rng.normal(0.0, s.position_noise, 2).tolist()
        psi = ssa(convert.quaternion_to_yaw(pose.orientation)
                  + float(self._rng.normal(0.0, s.heading_noise)))
        msg = new(PoseStamped)
        msg.header.stamp = truth.header.stamp
        msg.header.frame_id = topics.WORLD_FRAME
        convert.set_pose_eta(msg.pose, (pose.position.x + noise_x, pose.position.y + noise_y,
                                        psi))
        self.published += 1
        self._pub.publish(msg)
        self.sample_received()
