"""Conversions between standard messages and numpy arrays.

One place for them, so every node agrees on component order and units:
``nu``/``tau`` are ``[u, v, w, p, q, r]`` / ``[X, Y, Z, K, M, N]`` (linear then angular),
quaternions are ``[x, y, z, w]``.
"""

from __future__ import annotations

import math
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Twist, Vector3, Wrench
import numpy as np
from numpy.typing import NDArray
from rcl_interfaces.msg import ParameterType, ParameterValue

from enbarr_interfaces.fastmsg import new

NS_PER_S = 1_000_000_000


def stamp_to_ns(stamp: Time) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    ns: int = stamp.sec * NS_PER_S + stamp.nanosec  # the message's fields are untyped
    return ns


def ns_to_stamp(ns: int, out: Time | None = None) -> Time:
    """Integer nanoseconds -> ``builtin_interfaces/Time`` (filled in place when ``out``)."""
    out = out if out is not None else new(Time)
    out.sec, out.nanosec = divmod(int(ns), NS_PER_S)
    return out


def vector3_to_array(v: Vector3) -> NDArray[np.float64]:
    """Return a ``Vector3`` as a (3,) array."""
    return np.array((v.x, v.y, v.z))


def set_vector3(v: Vector3, a: Any) -> None:
    """Set a ``Vector3`` from 3 numbers."""
    v.x, v.y, v.z = float(a[0]), float(a[1]), float(a[2])


def quaternion_to_array(q: Any) -> NDArray[np.float64]:
    """``geometry_msgs/Quaternion`` -> ``[x, y, z, w]``."""
    return np.array((q.x, q.y, q.z, q.w))


def set_quaternion(q: Any, a: Any) -> None:
    """Set a ``Quaternion`` from [x, y, z, w]."""
    q.x, q.y, q.z, q.w = float(a[0]), float(a[1]), float(a[2]), float(a[3])


def twist_to_nu(t: Twist) -> NDArray[np.float64]:
    """``geometry_msgs/Twist`` -> nu = [u, v, w, p, q, r] [m/s, rad/s]."""
    return np.array((t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z))


def set_twist(t: Twist, nu: Any) -> None:
    """Set a ``Twist`` from nu = [u, v, w, p, q, r]."""
    set_vector3(t.linear, nu[:3])
    set_vector3(t.angular, nu[3:6])


def wrench_to_tau(w: Wrench) -> NDArray[np.float64]:
    """``geometry_msgs/Wrench`` -> tau = [X, Y, Z, K, M, N] [N, N m]."""
    return np.array((w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z))


def set_wrench(w: Wrench, tau: Any) -> None:
    """Set a ``Wrench`` from tau = [X, Y, Z, K, M, N]."""
    set_vector3(w.force, tau[:3])
    set_vector3(w.torque, tau[3:6])


def yaw_to_quaternion(psi: float, out: Any) -> None:
    """Write the quaternion of a rotation ``psi`` [rad] about z into ``out``."""
    out.x, out.y = 0.0, 0.0
    out.z, out.w = math.sin(0.5 * psi), math.cos(0.5 * psi)


def quaternion_to_yaw(q: Any) -> float:
    """Yaw [rad] (about z, ENU: counter-clockwise from east) of a ``Quaternion``."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def pose_to_eta(pose: Any) -> NDArray[np.float64]:
    """``geometry_msgs/Pose`` -> eta = [x, y, psi] of a 3-DOF vessel."""
    return np.array((pose.position.x, pose.position.y, quaternion_to_yaw(pose.orientation)))


def set_pose_eta(pose: Any, eta: Any) -> None:
    """Set a ``Pose`` from eta = [x, y, psi] (planar)."""
    pose.position.x, pose.position.y, pose.position.z = float(eta[0]), float(eta[1]), 0.0
    yaw_to_quaternion(float(eta[2]), pose.orientation)


def transform_to_eta(tf: Any) -> NDArray[np.float64]:
    """``geometry_msgs/Transform`` -> eta = [x, y, psi]; NaN stays NaN.

    psi is NaN when any quaternion component is not finite (see ``set_transform_eta``).
    """
    q = tf.rotation
    finite = all(math.isfinite(c) for c in (q.x, q.y, q.z, q.w))
    return np.array((tf.translation.x, tf.translation.y,
                     quaternion_to_yaw(q) if finite else math.nan))


def set_transform_eta(tf: Any, eta: Any) -> None:
    """Set a ``Transform`` from eta = [x, y, psi] (planar); a NaN component stays NaN.

    A NaN psi makes all four quaternion components NaN.
    """
    tf.translation.x, tf.translation.y, tf.translation.z = float(eta[0]), float(eta[1]), 0.0
    if math.isnan(float(eta[2])):
        q = tf.rotation
        q.x = q.y = q.z = q.w = math.nan
    else:
        yaw_to_quaternion(float(eta[2]), tf.rotation)


def twist_to_nu3(t: Twist) -> NDArray[np.float64]:
    """``geometry_msgs/Twist`` -> nu = [u, v, r] of a 3-DOF vessel."""
    return np.array((t.linear.x, t.linear.y, t.angular.z))


def set_twist_nu3(t: Twist, nu: Any) -> None:
    """Set a ``Twist`` from nu = [u, v, r] (planar)."""
    t.linear.x, t.linear.y, t.angular.z = float(nu[0]), float(nu[1]), float(nu[2])


def wrench_to_tau3(w: Wrench) -> NDArray[np.float64]:
    """``geometry_msgs/Wrench`` -> tau = [X, Y, N] of a 3-DOF vessel."""
    return np.array((w.force.x, w.force.y, w.torque.z))


def set_wrench_tau3(w: Wrench, tau: Any) -> None:
    """Set a ``Wrench`` from tau = [X, Y, N] (planar)."""
    w.force.x, w.force.y, w.torque.z = float(tau[0]), float(tau[1]), float(tau[2])


def set_covariance3(field: Any, cov: NDArray[np.float64]) -> None:
    """Write a 3x3 covariance into a ``float64[9]`` message field, row-major."""
    field[:] = np.asarray(cov, dtype=float).reshape(9)


#: Up to this many elements ``all_finite`` tests them one by one as Python floats (numpy's
#: per-call cost dominates on a few elements: ``docs/benchmarks.md``); larger arrays in numpy.
_SMALL = 16


def all_finite(*arrays: Any) -> bool:
    """Whether every element of every array (or sequence, or number) is finite.

    The check every node makes on every sample's vectors before it uses them: NaN, +inf and
    -inf are refused, exactly as ``np.isfinite`` refuses them.
    """
    isfinite = math.isfinite
    for a in arrays:
        if type(a) is float:
            if not isfinite(a):
                return False
            continue
        a = np.asarray(a, dtype=float) if type(a) is not np.ndarray else a
        if a.size > _SMALL:
            if not np.isfinite(a).all():
                return False
            continue
        for v in a.ravel().tolist():
            if not isfinite(v):
                return False
    return True


def parameter_value_to_python(value: ParameterValue) -> Any:
    """Return the typed content of an ``rcl_interfaces/ParameterValue`` (``None`` when NOT_SET)."""
    t = value.type
    if t == ParameterType.PARAMETER_BOOL:
        return bool(value.bool_value)
    if t == ParameterType.PARAMETER_INTEGER:
        return int(value.integer_value)
    if t == ParameterType.PARAMETER_DOUBLE:
        return float(value.double_value)
    if t == ParameterType.PARAMETER_STRING:
        return str(value.string_value)
    if t == ParameterType.PARAMETER_BYTE_ARRAY:
        return bytes(b[0] if isinstance(b, bytes) else b for b in value.byte_array_value)
    if t == ParameterType.PARAMETER_BOOL_ARRAY:
        return [bool(v) for v in value.bool_array_value]
    if t == ParameterType.PARAMETER_INTEGER_ARRAY:
        return [int(v) for v in value.integer_array_value]
    if t == ParameterType.PARAMETER_DOUBLE_ARRAY:
        return [float(v) for v in value.double_array_value]
    if t == ParameterType.PARAMETER_STRING_ARRAY:
        return [str(v) for v in value.string_array_value]
    return None


def python_to_parameter_value(value: Any) -> ParameterValue:
    """Convert a Python bool/int/float/str (or homogeneous list) to a ``ParameterValue``."""
    pv = ParameterValue()
    if isinstance(value, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, value
    elif isinstance(value, int):
        pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, value
    elif isinstance(value, float):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, value
    elif isinstance(value, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, value
    elif isinstance(value, (list, tuple)) and value and all(isinstance(v, bool) for v in value):
        pv.type, pv.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, list(value)
    elif isinstance(value, (list, tuple)) and value and all(
            isinstance(v, int) and not isinstance(v, bool) for v in value):
        pv.type, pv.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, list(value)
    elif isinstance(value, (list, tuple)) and value and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        pv.type = ParameterType.PARAMETER_DOUBLE_ARRAY
        pv.double_array_value = [float(v) for v in value]
    elif isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, list(value)
    else:
        raise TypeError(f'cannot carry {value!r} in an rcl_interfaces/ParameterValue')
    return pv


def parameter_value_is_finite(value: ParameterValue) -> bool:
    """Return False when a double (or double array) value holds NaN or Inf."""
    if value.type == ParameterType.PARAMETER_DOUBLE:
        return math.isfinite(value.double_value)
    if value.type == ParameterType.PARAMETER_DOUBLE_ARRAY:
        return all(math.isfinite(v) for v in value.double_array_value)
    return True
