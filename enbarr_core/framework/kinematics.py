"""Rotations and kinematics (Fossen 2021, ch. 2), in REP-103 frames.

World frame: ENU (x east, y north, z up). Body frame: FLU (x forward, y left, z up).
Quaternions are ``[x, y, z, w]`` unit quaternions rotating body vectors into the world frame.
Euler angles are ZYX (yaw psi about z, then pitch theta about y, then roll phi about x).
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

Vector = NDArray[np.float64]


@overload
def ssa(angle: float) -> float: ...
@overload
def ssa(angle: NDArray[np.float64]) -> NDArray[np.float64]: ...


def ssa(angle: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
    """Smallest signed angle: wrap ``angle`` [rad] to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def skew(a: ArrayLike) -> Vector:
    """Skew-symmetric matrix S(a) with S(a) b = a x b (Fossen 2021, eq. 2.9)."""
    x, y, z = np.asarray(a, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def quat_normalize(q: ArrayLike) -> Vector:
    """Return ``q`` scaled to unit norm, with w >= 0 (one of the two equal rotations)."""
    q = np.asarray(q, dtype=float)
    n = math.sqrt(float(q @ q))
    if n == 0.0 or not math.isfinite(n):
        raise ValueError(f'cannot normalize quaternion {q!r}')
    q = q / n
    return -q if q[3] < 0.0 else q


def quat_to_rotmat(q: ArrayLike) -> Vector:
    """Rotation matrix R(q) (body -> world) of a unit quaternion ``[x, y, z, w]``."""
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
        [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
        [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
    ])


def quat_multiply(q1: ArrayLike, q2: ArrayLike) -> Vector:
    """Hamilton product q1 (x) q2 of ``[x, y, z, w]`` quaternions."""
    x1, y1, z1, w1 = np.asarray(q1, dtype=float)
    x2, y2, z2, w2 = np.asarray(q2, dtype=float)
    return np.array([
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
    ])


def quat_conjugate(q: ArrayLike) -> Vector:
    """Inverse of a unit quaternion ``[x, y, z, w]``."""
    x, y, z, w = np.asarray(q, dtype=float)
    return np.array([-x, -y, -z, w])


def quat_from_rotvec(phi: ArrayLike) -> Vector:
    """Quaternion of the rotation vector ``phi`` [rad] (axis times angle), exact."""
    phi = np.asarray(phi, dtype=float)
    angle = math.sqrt(float(phi @ phi))
    if angle < 1e-12:
        # Series: sin(a/2)/a = 1/2 - a^2/48, cos(a/2) = 1 - a^2/8; below 1e-12 rad both
        # corrections (< 1.3e-25) vanish next to 1 in double precision, so they are left out.
        return quat_normalize(np.array([*(0.5 * phi), 1.0]))
    s = math.sin(0.5 * angle) / angle
    return np.array([*(s * phi), math.cos(0.5 * angle)])


def quat_integrate(q: ArrayLike, omega_body: ArrayLike, dt: float) -> Vector:
    """Propagate attitude ``q`` by body rate ``omega_body`` [rad/s] held for ``dt`` [s].

    q_k+1 = q_k (x) exp(omega dt / 2), exact for a constant rate (Fossen 2021, eq. 2.93).
    """
    return quat_normalize(quat_multiply(q, quat_from_rotvec(np.asarray(omega_body) * dt)))


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Vector:
    """Quaternion ``[x, y, z, w]`` of ZYX Euler angles [rad]."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


def quat_to_euler(q: ArrayLike) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] of a unit quaternion ``[x, y, z, w]``."""
    x, y, z, w = np.asarray(q, dtype=float)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def rot_z(psi: float) -> Vector:
    """R(psi) of the 3-DOF model (CS Saucer manual eq. 1.6): body (u, v, r) -> world."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
