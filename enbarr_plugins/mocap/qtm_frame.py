"""Where QTM's global frame sits in ``odom``, for the Qualisys driver and its emulator.

QTM's global frame is whatever its calibration (the L-frame) made it; ``up`` says which of
its axes points up (``z``, QTM's default, or ``y``), and ``yaw`` [rad] and ``x``/``y`` [m]
place it in ``odom`` (ENU)::

    p_odom = Rz(yaw) A p_qtm / 1000 + [x, y, 0],    R_odom_body = Rz(yaw) A R_qtm_body

with A = I for ``z`` up and A mapping (x, y, z)_qtm -> (x, -z, y) for ``y`` up. No ROS here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np

_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class QtmFrame:
    """Where QTM's global frame sits in ``odom`` (see the module docstring)."""

    yaw: float = 0.0     # [rad]
    x: float = 0.0       # [m]
    y: float = 0.0       # [m]
    up: str = 'z'        # 'z' or 'y'
    rotation: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Precompute Rz(yaw) A."""
        if self.up not in ('z', 'y'):
            raise ValueError(f"frame.up: 'z' or 'y', got {self.up!r}")
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        object.__setattr__(self, 'rotation', rz @ (_Y_UP if self.up == 'y' else np.eye(3)))

    def to_odom(self, position_mm: Any, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """QTM position [mm] and body rotation -> odom position [m] and rotation."""
        p = self.rotation @ (np.asarray(position_mm, dtype=float) * 1e-3)
        return p + np.array([self.x, self.y, 0.0]), self.rotation @ rotation

    def from_odom(self, position_m: Any, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Odom position [m] and rotation -> QTM position [mm] and rotation (the emulator)."""
        p = np.asarray(position_m, dtype=float) - np.array([self.x, self.y, 0.0])
        return self.rotation.T @ p * 1e3, self.rotation.T @ rotation
