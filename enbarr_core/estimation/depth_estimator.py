"""Vertical position and velocity of an ROV from a pressure sensor and the accelerometer.

Pure (no ROS). The pressure sensor measures depth well but slowly and noisily (a few
millimetres of noise at a few tens of hertz), the accelerometer measures vertical
acceleration fast but with a bias that integrates into drift; neither gives the vertical
velocity a depth-hold loop needs. ArduSub fuses them in its inertial navigation (a
complementary filter of barometer and accelerometer); here it is the equivalent Kalman filter
(filterpy), state

    x = [z, w, b]    z altitude of the sensor in odom (ENU, up; -depth) [m], w = z_dot [m/s],
                     b the accelerometer's vertical bias [m/s^2]

driven by the measured vertical acceleration a_m (the specific force rotated into odom by the
attitude, minus g): z_dot = w, w_dot = a_m - b, b_dot = 0 (+ white noises). Discretised exactly
for a held a_m over dt:

    F = [[1, dt, -dt^2/2], [0, 1, -dt], [0, 0, 1]],   B = [dt^2/2, dt, 0]^T,
    Q = q_a [[dt^4/4, dt^3/2, 0], [dt^3/2, dt^2, 0], [0, 0, 0]] + q_b diag(0, 0, dt)

with q_a the accelerometer's noise variance [(m/s^2)^2] and q_b the bias random walk
[(m/s^2)^2/s]. A depth measurement d with variance r updates z = -d (H = [1, 0, 0]).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_core.estimation.filterpy_kalman import KalmanFilter

Vector = NDArray[np.float64]


@dataclass(frozen=True)
class DepthEstimatorSettings:
    """Noise model of :class:`DepthEstimator`."""

    accel_noise: float       # standard deviation of the vertical acceleration [m/s^2]
    bias_walk: float         # bias random walk [m/s^2 / sqrt(s)]
    initial_bias_std: float  # standard deviation of the bias at start [m/s^2]
    max_dt: float            # a prediction longer than this is not trusted: reset [s]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` naming the first bad field."""
        for name in ('accel_noise', 'bias_walk', 'initial_bias_std', 'max_dt'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name}: {value} must be finite and > 0')


class DepthEstimator:
    """The filter of the module docstring. Not started until the first depth measurement."""

    def __init__(self, settings: DepthEstimatorSettings) -> None:
        settings.validate()
        self.settings = settings
        self.kf: KalmanFilter | None = None
        self.stamp_ns: int | None = None   # time of the state

    @property
    def started(self) -> bool:
        """Whether a depth measurement has started the filter."""
        return self.kf is not None

    def reset(self) -> None:
        """Forget the state: the next depth measurement starts again."""
        self.kf = None
        self.stamp_ns = None

    def _start(self, depth: float, variance: float, stamp_ns: int) -> None:
        kf = KalmanFilter(dim_x=3, dim_z=1, dim_u=1)
        kf.x = np.array([[-depth], [0.0], [0.0]])
        # velocity unknown within 1 m/s; bias as configured
        kf.P = np.diag([variance, 1.0, self.settings.initial_bias_std ** 2])
        kf.H = np.array([[1.0, 0.0, 0.0]])
        self.kf = kf
        self.stamp_ns = stamp_ns

    def predict(self, accel_up: float, stamp_ns: int) -> None:
        """Move the state to ``stamp_ns`` with the vertical acceleration ``accel_up`` [m/s^2].

        ``accel_up``: the specific force in odom's z minus g (0 at rest, + accelerating up).
        Ignored before the filter has started or for a stamp not after the state's; a gap
        longer than ``max_dt`` resets the filter (the integration cannot be trusted over it).
        """
        if self.kf is None or self.stamp_ns is None or stamp_ns <= self.stamp_ns:
            return
        dt = (stamp_ns - self.stamp_ns) * 1e-9
        if dt > self.settings.max_dt:
            self.reset()
            return
        s = self.settings
        f = np.array([[1.0, dt, -0.5 * dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
        b = np.array([[0.5 * dt * dt], [dt], [0.0]])
        qa, qb = s.accel_noise ** 2, s.bias_walk ** 2
        q = qa * np.array([[dt ** 4 / 4.0, dt ** 3 / 2.0, 0.0],
                           [dt ** 3 / 2.0, dt * dt, 0.0], [0.0, 0.0, 0.0]])
        q[2, 2] = qb * dt
        self.kf.predict(u=np.array([[accel_up]]), B=b, F=f, Q=q)
        self.stamp_ns = stamp_ns

    def update(self, depth: float, variance: float, stamp_ns: int) -> bool:
        """Correct with a depth [m, positive down] of ``variance`` [m^2] measured at ``stamp_ns``.

        The first one starts the filter. A measurement older than the state is applied at the
        state's time (the error is the vertical speed times the delay, well inside the
        sensor's noise at the rates used); False when ``depth`` or ``variance`` is not a
        finite number (>0 for the variance), which changes nothing.
        """
        if not (math.isfinite(depth) and math.isfinite(variance) and variance > 0.0):
            return False
        if self.kf is None:
            self._start(depth, variance, stamp_ns)
            return True
        self.kf.update(np.array([[-depth]]), R=np.array([[variance]]))
        return True

    @property
    def depth(self) -> float:
        """Estimated depth [m, positive down] (NaN before the start)."""
        return math.nan if self.kf is None else -float(self.kf.x[0, 0])

    @property
    def vertical_velocity(self) -> float:
        """Estimated w = z_dot [m/s, positive up] (NaN before the start)."""
        return math.nan if self.kf is None else float(self.kf.x[1, 0])

    @property
    def bias(self) -> float:
        """Estimated vertical accelerometer bias [m/s^2] (NaN before the start)."""
        return math.nan if self.kf is None else float(self.kf.x[2, 0])

    def covariance(self) -> Vector:
        """Return the state covariance (3, 3) (NaN before the start)."""
        if self.kf is None:
            return np.full((3, 3), math.nan)
        out: Vector = self.kf.P.copy()
        return out
