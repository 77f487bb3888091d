"""The weighted least-norm solution both allocators share (Fossen 2021, ch. 11).

For a configuration matrix ``B`` (m x k) and positive weights ``w`` (one per column),

    min_f  f^T W f   subject to   B f = tau   =>   f = B^+ tau,
    B^+ = W^-1 B^T (B W^-1 B^T)^-1 = W^-1/2 pinv(B W^-1/2)

exists for every ``tau`` only when rank(B) = m. ``fixed.ThrustAllocator`` and
``azimuth.AzimuthAllocator`` check their weights and their rank here, and build ``B^+`` here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.errors import ConfigurationError

Vector = NDArray[np.float64]

RANK_RTOL = 1e-9
"""Singular values below this fraction of the largest one count as zero."""


def check_weights(weights: Sequence[float] | None, n: int, per: str) -> Vector:
    """``weights`` as an (n,) array of positive finite numbers (ones when ``None``).

    ``per`` names what a weight belongs to (``'thruster'``, ``'azimuth'``) in the
    ``ConfigurationError`` (parameter ``weights``) raised for anything else.
    """
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w <= 0.0):
        raise ConfigurationError(
            f'weights must be {n} positive finite numbers (one per {per}), '
            f'got {list(weights)}', parameter='weights')
    return w


def unreachable_rows(B: Vector) -> tuple[int, list[int]]:
    """``(rank(B), rows j whose unit vector e_j lies outside range(B))``.

    A listed row is a degree of freedom no force vector produces alone (without also
    producing something else it cannot cancel); the list is empty when rank(B) = rows of B.
    """
    m = B.shape[0]
    U, s, _ = np.linalg.svd(B)
    tol = RANK_RTOL * (s[0] if s.size and s[0] > 0.0 else 1.0)
    rank = int(np.count_nonzero(s > tol))
    if rank == m:
        return rank, []
    U_r = U[:, :rank]
    residual = 1.0 - np.sum(U_r * U_r, axis=1)  # |(I - U_r U_r^T) e_j|^2 = 1 - |U_r[j, :]|^2
    return rank, [j for j in range(m) if residual[j] > 1e-6]


def weighted_pinv(B: Vector, w: Vector) -> Vector:
    """``B^+ = W^-1/2 pinv(B W^-1/2)`` (k x m), ``W = diag(w)`` with one weight per column.

    The same as ``W^-1 B^T (B W^-1 B^T)^-1`` when B has full row rank, computed through the
    SVD for conditioning. Singular values below ``RANK_RTOL`` of the largest count as zero,
    as in ``unreachable_rows``, so a rank-deficient B gives no huge gains.
    """
    w_isqrt: Vector = 1.0 / np.sqrt(np.asarray(w, dtype=float))
    return w_isqrt[:, None] * np.linalg.pinv(B * w_isqrt[None, :], RANK_RTOL)


def reachable_pinv(B: Vector, w: Vector) -> tuple[Vector, int, list[int]]:
    """``(B_r^+, rank(B), lost rows)`` for a B that may have lost rank (a failed thruster).

    ``B_r^+`` (k x m) is ``weighted_pinv(B, w)`` with the columns of the lost rows (those
    ``unreachable_rows`` lists) set to zero: ``f = B_r^+ tau`` solves

        min_f  f^T W f   subject to   B f = P tau,

    ``P`` zeroing the lost rows of tau. ``P tau`` lies in range(B) (every kept row's unit
    vector does), so the kept DOFs are delivered exactly and nothing appears in the lost
    ones: a demand that cannot be met any more is dropped instead of leaking into the DOFs
    that still can be (which the least-squares ``pinv(B) tau`` would do). With no columns at
    all (k = 0) every row is lost.
    """
    m, k = B.shape
    if k == 0:
        return np.zeros((0, m)), 0, list(range(m))
    rank, lost = unreachable_rows(B)
    B_pinv = weighted_pinv(B, w)
    B_pinv[:, lost] = 0.0
    return B_pinv, rank, lost
