"""Rotations and kinematics (``framework/kinematics.py``) against independent formulations:
rotation matrices built from elementary rotations and Rodrigues' formula (axis-angle), the
quaternion algebra's defining products (i j = k), and hand-computed values.

Tolerance budget: every formulation here is closed-form double-precision arithmetic of a few
dozen operations on numbers of order 1, so agreement is to ~1e-15; ``TOL = 1e-12`` leaves three
decades of margin and is still ten orders below any sign or term error (those move entries by
O(0.1..1) for the angles used).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.framework.kinematics import (
    quat_conjugate, quat_from_euler, quat_from_rotvec, quat_integrate, quat_multiply,
    quat_normalize, quat_to_euler, quat_to_rotmat, rot_z, skew, ssa)

TOL = 1e-12
RNG = np.random.default_rng(20261122)


def Rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def Ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rodrigues(axis, angle: float) -> np.ndarray:
    """R = I + sin(a) K + (1 - cos(a)) K^2, K the cross-product matrix of the unit axis
    (written out here, not with ``skew``)."""
    n = np.asarray(axis, dtype=float)
    n = n / np.linalg.norm(n)
    K = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def axis_angle_quat(axis, angle: float) -> np.ndarray:
    n = np.asarray(axis, dtype=float)
    n = n / np.linalg.norm(n)
    return np.array([*(math.sin(angle / 2) * n), math.cos(angle / 2)])


def random_axes_angles(k: int):
    for _ in range(k):
        yield RNG.normal(size=3), float(RNG.uniform(-3.0, 3.0))


# -- ssa ---------------------------------------------------------------------------------------

@pytest.mark.parametrize('angle, wrapped', [
    (0.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (3.0, 3.0), (-3.0, -3.0),
    (math.pi, -math.pi),               # [-pi, pi): +pi maps to -pi
    (-math.pi, -math.pi),
    (4.0, 4.0 - 2 * math.pi), (-4.0, -4.0 + 2 * math.pi),
    (7.0, 7.0 - 2 * math.pi), (-13.0, -13.0 + 4 * math.pi),
])
def test_ssa_hand_values(angle, wrapped):
    assert ssa(angle) == pytest.approx(wrapped, abs=TOL)


def test_ssa_of_arrays_stays_in_range_and_keeps_the_angle():
    a = RNG.uniform(-50.0, 50.0, size=200)
    w = ssa(a)
    assert np.all(w >= -math.pi) and np.all(w < math.pi)
    turns = (a - w) / (2 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)


# -- skew --------------------------------------------------------------------------------------

def test_skew_is_the_cross_product():
    for _ in range(20):
        a, b = RNG.normal(size=3), RNG.normal(size=3)
        np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=TOL)
    np.testing.assert_array_equal(skew([1.0, 2.0, 3.0]),
                                  [[0, -3, 2], [3, 0, -1], [-2, 1, 0]])


# -- quaternions -------------------------------------------------------------------------------

def test_normalize_scales_to_unit_length_and_positive_w():
    np.testing.assert_allclose(quat_normalize([0.0, 0.0, 0.0, 2.0]), [0, 0, 0, 1], atol=TOL)
    np.testing.assert_allclose(quat_normalize([0.0, 3.0, 0.0, -4.0]), [0, -0.6, 0, 0.8],
                               atol=TOL)
    np.testing.assert_allclose(quat_normalize([1.0, 1.0, 1.0, 1.0]), [0.5] * 4, atol=TOL)
    # w = 0 is kept as is (either sign is the same rotation; no flip needed)
    np.testing.assert_allclose(quat_normalize([0.0, 0.0, 2.0, 0.0]), [0, 0, 1, 0], atol=TOL)


@pytest.mark.parametrize('q', [[0.0, 0.0, 0.0, 0.0], [math.nan, 0.0, 0.0, 1.0],
                               [math.inf, 0.0, 0.0, 1.0]])
def test_normalize_refuses_what_has_no_direction(q):
    with pytest.raises(ValueError, match='cannot normalize quaternion'):
        quat_normalize(q)


def test_rotmat_of_axis_angle_is_rodrigues():
    for axis, angle in random_axes_angles(20):
        np.testing.assert_allclose(quat_to_rotmat(axis_angle_quat(axis, angle)),
                                   rodrigues(axis, angle), atol=TOL)


def test_rotmat_by_hand_quarter_turn_about_z():
    # body x (forward) points world y (north) after +90 deg yaw
    R = quat_to_rotmat([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=TOL)


def test_multiply_is_the_hamilton_product():
    i, j, k, one = np.eye(4)
    np.testing.assert_allclose(quat_multiply(i, j), k, atol=TOL)
    np.testing.assert_allclose(quat_multiply(j, k), i, atol=TOL)
    np.testing.assert_allclose(quat_multiply(k, i), j, atol=TOL)
    np.testing.assert_allclose(quat_multiply(j, i), -k, atol=TOL)
    np.testing.assert_allclose(quat_multiply(i, i), -one, atol=TOL)
    np.testing.assert_allclose(quat_multiply(one, k), k, atol=TOL)
    # general entries: q1 = 1 + 2i + 3j + 4k, q2 = 5 + 6i + 7j + 8k by hand
    # (w1 w2 - v1.v2, w1 v2 + w2 v1 + v1 x v2) = (-60, [12, 30, 24])
    np.testing.assert_allclose(quat_multiply([2, 3, 4, 1], [6, 7, 8, 5]), [12, 30, 24, -60],
                               atol=TOL)


def test_multiply_composes_rotations():
    for (a1, t1), (a2, t2) in zip(random_axes_angles(10), random_axes_angles(10)):
        q = quat_multiply(axis_angle_quat(a1, t1), axis_angle_quat(a2, t2))
        np.testing.assert_allclose(quat_to_rotmat(q), rodrigues(a1, t1) @ rodrigues(a2, t2),
                                   atol=TOL)


def test_conjugate_is_the_inverse_rotation():
    np.testing.assert_array_equal(quat_conjugate([1.0, -2.0, 3.0, 4.0]), [-1, 2, -3, 4])
    for axis, angle in random_axes_angles(10):
        q = axis_angle_quat(axis, angle)
        np.testing.assert_allclose(quat_to_rotmat(quat_conjugate(q)), rodrigues(axis, -angle),
                                   atol=TOL)


def test_rotvec_is_axis_times_angle():
    for axis, angle in random_axes_angles(20):
        n = axis / np.linalg.norm(axis)
        q = quat_from_rotvec(angle * n)
        np.testing.assert_allclose(q, axis_angle_quat(n, angle), atol=TOL)


def test_rotvec_small_angle_series_matches_the_exact_formula():
    # below 1e-12 rad the series sin(a/2)/a ~ 1/2 is used: it must equal the exact value
    # (error O(a^2) ~ 1e-26) and stay a unit quaternion
    phi = np.array([3e-13, -4e-13, 0.0])
    q = quat_from_rotvec(phi)
    np.testing.assert_allclose(q, [1.5e-13, -2e-13, 0.0, 1.0], rtol=1e-9, atol=0.0)
    np.testing.assert_allclose(quat_from_rotvec([0.0, 0.0, 0.0]), [0, 0, 0, 1], atol=0.0)


def test_integrate_applies_the_body_rate_on_the_right():
    # R_k+1 = R_k Rodrigues(omega dt): a body-frame rate composes on the right
    q0 = quat_from_euler(0.0, 0.0, math.pi / 2)   # facing north
    omega, dt = np.array([0.3, 0.0, 0.0]), 0.5     # roll about the body x axis
    q1 = quat_integrate(q0, omega, dt)
    np.testing.assert_allclose(quat_to_rotmat(q1), Rz(math.pi / 2) @ Rx(0.15), atol=TOL)
    assert np.linalg.norm(q1) == pytest.approx(1.0, abs=TOL) and q1[3] >= 0.0


def test_integrate_constant_yaw_rate_is_exact():
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for _ in range(100):
        q = quat_integrate(q, [0.0, 0.0, 0.2], 0.05)
    # 100 steps of 0.05 s at 0.2 rad/s: yaw 1.0 rad, roll and pitch 0
    roll, pitch, yaw = quat_to_euler(q)
    assert (roll, pitch) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert yaw == pytest.approx(1.0, abs=1e-12)


def test_euler_is_zyx():
    for _ in range(20):
        roll, pitch, yaw = RNG.uniform(-3.0, 3.0), RNG.uniform(-1.5, 1.5), RNG.uniform(-3, 3)
        q = quat_from_euler(roll, pitch, yaw)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=TOL)
        np.testing.assert_allclose(quat_to_rotmat(q), Rz(yaw) @ Ry(pitch) @ Rx(roll),
                                   atol=TOL)
        assert quat_to_euler(q) == pytest.approx((roll, pitch, yaw), abs=1e-9)


def test_euler_hand_values():
    h = math.sqrt(0.5)
    np.testing.assert_allclose(quat_from_euler(math.pi / 2, 0.0, 0.0), [h, 0, 0, h], atol=TOL)
    np.testing.assert_allclose(quat_from_euler(0.0, math.pi / 2, 0.0), [0, h, 0, h], atol=TOL)
    np.testing.assert_allclose(quat_from_euler(0.0, 0.0, math.pi / 2), [0, 0, h, h], atol=TOL)
    assert quat_to_euler([h, 0.0, 0.0, h]) == pytest.approx((math.pi / 2, 0.0, 0.0), abs=TOL)
    assert quat_to_euler([0.0, 0.0, h, h]) == pytest.approx((0.0, 0.0, math.pi / 2), abs=TOL)


def test_to_euler_clamps_pitch_at_the_pole():
    # a quaternion a hair over unit length at pitch +-90 deg: 2 (w y - z x) > 1, asin would
    # raise without the clamp
    q = np.array([0.0, 1.0, 0.0, 1.0]) * math.sqrt(0.5) * (1.0 + 1e-12)
    assert quat_to_euler(q)[1] == pytest.approx(math.pi / 2, abs=1e-6)
    assert quat_to_euler(-q * np.array([1, 1, 1, -1]))[1] == pytest.approx(-math.pi / 2,
                                                                           abs=1e-6)


def test_rot_z_is_the_yaw_rotation():
    np.testing.assert_allclose(rot_z(0.7), Rz(0.7), atol=TOL)
    np.testing.assert_allclose(rot_z(math.pi / 2) @ [1.0, 0.0, 0.3], [0.0, 1.0, 0.3], atol=TOL)
