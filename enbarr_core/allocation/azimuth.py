"""Azimuth thrust allocation and the PWM calibration of an azimuth (Fossen 2021, ch. 11).

Extended thrust formulation (Fossen 2021, ch. 11): azimuth i at (x_i, y_i) [m] with thrust
T_i along angle a_i is written as two orthogonal forces f_xi = T_i cos a_i, f_yi = T_i sin a_i,
which enter linearly:

    tau = B_ext f,   column pair i of B_ext = [[1, 0], [0, 1], [-y_i, x_i]]   (3 x 2n)

The weighted least-norm solution f = W^-1 B_ext^T (B_ext W^-1 B_ext^T)^-1 tau minimizes
sum_i w_i T_i^2, since T_i^2 = f_xi^2 + f_yi^2. Each pair then gives a magnitude and a
direction phi_i; a reversible propeller produces it either as (a = phi, T > 0) or as
(a = phi -/+ pi, T < 0), and the allocator picks the one inside the servo travel (closest to
the previous angle when both are). Saturation scales all thrusts by one factor, which keeps the
direction of the delivered tau.

A failed azimuth (``fail``) changes B_ext once, and its weighted pseudo-inverse is recomputed
then (never per call): a dead one loses its column pair and is commanded zero thrust; one stuck
at angle a_s still pushes, along that direction only, so its pair becomes the single column

    [cos a_s, sin a_s, x_i sin a_s - y_i cos a_s]^T   (its thrust T_i, weight w_i on T_i^2).

A DOF the azimuths left cannot produce alone (``least_norm.reachable_pinv``) is reported in
``lost_dofs`` and its demand dropped; the others are delivered exactly when within the limits.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.allocation.failures import DEAD, STUCK, Failure
from enbarr_core.allocation.least_norm import check_weights, reachable_pinv, unreachable_rows
from enbarr_core.framework.errors import AllocationError, ConfigurationError
from enbarr_core.models.vessel3dof import AzimuthSpec, _floats, _tau_xyn

Vector = NDArray[np.float64]

DOF_NAMES_3: tuple[str, str, str] = ('surge', 'sway', 'yaw')
"""Names of the three degrees of freedom, in the order of tau = [X, Y, N]."""

_ZERO_FORCE = 1e-9
"""Force pairs below this fraction of the smallest thrust limit count as zero thrust [-]."""

_ANGLE_TOL = 1e-12
"""Slack [rad] on the servo limits when testing a candidate angle (then clipped)."""


def extended_allocation_matrix(positions: ArrayLike) -> Vector:
    """B_ext (3 x 2n) of azimuths at ``positions`` (n, 2) [m]: tau = B_ext [f_x1, f_y1, ...]."""
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    B = np.zeros((3, 2 * p.shape[0]))
    B[0, 0::2] = 1.0
    B[1, 1::2] = 1.0
    B[2, 0::2] = -p[:, 1]  # N = x f_y - y f_x
    B[2, 1::2] = p[:, 0]
    return B


@dataclass(frozen=True, eq=False)
class AzimuthResult:
    """One allocation. Arrays are fresh per call (``eq=False``: compare the arrays yourself)."""

    thrust: Vector         # (n,) signed thrust T [N] (negative: propeller reversed)
    angle: Vector          # (n,) servo angle a [rad], within [angle_min, angle_max]
    tau_delivered: Vector  # (3,) [X, Y, N] of (thrust, angle) [N, N, N m]
    scale: float           # 1.0 when feasible, else 1/s in (0, 1)
    feasible: bool         # False when the thrusts were scaled down to the limits


class AzimuthAllocator:
    """Weighted least-norm extended-thrust allocation with direction-preserving saturation.

    ``fail`` (dead, or stuck at an angle) and ``restore`` change the azimuths in use at run
    time (see the module docstring); ``failed``, ``lost_dofs`` and ``rank`` say what is left.
    """

    def __init__(self, specs: Sequence[AzimuthSpec],
                 weights: Sequence[float] | None = None) -> None:
        self.specs: tuple[AzimuthSpec, ...] = tuple(specs)
        n = len(self.specs)
        names = [s.name for s in self.specs]
        if n == 0:
            raise AllocationError('azimuth layout is empty: cannot produce surge, sway, yaw')
        if len(set(names)) != n:
            raise ConfigurationError(f'azimuth names must be unique, got {names}')
        for s in self.specs:
            if s.angle_max - s.angle_min < math.pi - _ANGLE_TOL:
                # With less than 180 deg of travel some force directions cannot be produced
                # even with the propeller reversed; this allocator assumes all can.
                raise ConfigurationError(
                    f'azimuth {s.name!r}: angle_max - angle_min must be >= pi rad (180 deg) '
                    f'for the allocator, got {s.angle_max - s.angle_min:.4f} rad',
                    parameter='angle_min')
        w = check_weights(weights, n, 'azimuth')

        positions = np.array([s.position for s in self.specs])
        B = extended_allocation_matrix(positions)
        self._check_reachable(B, names)
        for a in (positions, B, w):
            a.setflags(write=False)
        self.positions: Vector = positions
        self.B_ext: Vector = B
        self.weights: Vector = w
        self._names = names
        self._failed: dict[str, Failure] = {}
        self.B_pinv: Vector  # (2n x 3): rows (f_xi, f_yi) per azimuth
        self.rank: int
        self.lost_dofs: tuple[str, ...]
        # (cos a_s, sin a_s, a_s) of a stuck azimuth, else None (a dead one's rows are zero)
        self._stuck: tuple[tuple[float, float, float] | None, ...] = (None,) * n
        self._rows: tuple[tuple[float, ...], ...] = ()
        self._solve()
        # Fast-path constants as Python floats.
        self._pos = tuple(s.position for s in self.specs)
        self._fwd = tuple(s.max_forward for s in self.specs)
        self._rev = tuple(s.max_reverse for s in self.specs)
        self._lo = tuple(s.angle_min for s in self.specs)
        self._hi = tuple(s.angle_max for s in self.specs)
        self._rest = tuple(min(max(0.0, s.angle_min), s.angle_max) for s in self.specs)
        self._eps = _ZERO_FORCE * min(min(self._fwd), min(self._rev))

    def _solve(self) -> None:
        """Recompute ``B_pinv`` for the failures (once per change, not per allocation)."""
        cols: list[Vector] = []
        weights: list[float] = []
        owner: list[tuple[int, Vector]] = []  # per column: azimuth i, its (f_x, f_y) direction
        for i, name in enumerate(self._names):
            failure = self._failed.get(name)
            if failure is None:
                cols += [self.B_ext[:, 2 * i], self.B_ext[:, 2 * i + 1]]
                weights += [self.weights[i]] * 2
                owner += [(i, np.array([1.0, 0.0])), (i, np.array([0.0, 1.0]))]
            elif failure.mode == STUCK:
                x, y = self.positions[i]
                c, s = math.cos(failure.angle), math.sin(failure.angle)
                cols.append(np.array([c, s, x * s - y * c]))  # N = x f_y - y f_x
                weights.append(self.weights[i])
                owner.append((i, np.array([c, s])))
        B = np.array(cols).T if cols else np.zeros((3, 0))
        # B^+ = W^-1 B^T (B W^-1 B^T)^-1 over the columns left, lost rows dropped
        P, rank, lost = reachable_pinv(B, np.array(weights))
        # Back to one (f_x, f_y) row pair per azimuth: a stuck one's T times (cos, sin) a_s.
        B_pinv = np.zeros((2 * len(self._names), 3))
        for row, (i, direction) in zip(P, owner):
            B_pinv[2 * i:2 * i + 2, :] += direction[:, None] * row[None, :]
        B_pinv.setflags(write=False)
        self.B_pinv = B_pinv
        self.rank = rank
        self.lost_dofs = tuple(DOF_NAMES_3[j] for j in lost)
        self._rows = tuple(tuple(row) for row in B_pinv.tolist())
        self._stuck = tuple(
            (math.cos(f.angle), math.sin(f.angle), f.angle) if f is not None and f.mode == STUCK
            else None for f in (self._failed.get(n) for n in self._names))

    @property
    def failed(self) -> dict[str, Failure]:
        """The failed azimuths and how, in layout order (a copy)."""
        return {n: self._failed[n] for n in self._names if n in self._failed}

    def fail(self, name: str, mode: str = DEAD, angle: float = 0.0) -> None:
        """Mark azimuth ``name`` ``'dead'`` or ``'stuck'`` at ``angle`` [rad].

        Raises ValueError for an unknown azimuth or mode.
        """
        self.set_failures({**self._failed, self._known(name): Failure(mode, angle)})

    def restore(self, name: str) -> None:
        """Give azimuth ``name`` back to the allocation (ValueError when unknown)."""
        self.set_failures({n: f for n, f in self._failed.items() if n != self._known(name)})

    def set_failures(self, failures: dict[str, Failure]) -> None:
        """Run with exactly these azimuths failed (one re-solve for the whole set)."""
        for name in failures:
            self._known(name)
        if failures != self._failed:
            self._failed = dict(failures)
            self._solve()

    def _known(self, name: str) -> str:
        if name not in self._names:
            raise ValueError(f'unknown azimuth {name!r}; expected one of '
                             f'{", ".join(self._names)}')
        return name

    @staticmethod
    def _check_reachable(B: Vector, names: list[str]) -> None:
        """Raise AllocationError unless rank(B_ext) == 3, naming the DOFs outside its range."""
        rank, rows = unreachable_rows(B)
        if rank == 3:
            return
        missing = [DOF_NAMES_3[j] for j in rows]
        raise AllocationError(
            f'azimuth layout [{", ".join(names)}] cannot produce {", ".join(missing)} '
            f'(rank {rank} of 3 DOFs surge, sway, yaw); '
            'move the azimuths off the centre or add one', parameter='azimuths')

    def allocate(self, tau: ArrayLike,
                 previous_angle: ArrayLike | None = None) -> AzimuthResult:
        """Thrust [N] and angle [rad] per azimuth for ``tau`` = [X, Y, N] [N, N, N m].

        ``previous_angle`` (n,) [rad], the last commanded (or measured) angles: when both signs
        of thrust can produce a force, the angle closest to it is kept (no 180 deg servo flips),
        and an azimuth with (almost) no force keeps it with zero thrust. Without it, positive
        thrust is preferred and idle azimuths point at 0 rad (clipped to their travel). A dead
        azimuth gets zero thrust the same way; a stuck one its stuck angle, whatever the sign
        of its thrust (``lost_dofs`` of tau are not delivered).
        """
        n = len(self.specs)
        X, Y, N = _floats('tau', tau, 3)
        prev = None if previous_angle is None else _floats('previous_angle', previous_angle, n)
        eps = self._eps
        fxy = [r0 * X + r1 * Y + r2 * N for r0, r1, r2 in self._rows]  # f = B^+ tau
        T_out, a_out = [0.0] * n, [0.0] * n
        s = 0.0
        for i in range(n):
            fx, fy = fxy[2 * i], fxy[2 * i + 1]
            lo, hi = self._lo[i], self._hi[i]
            stuck = self._stuck[i]
            if stuck is not None:
                T = fx * stuck[0] + fy * stuck[1]  # (f_x, f_y) = T (cos, sin) a_s
                ratio = T / self._fwd[i] if T >= 0.0 else -T / self._rev[i]
                T_out[i], a_out[i] = T, stuck[2]
                s = max(s, ratio)
                continue
            m = math.hypot(fx, fy)
            if m <= eps:
                a_out[i] = self._rest[i] if prev is None else min(max(prev[i], lo), hi)
                continue
            phi = math.atan2(fy, fx)                             # (T = +m, a = phi)
            phi_r = phi - math.pi if phi > 0.0 else phi + math.pi  # (T = -m, a = phi_r)
            ok_pos = lo - _ANGLE_TOL <= phi <= hi + _ANGLE_TOL
            ok_neg = lo - _ANGLE_TOL <= phi_r <= hi + _ANGLE_TOL
            if ok_pos and ok_neg and prev is not None:
                use_pos = abs(phi - prev[i]) <= abs(phi_r - prev[i])
            else:
                use_pos = ok_pos  # travel >= pi: at least one of the two is inside
            if use_pos:
                T, a, ratio = m, phi, m / self._fwd[i]
            else:
                T, a, ratio = -m, phi_r, m / self._rev[i]
            T_out[i] = T
            a_out[i] = min(max(a, lo), hi)
            if ratio > s:
                s = ratio
        if s > 1.0:
            k = 1.0 / s
            T_out = [T * k for T in T_out]
            scale, feasible = k, False
        else:
            scale, feasible = 1.0, True
        return AzimuthResult(np.array(T_out), np.array(a_out),
                             np.array(_tau_xyn(self._pos, T_out, a_out)), scale, feasible)


# -- PWM calibration --------------------------------------------------------------------------


def _table(name: str, value: Any) -> tuple[float, ...]:
    try:
        out = tuple(float(c) for c in value)
    except (TypeError, ValueError):
        raise ValueError(f'{name}: expected a list of numbers, got {value!r}') from None
    for i, c in enumerate(out):
        if not math.isfinite(c):
            raise ValueError(f'{name}[{i}]: must be finite, got {c}')
    return out


def _interp(x: float, xp: Sequence[float], fp: Sequence[float], right: bool) -> float:
    """Piecewise-linear f(x) on a non-decreasing ``xp``, ``x`` clipped to [xp[0], xp[-1]].

    On a flat run of ``xp`` the first (``right`` False) or the last (``right`` True) point of
    the run is used.
    """
    if math.isnan(x):
        raise ValueError('expected a number, got nan')
    if x <= xp[0]:
        return fp[0] if not right else fp[bisect.bisect_right(xp, xp[0]) - 1]
    if x >= xp[-1]:
        return fp[-1] if right else fp[bisect.bisect_left(xp, xp[-1])]
    if right:
        j = bisect.bisect_right(xp, x) - 1  # xp[j] <= x < xp[j + 1]
        i, j = j, j + 1
    else:
        j = bisect.bisect_left(xp, x)       # xp[j - 1] < x <= xp[j]
        i = j - 1
    x0, x1 = xp[i], xp[j]
    if x1 == x0:
        return fp[j] if not right else fp[i]
    return fp[i] + (fp[j] - fp[i]) * (x - x0) / (x1 - x0)


@dataclass(frozen=True)
class PwmCalibration:
    """Thrust and servo-angle maps to the PWM duty cycle [%] of one azimuth.

    The PWM board accepts duties in [``duty_min_percent``, ``duty_max_percent``] (a vessel
    profile gives them: the CS Saucer's Arduino Mega drives its Torpedo 800 motor drives and
    servos between 4.3 % and 9.4 %, manual Table 1.1). Both tables are measured per thruster
    and interpolated linearly:

    - thrust: ``thrust_duty_percent`` strictly increasing, ``thrust_newton`` [N] non-decreasing
      and containing 0; a dead band of several 0 N entries is allowed and the neutral duty is
      the middle of the 0 N duties.
    - angle: ``angle_duty_percent`` and ``angle_rad`` [rad] strictly increasing, containing
      angle 0 (the neutral duty); it should cover the servo's [angle_min, angle_max]
      (``check_covers``).

    Every duty of the tables lies within the duty limits. Construction validates (ValueError
    naming the field, and the index in a table).
    """

    thrust_duty_percent: tuple[float, ...]
    thrust_newton: tuple[float, ...]
    angle_duty_percent: tuple[float, ...]
    angle_rad: tuple[float, ...]
    duty_min_percent: float  # [%] lowest duty the PWM board accepts
    duty_max_percent: float  # [%] highest duty the PWM board accepts
    _zero: tuple[int, int] = field(init=False, repr=False, compare=False, default=(0, 0))

    _TABLES = ('thrust_duty_percent', 'thrust_newton', 'angle_duty_percent', 'angle_rad')

    def __post_init__(self) -> None:
        for name in self._TABLES:
            object.__setattr__(self, name, _table(name, getattr(self, name)))
        for name in ('duty_min_percent', 'duty_max_percent'):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f'{name}: expected a number, got {value!r}') from None
            if not 0.0 <= value <= 100.0:
                raise ValueError(f'{name}: expected a duty cycle in [0, 100] %, got {value}')
            object.__setattr__(self, name, value)
        if not self.duty_min_percent < self.duty_max_percent:
            raise ValueError(f'duty_max_percent: must be above duty_min_percent '
                             f'({self.duty_min_percent} %), got {self.duty_max_percent} %')
        self.validate()
        zeros = [i for i, t in enumerate(self.thrust_newton) if t == 0.0]
        object.__setattr__(self, '_zero', (zeros[0], zeros[-1]))

    def validate(self) -> None:
        """Raise ValueError naming the table (and index) if a table is unusable."""
        lo, hi = self.duty_min_percent, self.duty_max_percent
        for duty, values in (('thrust_duty_percent', 'thrust_newton'),
                             ('angle_duty_percent', 'angle_rad')):
            d = _table(duty, getattr(self, duty))
            v = _table(values, getattr(self, values))
            if len(d) < 2:
                raise ValueError(f'{duty}: needs at least 2 entries, got {len(d)}')
            if len(v) != len(d):
                raise ValueError(f'{values}: {len(v)} entries but {duty} has {len(d)}')
            for i, c in enumerate(d):
                if not lo <= c <= hi:
                    raise ValueError(
                        f'{duty}[{i}]: {c} % is outside the PWM range [{lo}, {hi}] % '
                        '(duty_min_percent, duty_max_percent)')
                if i and c <= d[i - 1]:
                    raise ValueError(f'{duty}[{i}]: must be strictly increasing, '
                                     f'got {c} after {d[i - 1]}')
            strict = values == 'angle_rad'
            for i in range(1, len(v)):
                if v[i] < v[i - 1] or (strict and v[i] == v[i - 1]):
                    kind = 'strictly increasing' if strict else 'non-decreasing'
                    raise ValueError(f'{values}[{i}]: must be {kind}, '
                                     f'got {v[i]} after {v[i - 1]}')
        if 0.0 not in self.thrust_newton:
            raise ValueError('thrust_newton: must contain 0 N (the neutral duty), got '
                             f'{list(self.thrust_newton)}')
        if not self.angle_rad[0] <= 0.0 <= self.angle_rad[-1]:
            raise ValueError('angle_rad: must span angle 0 (the neutral duty), got '
                             f'[{self.angle_rad[0]}, {self.angle_rad[-1]}]')

    def accepts(self, duty: float) -> bool:
        """Return whether ``duty`` [%] is finite and within the PWM board's limits."""
        return math.isfinite(duty) and self.duty_min_percent <= duty <= self.duty_max_percent

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any]) -> PwmCalibration:
        """Build and validate from a mapping whose keys are the field names."""
        names = [f.name for f in fields(cls) if f.init]
        unknown = sorted(str(k) for k in set(d) - set(names))
        if unknown:
            raise ValueError(f'{", ".join(unknown)}: unknown key(s); expected {", ".join(names)}')
        missing = [k for k in names if k not in d]
        if missing:
            raise ValueError(f'{", ".join(missing)}: missing')
        return cls(**{k: d[k] for k in names})

    def check_covers(self, angle_min: float, angle_max: float) -> None:
        """Raise ValueError if the angle table does not cover [angle_min, angle_max] [rad]."""
        lo, hi = self.angle_rad[0], self.angle_rad[-1]
        if lo > angle_min + 1e-9 or hi < angle_max - 1e-9:
            raise ValueError(f'angle_rad: table covers [{lo}, {hi}] rad but the servo travels '
                             f'[{angle_min}, {angle_max}] rad')

    @property
    def neutral_thrust_duty(self) -> float:
        """Duty [%] for 0 N: the middle of the 0 N entries (dead band)."""
        i, j = self._zero
        return 0.5 * (self.thrust_duty_percent[i] + self.thrust_duty_percent[j])

    @property
    def neutral_angle_duty(self) -> float:
        """Duty [%] for angle 0."""
        return _interp(0.0, self.angle_rad, self.angle_duty_percent, False)

    def thrust_to_duty(self, thrust: float) -> float:
        """Duty [%] for ``thrust`` [N]; clipped to the table's ends.

        0 N gives the neutral duty exactly. Positive thrust interpolates on the table above
        the dead band, negative below it; on a flat run the duty closest to neutral is used.
        """
        T = float(thrust)
        if math.isnan(T):
            raise ValueError('thrust: must be a number, got nan')
        if T == 0.0:
            return self.neutral_thrust_duty
        i, j = self._zero
        if T > 0.0:
            return _interp(T, self.thrust_newton[j:], self.thrust_duty_percent[j:], False)
        return _interp(T, self.thrust_newton[:i + 1], self.thrust_duty_percent[:i + 1], True)

    def duty_to_thrust(self, duty: float) -> float:
        """Thrust [N] at ``duty`` [%] (clipped to the table's duty range)."""
        return _interp(float(duty), self.thrust_duty_percent, self.thrust_newton, False)

    def angle_to_duty(self, angle: float) -> float:
        """Duty [%] for servo ``angle`` [rad] (clipped to the table's angle range)."""
        return _interp(float(angle), self.angle_rad, self.angle_duty_percent, False)

    def duty_to_angle(self, duty: float) -> float:
        """Servo angle [rad] at ``duty`` [%] (clipped to the table's duty range)."""
        return _interp(float(duty), self.angle_duty_percent, self.angle_rad, False)
