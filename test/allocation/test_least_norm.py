"""The shared weighted least-norm pieces (``allocation/least_norm.py``) against independent
formulations: the KKT system of ``min f^T W f s.t. B f = tau`` solved directly, the
Moore-Penrose conditions, and hand-built matrices whose rank and range are known by
construction.

Tolerance budget: the matrices are 3..6 x 4..8 with entries O(1) and condition numbers below
1e3 (seeded), so the SVD-based and KKT solutions agree to ~1e-13; ``TOL = 1e-9`` is the
margin, far below the O(0.1) a dropped weight or a transposed factor changes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.allocation.least_norm import (
    RANK_RTOL, check_weights, unreachable_rows, weighted_pinv)
from enbarr_core.framework.errors import ConfigurationError

TOL = 1e-9
RNG = np.random.default_rng(7)


def kkt_solution(B: np.ndarray, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """argmin f^T W f s.t. B f = tau from [[2W, B^T], [B, 0]] [f; lam] = [0; tau]."""
    m, k = B.shape
    K = np.zeros((k + m, k + m))
    K[:k, :k] = 2.0 * np.diag(w)
    K[:k, k:] = B.T
    K[k:, :k] = B
    return np.linalg.solve(K, np.concatenate([np.zeros(k), tau]))[:k]


# -- check_weights -----------------------------------------------------------------------------

def test_no_weights_are_ones():
    w = check_weights(None, 4, 'thruster')
    np.testing.assert_array_equal(w, np.ones(4))


def test_weights_become_a_flat_float_array():
    w = check_weights([1, 2, 3], 3, 'thruster')                     # integers: floats
    assert w.dtype == float and w.tolist() == [1.0, 2.0, 3.0]
    w = check_weights(np.array([[1.0, 2.0, 3.0]]), 3, 'thruster')   # a row: flattened
    assert w.shape == (3,)


@pytest.mark.parametrize('weights', [
    [1.0, 2.0],                 # too few
    [1.0, 2.0, 3.0, 4.0],       # too many
    [1.0, 0.0, 1.0],            # zero: the inverse weight is infinite
    [1.0, -1.0, 1.0],           # negative: not a norm
    [1.0, math.nan, 1.0],
    [1.0, math.inf, 1.0],
])
def test_bad_weights_name_the_parameter(weights):
    with pytest.raises(ConfigurationError,
                       match=r'^weights must be 3 positive finite numbers \(one per azimuth\)'
                             r', got ') as info:
        check_weights(weights, 3, 'azimuth')
    assert info.value.parameter == 'weights'


# -- weighted_pinv -----------------------------------------------------------------------------

@pytest.mark.parametrize('m, k', [(3, 4), (3, 3), (6, 8), (5, 6)])
def test_weighted_pinv_is_the_kkt_minimum(m, k):
    for _ in range(5):
        B = RNG.normal(size=(m, k))
        w = RNG.uniform(0.2, 5.0, size=k)
        tau = RNG.normal(size=m)
        f = weighted_pinv(B, w) @ tau
        np.testing.assert_allclose(f, kkt_solution(B, w, tau), atol=TOL)
        np.testing.assert_allclose(B @ f, tau, atol=TOL)


def test_weighted_pinv_closed_form_by_hand():
    # B = [1 1], W = diag(1, 3): f = W^-1 B^T (B W^-1 B^T)^-1 = [1, 1/3] / (4/3) = [3/4, 1/4]
    Bp = weighted_pinv(np.array([[1.0, 1.0]]), np.array([1.0, 3.0]))
    np.testing.assert_allclose(Bp, [[0.75], [0.25]], atol=TOL)


def test_weighted_pinv_of_a_rank_deficient_matrix_is_a_generalized_inverse():
    # two identical columns and a zero row: rank 1 of 2 rows; B B+ B = B still holds and the
    # result is the W-weighted minimum-norm least-squares solution (the weights split f)
    B = np.array([[1.0, 1.0], [0.0, 0.0]])
    w = np.array([1.0, 3.0])
    Bp = weighted_pinv(B, w)
    np.testing.assert_allclose(B @ Bp @ B, B, atol=TOL)
    np.testing.assert_allclose(Bp @ [4.0, 9.0], [3.0, 1.0], atol=TOL)


# -- unreachable_rows --------------------------------------------------------------------------

@pytest.mark.parametrize('B, rank, rows', [
    (np.eye(3), 3, []),
    (np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]), 2, [2]),
    # e1 is the second column; e0 and e2 only appear together, as (1, 0, 1)
    (np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]]), 2, [0, 2]),
    (np.array([[1.0], [1.0], [0.0]]), 1, [0, 1, 2]),
    (np.zeros((3, 2)), 0, [0, 1, 2]),
    (np.zeros((3, 0)), 0, [0, 1, 2]),   # no columns at all: no singular value to scale by
    # full rank but wide: every row reachable
    (np.array([[1.0, 2.0, 0.0, 1.0], [0.0, 1.0, 1.0, 1.0]]), 2, []),
])
def test_rank_and_unreachable_rows_by_construction(B, rank, rows):
    assert unreachable_rows(B) == (rank, rows)


def test_singular_values_below_the_relative_tolerance_count_as_zero():
    s0 = 1e3
    tiny = 0.5 * RANK_RTOL * s0       # below the tolerance: not a direction
    B = np.diag([s0, 1.0, tiny])
    assert unreachable_rows(B) == (2, [2])
    B = np.diag([s0, 1.0, 4.0 * RANK_RTOL * s0])  # above it: full rank
    assert unreachable_rows(B) == (3, [])


@pytest.mark.parametrize('scale', [1e-6, 1e-3, 1.0, 1e6])
def test_rank_does_not_depend_on_the_units(scale):
    """The tolerance is relative to the largest singular value: a matrix in mN or kN has the
    rank it has in N (1e-11 in a matrix whose largest entry is 1e-3 is a direction)."""
    assert unreachable_rows(scale * np.diag([1.0, 1e-8])) == (2, [])
    assert unreachable_rows(scale * np.diag([1.0, 1e-10])) == (1, [1])
