"""Azimuth thrust allocation and the PWM calibration of the CS Saucer (Fossen 2021, ch. 11).

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
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.models.vessel3dof import AzimuthSpec, _floats, _tau_xyn
from enbarr_core.framework.errors import AllocationError, ConfigurationError

Vector = NDArray[np.float64]

DOF_NAMES_3: tuple[str, str, str] = ('surge', 'sway', 'yaw')
"""Names of the three degrees of freedom, in the order of tau = [X, Y, N]."""

_RANK_RTOL = 1e-9
"""Singular values below this fraction of the largest one count as zero."""

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
    """Weighted least-norm extended-thrust allocation with direction-preserving saturation."""

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
        if weights is None:
            w = np.ones(n)
        else:
            w = np.asarray(weights, dtype=float).reshape(-1)
            if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w <= 0.0):
                raise ConfigurationError(
                    f'weights must be {n} positive finite numbers (one per azimuth), '
                    f'got {list(weights)}', parameter='weights')

        positions = np.array([s.position for s in self.specs])
        B = extended_allocation_matrix(positions)
        self._check_reachable(B, names)
        # B^+ = W^-1 B^T (B W^-1 B^T)^-1 = W^-1/2 pinv(B W^-1/2), W = diag(w_i, w_i per pair)
        w_isqrt = np.repeat(1.0 / np.sqrt(w), 2)
        B_pinv = w_isqrt[:, None] * np.linalg.pinv(B * w_isqrt[None, :])
        for a in (positions, B, B_pinv, w):
            a.setflags(write=False)
        self.positions: Vector = positions
        self.B_ext: Vector = B
        self.B_pinv: Vector = B_pinv  # (2n x 3)
        self.weights: Vector = w
        # Fast-path constants as Python floats.
        self._rows = tuple(tuple(row) for row in B_pinv.tolist())
        self._pos = tuple(s.position for s in self.specs)
        self._fwd = tuple(s.max_forward for s in self.specs)
        self._rev = tuple(s.max_reverse for s in self.specs)
        self._lo = tuple(s.angle_min for s in self.specs)
        self._hi = tuple(s.angle_max for s in self.specs)
        self._rest = tuple(min(max(0.0, s.angle_min), s.angle_max) for s in self.specs)
        self._eps = _ZERO_FORCE * min(min(self._fwd), min(self._rev))

    @staticmethod
    def _check_reachable(B: Vector, names: list[str]) -> None:
        """Raise AllocationError unless rank(B_ext) == 3, naming the DOFs outside its range."""
        U, s, _ = np.linalg.svd(B)
        tol = _RANK_RTOL * (s[0] if s.size and s[0] > 0.0 else 1.0)
        rank = int(np.count_nonzero(s > tol))
        if rank == 3:
            return
        U_r = U[:, :rank]
        residual = 1.0 - np.sum(U_r * U_r, axis=1)  # |(I - U_r U_r^T) e_j|^2
        missing = [DOF_NAMES_3[j] for j in range(3) if residual[j] > 1e-6]
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
        thrust is preferred and idle azimuths point at 0 rad (clipped to their travel).
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
    """Thrust and servo-angle maps to the Arduino PWM duty cycle [%] of one azimuth.

    The Arduino Mega drives the Torpedo 800 motor drives and the servos with duty cycles
    between 4.3 % and 9.4 % (CS Saucer manual Table 1.1). Both tables are measured per
    thruster (the manual gives no thrust curve) and interpolated linearly:

    - thrust: ``thrust_duty_percent`` strictly increasing, ``thrust_newton`` [N] non-decreasing
      and containing 0; a dead band of several 0 N entries is allowed and the neutral duty is
      the middle of the 0 N duties.
    - angle: ``angle_duty_percent`` and ``angle_rad`` [rad] strictly increasing, containing
      angle 0 (the neutral duty); it should cover the servo's [angle_min, angle_max]
      (``check_covers``).

    Construction validates (ValueError naming the table and the index).
    """

    DUTY_MIN: ClassVar[float] = 4.3  # [%] CS Saucer manual Table 1.1
    DUTY_MAX: ClassVar[float] = 9.4  # [%] CS Saucer manual Table 1.1

    thrust_duty_percent: tuple[float, ...]
    thrust_newton: tuple[float, ...]
    angle_duty_percent: tuple[float, ...]
    angle_rad: tuple[float, ...]
    _zero: tuple[int, int] = field(init=False, repr=False, compare=False, default=(0, 0))

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.init:
                object.__setattr__(self, f.name, _table(f.name, getattr(self, f.name)))
        self.validate()
        zeros = [i for i, t in enumerate(self.thrust_newton) if t == 0.0]
        object.__setattr__(self, '_zero', (zeros[0], zeros[-1]))

    def validate(self) -> None:
        """Raise ValueError naming the table (and index) if a table is unusable."""
        for duty, values in (('thrust_duty_percent', 'thrust_newton'),
                             ('angle_duty_percent', 'angle_rad')):
            d = _table(duty, getattr(self, duty))
            v = _table(values, getattr(self, values))
            if len(d) < 2:
                raise ValueError(f'{duty}: needs at least 2 entries, got {len(d)}')
            if len(v) != len(d):
                raise ValueError(f'{values}: {len(v)} entries but {duty} has {len(d)}')
            for i, c in enumerate(d):
                if not self.DUTY_MIN <= c <= self.DUTY_MAX:
                    raise ValueError(
                        f'{duty}[{i}]: {c} % is outside the Arduino PWM range '
                        f'[{self.DUTY_MIN}, {self.DUTY_MAX}] % (CS Saucer manual Table 1.1)')
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

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any]) -> PwmCalibration:
        """Build and validate from a mapping whose keys are the four table names."""
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
