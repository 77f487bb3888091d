"""Thrust allocation for fixed thrusters (Fossen 2021, ch. 11).

A thruster ``i`` at ``r_i`` [m] (body FLU) pushing along the unit vector ``d_i`` with thrust
``f_i`` [N] produces the generalized force ``[d_i; r_i x d_i] f_i``. Stacking the columns gives
the thrust configuration matrix ``B`` (6 x n, Fossen's ``T``) and ``tau = B f``.

The allocator solves the unconstrained weighted least-norm problem (Fossen 2021, ch. 11,
explicit solution by the generalized inverse)

    min_f  f^T W f   subject to   B_c f = tau_c

over the controlled rows ``B_c`` of ``B``; its solution ``f = B_c^+ tau_c`` with
``B_c^+ = W^-1 B_c^T (B_c W^-1 B_c^T)^-1`` is precomputed once. Saturation is handled by
scaling the whole thrust vector, which keeps the direction of the delivered ``tau`` (the
vehicle slows down along the requested motion instead of drifting sideways).

A thruster marked failed (``fail``) loses its column: ``B_c^+`` is recomputed once for the
thrusters left (``least_norm.reachable_pinv``), the failed one is commanded zero, and a
controlled DOF the others cannot produce any more is reported in ``lost_dofs`` and its demand
dropped, so the DOFs still reachable are delivered exactly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.allocation.failures import DEAD, Failure
from enbarr_core.allocation.least_norm import check_weights, reachable_pinv, unreachable_rows
from enbarr_core.framework.errors import AllocationError, ConfigurationError

Vector = NDArray[np.float64]

DOF_NAMES: tuple[str, ...] = ('surge', 'sway', 'heave', 'roll', 'pitch', 'yaw')
"""Names of the six degrees of freedom, in the order of ``tau = [X, Y, Z, K, M, N]``."""

def _vector3(value: Sequence[float], what: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(c) for c in value)
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{what} must be 3 numbers, got {value!r}') from exc
    if not all(math.isfinite(c) for c in (x, y, z)):
        raise ConfigurationError(f'{what} must be finite, got {value!r}')
    return x, y, z


@dataclass(frozen=True)
class Thruster:
    """One fixed thruster.

    ``direction`` is normalized on construction; ``max_forward`` and ``max_reverse`` are the
    thrust magnitudes [N] at command +1 and -1 (both positive).
    """

    name: str
    position: tuple[float, float, float]   # r_i [m], body FLU, from the body origin
    direction: tuple[float, float, float]  # d_i, unit thrust direction for a positive command
    max_forward: float                     # [N] thrust at command +1
    max_reverse: float                     # [N] thrust magnitude at command -1

    def __post_init__(self) -> None:
        where = f'thruster {self.name!r}'
        position = _vector3(self.position, f'{where}: position')
        dx, dy, dz = _vector3(self.direction, f'{where}: direction')
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        if norm < 1e-9:
            raise ConfigurationError(f'{where}: direction must be a non-zero vector')
        for field in ('max_forward', 'max_reverse'):
            value = float(getattr(self, field))
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigurationError(
                    f'{where}: {field} must be a positive finite thrust [N], got {value!r}')
            object.__setattr__(self, field, value)
        object.__setattr__(self, 'position', position)
        object.__setattr__(self, 'direction', (dx / norm, dy / norm, dz / norm))


def allocation_matrix(thrusters: Sequence[Thruster]) -> Vector:
    """Thrust configuration matrix ``B`` (6 x n): column i = [d_i; r_i x d_i].

    Fossen 2021, ch. 11, ``T`` for fixed thrusters.
    """
    B = np.zeros((6, len(thrusters)))
    for i, t in enumerate(thrusters):
        d = np.asarray(t.direction, dtype=float)
        r = np.asarray(t.position, dtype=float)
        B[:3, i] = d               # force    f_i d_i
        B[3:, i] = np.cross(r, d)  # moment   r_i x (f_i d_i)
    return B


@dataclass(frozen=True, eq=False)
class AllocationResult:
    """One allocation. Arrays are fresh per call (``eq=False``: compare the arrays yourself)."""

    thrust: Vector         # (n,) f [N] per thruster
    command: Vector        # (n,) normalized command in [-1, 1]
    tau_delivered: Vector  # (6,) B f [N, N m]
    scale: float           # 1.0 unsaturated, else the factor in (0, 1] applied to f
    saturated: bool


class ThrustAllocator:
    """Weighted pseudo-inverse allocation with direction-preserving saturation.

    ``fail`` and ``restore`` take a thruster out of the solution and give it back at run time
    (see the module docstring); ``failed``, ``lost_dofs`` and ``rank`` say what is left.
    """

    def __init__(
        self,
        thrusters: Sequence[Thruster],
        controlled_dofs: Sequence[int] = (0, 1, 2, 3, 4, 5),
        weights: Sequence[float] | None = None,
    ) -> None:
        self.thrusters: tuple[Thruster, ...] = tuple(thrusters)
        n = len(self.thrusters)
        names = [t.name for t in self.thrusters]
        if n == 0:
            raise AllocationError('thruster layout is empty: cannot produce any DOF')
        if len(set(names)) != n:
            raise ConfigurationError(f'thruster names must be unique, got {names}')

        dofs = tuple(int(k) for k in controlled_dofs)
        if not dofs or len(set(dofs)) != len(dofs) or not all(0 <= k < 6 for k in dofs):
            raise ConfigurationError(
                f'controlled_dofs must be distinct indices in 0..5, got {tuple(controlled_dofs)}')
        self.controlled_dofs: tuple[int, ...] = tuple(sorted(dofs))

        w = check_weights(weights, n, 'thruster')

        B = allocation_matrix(self.thrusters)
        B_c = B[list(self.controlled_dofs), :]
        self._check_reachable(B_c, names)

        B.setflags(write=False)
        self.B: Vector = B
        self.weights: Vector = w
        self.weights.setflags(write=False)
        self._B_c = B_c
        self._names = names
        self._dof_index = np.array(self.controlled_dofs, dtype=np.intp)
        self._inv_forward = np.array([1.0 / t.max_forward for t in self.thrusters])
        self._inv_reverse = np.array([1.0 / t.max_reverse for t in self.thrusters])
        self._failed: dict[str, Failure] = {}
        self.B_pinv: Vector  # (n x m), m = len(controlled_dofs); zero rows for failed ones
        self.rank: int
        self.lost_dofs: tuple[str, ...]
        self._solve()

    def _solve(self) -> None:
        """Recompute ``B_pinv`` for the thrusters not failed (once per change, not per call)."""
        alive = [i for i, n in enumerate(self._names) if n not in self._failed]
        # B_c^+ = W^-1 B_c^T (B_c W^-1 B_c^T)^-1 over the live columns, lost rows dropped
        P, rank, lost = reachable_pinv(self._B_c[:, alive], self.weights[alive])
        B_pinv = np.zeros((len(self._names), len(self.controlled_dofs)))
        B_pinv[alive, :] = P
        B_pinv.setflags(write=False)
        self.B_pinv = B_pinv
        self.rank = rank
        self.lost_dofs = tuple(DOF_NAMES[self.controlled_dofs[j]] for j in lost)

    @property
    def failed(self) -> dict[str, Failure]:
        """The failed thrusters and how, in layout order (a copy)."""
        return {n: self._failed[n] for n in self._names if n in self._failed}

    def fail(self, name: str, mode: str = DEAD) -> None:
        """Take thruster ``name`` out of the allocation (``mode``: only ``'dead'`` here).

        Raises ValueError for an unknown thruster or mode.
        """
        self.set_failures({**self._failed, self._known(name): Failure(mode)})

    def restore(self, name: str) -> None:
        """Give thruster ``name`` back to the allocation (ValueError when unknown)."""
        self.set_failures({n: f for n, f in self._failed.items() if n != self._known(name)})

    def set_failures(self, failures: dict[str, Failure]) -> None:
        """Run with exactly these thrusters failed (one re-solve for the whole set)."""
        for name, failure in failures.items():
            self._known(name)
            if failure.mode != DEAD:
                raise ValueError(f'thruster {name!r}: a fixed thruster can only be '
                                 f'{DEAD!r}, got {failure.mode!r}')
        if failures != self._failed:
            self._failed = dict(failures)
            self._solve()

    def _known(self, name: str) -> str:
        if name not in self._names:
            raise ValueError(f'unknown thruster {name!r}; expected one of '
                             f'{", ".join(self._names)}')
        return name

    def _check_reachable(self, B_c: Vector, names: list[str]) -> None:
        """Raise AllocationError unless rank(B_c) == number of controlled DOFs.

        A DOF is named when its unit vector e_j lies outside range(B_c): no thrust vector
        produces it alone (without also producing something else it cannot cancel).
        """
        m = B_c.shape[0]
        rank, rows = unreachable_rows(B_c)
        if rank == m:
            return
        missing = [DOF_NAMES[self.controlled_dofs[j]] for j in rows]
        raise AllocationError(
            f'thruster layout [{", ".join(names)}] cannot produce {", ".join(missing)} '
            f'(rank {rank} of {m} controlled DOFs '
            f'{[DOF_NAMES[k] for k in self.controlled_dofs]}); '
            'add or re-aim thrusters, or remove the DOF from controlled_dofs')

    def allocate(self, tau: ArrayLike) -> AllocationResult:
        """Thrusts for the generalized force ``tau`` [N, N m] (6,).

        Only the controlled DOFs of ``tau`` are used (the others are ignored, but must still be
        finite), and of those not the ``lost_dofs`` (a failed thruster's). If a thruster would
        exceed its limit the whole thrust vector is scaled by ``1/s``,
        ``s = max_i |f_i| / limit_i``, so ``tau_delivered`` stays parallel to the controlled
        part of ``tau``.
        """
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (6,):
            raise ValueError(f'tau must have shape (6,), got {tau.shape}')
        if not np.isfinite(tau).all():
            raise ValueError(f'tau must be finite, got {tau}')
        f = self.B_pinv @ tau[self._dof_index]                             # f = B_c^+ tau_c
        u = f * np.where(f >= 0.0, self._inv_forward, self._inv_reverse)  # u_i = f_i / limit_i
        s = float(np.abs(u).max())                                          # worst ratio
        if s > 1.0:
            f /= s
            u /= s
            scale, saturated = 1.0 / s, True
        else:
            scale, saturated = 1.0, False
        return AllocationResult(f, u, self.B @ f, scale, saturated)
