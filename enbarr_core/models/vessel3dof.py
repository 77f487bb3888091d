"""3-DOF surface-vessel model and azimuth-thruster actuators.

The control design model of a small surface vessel with a diagonal inertia (Fossen 2021),
extended with an irrotational ocean current and a world-frame force bias:

    eta_dot = R(psi) nu
    M nu_r_dot + (C(nu_r) + D + D_n(nu_r)) nu_r = tau + R(psi)^T b
    nu_r = nu - nu_c,   nu_c = R(psi)^T [V_x, V_y, 0],   nu_dot = nu_r_dot + nu_c_dot

with eta = [x, y, psi] (world ENU, psi CCW from east), nu = [u, v, r] (body FLU),
tau = [X, Y, N], M = diag(m11, m22, m33), D = diag(d11, d22, d33), D_n(nu) = diag(dn |nu|) and
C(nu) = [[0, -m11 r, 0], [m11 r, 0, 0], [0, 0, 0]] (for m11 = m22). For a constant
current (V_x, V_y) in the world frame, nu_c_dot = [r nu_c2, -r nu_c1, 0]. Writing the rigid-body
part in relative velocity is exact here because C does not depend on the linear velocities
(Fossen 2021, ch. 10, irrotational ocean currents). With zero current and bias the model is
exactly eta_dot = R(psi) nu, M nu_dot + (C + D + D(nu)) nu = tau. A vessel's numbers live in
its profile (``params/*_core.yaml``, parameters ``vessel.*``), never here.

Reference: T. I. Fossen, Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed.,
Wiley 2021.

``Vessel3Dof.step`` and ``AzimuthActuators`` use Python floats instead of small numpy arrays:
they run at up to 400 Hz and per-element arithmetic on 6 states is several times faster than
numpy's per-call overhead. ``coriolis``, ``damping`` and ``M`` are the readable matrix forms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.kinematics import ssa
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.checks import floats

Vector = NDArray[np.float64]
Matrix = NDArray[np.float64]

def _floats(name: str, value: Any, n: int) -> list[float]:
    """``value`` as a list of ``n`` finite Python floats, else ValueError naming ``name``."""
    return list(floats(name, value, n))

def _dt(dt: Any) -> float:
    if not isinstance(dt, (int, float, np.floating, np.integer)) or isinstance(dt, bool):
        raise ValueError(f'dt: expected a number of seconds, got {dt!r}')
    h = float(dt)
    if not (h > 0.0 and math.isfinite(h)):
        raise ValueError(f'dt: must be finite and > 0 s, got {dt!r}')
    return h


# -- vessel -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Vessel3DofParams:
    """Diagonal 3-DOF model parameters (SI units); a profile's ``vessel.*`` parameters."""

    M: tuple[float, float, float]   # diag of M = M_RB + M_A [kg, kg, kg m^2]
    D: tuple[float, float, float]   # diag of the linear damping D [N s/m, N s/m, N m s/rad]
    Dn: tuple[float, float, float]  # D_n(nu) = diag(Dn |nu|) [N s^2/m^2, .., N m s^2/rad^2]

    def validate(self) -> None:
        """Raise ValueError, starting with the field name, if a parameter is non-physical.

        M must be > 0; D and Dn must be >= 0.
        """
        for f in fields(self):
            values = _floats(f.name, getattr(self, f.name), 3)
            if f.name == 'M' and min(values) <= 0.0:
                raise ValueError(f'M: inertia must be > 0, got {values}')
            if f.name != 'M' and min(values) < 0.0:
                raise ValueError(f'{f.name}: damping must be >= 0, got {values}')

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any]) -> Vessel3DofParams:
        """Build and validate parameters from a mapping with the keys ``M``, ``D``, ``Dn``.

        Each value is a sequence of 3 numbers. Unknown or missing keys raise ValueError
        naming them.
        """
        names = [f.name for f in fields(cls)]
        unknown = sorted(str(k) for k in set(d) - set(names))
        if unknown:
            raise ValueError(f'{", ".join(unknown)}: unknown key(s); expected {", ".join(names)}')
        kwargs: dict[str, Any] = {}
        for name in names:
            if name not in d:
                raise ValueError(f'{name}: missing')
            kwargs[name] = tuple(_floats(name, d[name], 3))
        params = cls(**kwargs)
        params.validate()
        return params


class Vessel3Dof:
    """eta_dot = R(psi) nu, M nu_r_dot + (C(nu_r) + D + D_n(nu_r)) nu_r = tau + R^T b; RK4."""

    def __init__(self, params: Vessel3DofParams):
        params.validate()
        self.params = params
        self._m = tuple(_floats('M', params.M, 3))
        self._d = tuple(_floats('D', params.D, 3))
        self._dn = tuple(_floats('Dn', params.Dn, 3))
        self._m_inv = tuple(1.0 / m for m in self._m)
        M = np.diag(self._m)
        M.flags.writeable = False
        self._M = M

    @property
    def M(self) -> Matrix:
        """Inertia matrix M (3x3, read-only) [kg, kg m^2]."""
        return self._M

    def coriolis(self, nu: ArrayLike) -> Matrix:
        """C(nu) = [[0, -m11 r, 0], [m11 r, 0, 0], [0, 0, 0]] (rigid-body Coriolis, m11 = m22).

        C(nu) is skew-symmetric, so nu^T C(nu) nu = 0.
        """
        r = _floats('nu', nu, 3)[2]
        m11r = self._m[0] * r
        return np.array([[0.0, -m11r, 0.0], [m11r, 0.0, 0.0], [0.0, 0.0, 0.0]])

    def damping(self, nu: ArrayLike) -> Matrix:
        """D + D_n(nu) = diag(D + Dn |nu|) (3x3)."""
        a = np.abs(np.asarray(_floats('nu', nu, 3)))
        return np.diag(np.asarray(self._d) + np.asarray(self._dn) * a)

    def steady_surge_speed(self, X: float) -> float:
        """Steady surge speed u [m/s] under a constant surge force ``X`` [N] (v = r = 0).

        The positive root of d11 u + dn11 u |u| = X, in the cancellation-free form
        u = 2 X / (d11 + sqrt(d11^2 + 4 dn11 |X|)).
        """
        X = _floats('X', (X,), 1)[0]
        d, dn = self._d[0], self._dn[0]
        den = d + math.sqrt(d * d + 4.0 * dn * abs(X))
        if den == 0.0:
            if X == 0.0:
                return 0.0
            raise ValueError('D, Dn: surge has no damping, so no steady speed exists')
        return 2.0 * X / den

    def derivatives(self, eta: ArrayLike, nu: ArrayLike, tau: ArrayLike,
                    current: ArrayLike = (0.0, 0.0),
                    bias: ArrayLike = (0.0, 0.0, 0.0)) -> tuple[Vector, Vector]:
        """(eta_dot, nu_dot) [m/s, rad/s; m/s^2, rad/s^2] at ``eta``, ``nu``.

        ``tau`` = [X, Y, N] [N, N, N m] in the body frame; ``current`` = (V_x, V_y) [m/s] and
        ``bias`` = [F_x, F_y, N] [N, N, N m] in the world frame.
        """
        x = _floats('eta', eta, 3) + _floats('nu', nu, 3)
        k = self._f(x, _floats('tau', tau, 3), _floats('current', current, 2),
                    _floats('bias', bias, 3))
        return np.array(k[:3]), np.array(k[3:])

    def step(self, eta: ArrayLike, nu: ArrayLike, tau: ArrayLike, dt: float,
             current: ArrayLike = (0.0, 0.0),
             bias: ArrayLike = (0.0, 0.0, 0.0)) -> tuple[Vector, Vector]:
        """Advance (eta, nu) by ``dt`` [s] with tau, current and bias held; classic RK4.

        Returns new (eta, nu); psi is wrapped to [-pi, pi) by ``ssa``.
        """
        h = _dt(dt)
        x0 = _floats('eta', eta, 3) + _floats('nu', nu, 3)
        t = _floats('tau', tau, 3)
        c = _floats('current', current, 2)
        b = _floats('bias', bias, 3)
        f = self._f
        h2 = 0.5 * h
        k1 = f(x0, t, c, b)
        k2 = f([xi + h2 * ki for xi, ki in zip(x0, k1)], t, c, b)
        k3 = f([xi + h2 * ki for xi, ki in zip(x0, k2)], t, c, b)
        k4 = f([xi + h * ki for xi, ki in zip(x0, k3)], t, c, b)
        h6 = h / 6.0
        x1 = [xi + h6 * (a + 2.0 * (bb + cc) + d)
              for xi, a, bb, cc, d in zip(x0, k1, k2, k3, k4)]
        x1[2] = ssa(x1[2])
        return np.array(x1[:3]), np.array(x1[3:])

    def _f(self, x: list[float], tau: list[float], current: list[float],
           bias: list[float]) -> list[float]:
        """d/dt of x = [x, y, psi, u, v, r] as 6 floats."""
        _, _, psi, u, v, r = x
        cp, sp = math.cos(psi), math.sin(psi)
        vx, vy = current
        fx, fy, fn = bias
        # nu_c = R^T [V_x, V_y, 0]; nu_r = nu - nu_c (an irrotational current: r_r = r)
        uc = cp * vx + sp * vy
        vc = -sp * vx + cp * vy
        ur, vr = u - uc, v - vc
        m1, m2, m3 = self._m
        i1, i2, i3 = self._m_inv
        d1, d2, d3 = self._d
        n1, n2, n3 = self._dn
        # M nu_r_dot = tau + R^T b - C(nu_r) nu_r - (D + D_n(nu_r)) nu_r, C nu = m11 r [-v, u, 0]
        m11r = m1 * r
        urd = i1 * (tau[0] + cp * fx + sp * fy + m11r * vr - (d1 + n1 * abs(ur)) * ur)
        vrd = i2 * (tau[1] - sp * fx + cp * fy - m11r * ur - (d2 + n2 * abs(vr)) * vr)
        rd = i3 * (tau[2] + fn - (d3 + n3 * abs(r)) * r)
        # nu_dot = nu_r_dot + nu_c_dot, nu_c_dot = d/dt(R^T) v_c = r [vc, -uc, 0]
        return [cp * u - sp * v, sp * u + cp * v, r, urd + r * vc, vrd - r * uc, rd]


def current_at(t_s: float, current: Sequence[float], amplitude: Sequence[float],
               period: float) -> tuple[float, float]:
    """World current (V_x, V_y) [m/s] at time ``t_s`` [s]: V = current + sin(2 pi t / T) a.

    ``current`` and ``amplitude`` are (east, north) [m/s], ``period`` T [s]: a steady current
    with a slow sinusoidal variation on top (the simulator's, and what a plot compares with).
    """
    phase = math.sin(2.0 * math.pi * t_s / period)
    return current[0] + phase * amplitude[0], current[1] + phase * amplitude[1]


def disturbance_at_rest(params: Vessel3DofParams, psi: ArrayLike, current: ArrayLike,
                        bias: ArrayLike) -> Vector:
    """World-frame force [F_x, F_y, N] [N, N, N m] that current and bias put on a still hull.

    With nu = 0 the water-relative velocity is nu_r = -nu_c, nu_c = R(psi)^T V, so the model's
    damping pushes the hull with (D + D_n(nu_c)) nu_c (body frame; no yaw moment, the current
    being irrotational, and no Coriolis force at r = 0); in the world frame

        b_rest = b + R(psi) [(d11 + dn11 |u_c|) u_c, (d22 + dn22 |v_c|) v_c, 0].

    This is the force that holding station must cancel, so it is what an observer's world-frame
    bias estimate (which has no current in its model) converges to while the vessel holds
    still. ``psi`` (n,) [rad, ENU], ``current`` (n, 2) or (2,) world (east, north) [m/s],
    ``bias`` (3,) world [N, N, N m]; returns (n, 3).
    """
    psi = np.atleast_1d(np.asarray(psi, dtype=float))
    V = np.broadcast_to(np.asarray(current, dtype=float), (len(psi), 2))
    c, s = np.cos(psi), np.sin(psi)
    u_c = c * V[:, 0] + s * V[:, 1]     # nu_c = R(psi)^T V
    v_c = -s * V[:, 0] + c * V[:, 1]
    (d1, d2, _), (n1, n2, _) = params.D, params.Dn
    X = (d1 + n1 * np.abs(u_c)) * u_c   # body frame
    Y = (d2 + n2 * np.abs(v_c)) * v_c
    out = np.empty((len(psi), 3))
    out[:, 0] = c * X - s * Y           # R(psi) [X, Y]
    out[:, 1] = s * X + c * Y
    out[:, 2] = 0.0
    out += np.asarray(bias, dtype=float)
    return out


# -- azimuth thrusters ------------------------------------------------------------------------


@dataclass(frozen=True)
class AzimuthSpec:
    """One azimuth thruster: a reversible propeller on a servo-driven vertical axis.

    The angle a is the direction of positive thrust in the body frame, CCW from the surge axis:
    thrust T [N] pushes the hull with [T cos a, T sin a] at ``position``. The defaults are an
    ideal actuator (instant thrust, unlimited slew, a full turn of travel); a vessel's servo
    travel, lag and slew rate come from its profile (``azimuths.<name>.*``).
    """

    name: str
    position: tuple[float, float]      # (x, y) [m], body FLU, from the body origin
    max_forward: float                 # largest positive thrust [N]
    max_reverse: float                 # largest negative thrust magnitude [N] (> 0)
    angle_min: float = -math.pi        # servo travel limit [rad]
    angle_max: float = math.pi         # servo travel limit [rad]
    time_constant: float = 0.0         # first-order thrust lag [s]; 0 = instant
    max_angle_rate: float = math.inf   # servo slew rate [rad/s]

    def __post_init__(self) -> None:
        where = f'azimuth {self.name!r}'
        try:
            x, y = (float(c) for c in self.position)
        except (TypeError, ValueError):
            raise ConfigurationError(f'{where}: position must be 2 numbers (x, y) [m], '
                                     f'got {self.position!r}', parameter='position') from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ConfigurationError(f'{where}: position must be finite, got {self.position!r}',
                                     parameter='position')
        object.__setattr__(self, 'position', (x, y))
        for name, low, allow_inf in (('max_forward', 'positive', False),
                                     ('max_reverse', 'positive', False),
                                     ('angle_min', None, False), ('angle_max', None, False),
                                     ('time_constant', 'non-negative', False),
                                     ('max_angle_rate', 'positive', True)):
            raw = getattr(self, name)
            try:
                value = float(raw)
            except (TypeError, ValueError):
                value = math.nan
            ok = not math.isnan(value) and (allow_inf or math.isfinite(value))
            if ok and low == 'positive':
                ok = value > 0.0
            elif ok and low == 'non-negative':
                ok = value >= 0.0
            if not ok or isinstance(raw, bool):
                kind = f'a {low} number' if low else 'a finite number'
                raise ConfigurationError(f'{where}: {name} must be {kind}, got {raw!r}',
                                         parameter=name)
            object.__setattr__(self, name, value)
        if not (-math.pi <= self.angle_min < self.angle_max <= math.pi):
            raise ConfigurationError(
                f'{where}: angle_min, angle_max must satisfy -pi <= angle_min < angle_max <= pi '
                f'rad, got {self.angle_min!r}, {self.angle_max!r}', parameter='angle_max')


def _tau_xyn(positions: Sequence[tuple[float, float]], thrust: Sequence[float],
             angle: Sequence[float]) -> list[float]:
    """[X, Y, N] of azimuths as Python floats (the one place the geometry is written)."""
    X = Y = N = 0.0
    for (x, y), T, a in zip(positions, thrust, angle):
        fx, fy = T * math.cos(a), T * math.sin(a)
        X += fx
        Y += fy
        N += x * fy - y * fx
    return [X, Y, N]


def azimuth_tau(positions: ArrayLike, thrust: ArrayLike, angle: ArrayLike) -> Vector:
    """Generalized force [X, Y, N] (3,) [N, N, N m] of azimuths at ``positions`` (n, 2) [m].

    X = sum T_i cos a_i, Y = sum T_i sin a_i, N = sum x_i T_i sin a_i - y_i T_i cos a_i
    (Fossen 2021, ch. 11, azimuth thrusters); ``thrust`` (n,) [N], ``angle`` (n,) [rad].
    """
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f'positions: expected shape (n, 2), got {p.shape}')
    n = p.shape[0]
    return np.array(_tau_xyn(p.tolist(), _floats('thrust', thrust, n),
                             _floats('angle', angle, n)))


class AzimuthActuators:
    """First-order thrust and rate-limited servo angle of each azimuth.

    ``thrust`` (n,) [N] and ``angle`` (n,) [rad] are the current states (start at 0 N and the
    angle in [angle_min, angle_max] closest to 0).
    """

    def __init__(self, specs: Sequence[AzimuthSpec]):
        self.specs: tuple[AzimuthSpec, ...] = tuple(specs)
        if not self.specs:
            raise ConfigurationError('azimuth layout is empty')
        s = self.specs
        self._t_lo = [-a.max_reverse for a in s]
        self._t_hi = [a.max_forward for a in s]
        self._a_lo = [a.angle_min for a in s]
        self._a_hi = [a.angle_max for a in s]
        self._tc = [a.time_constant for a in s]
        self._rate = [a.max_angle_rate for a in s]
        self._pos = [a.position for a in s]
        self.positions: Vector = np.array(self._pos)
        self.positions.flags.writeable = False
        self._T = [0.0] * len(s)
        self._a = [min(max(0.0, lo), hi) for lo, hi in zip(self._a_lo, self._a_hi)]

    @property
    def thrust(self) -> Vector:
        """Current thrust (n,) [N] (a copy)."""
        return np.array(self._T)

    @property
    def angle(self) -> Vector:
        """Current servo angle (n,) [rad] (a copy)."""
        return np.array(self._a)

    def reset(self, thrust: ArrayLike | None = None, angle: ArrayLike | None = None) -> None:
        """Set the states (clipped to the limits); None leaves 0 N / the angle closest to 0."""
        n = len(self.specs)
        T = [0.0] * n if thrust is None else _floats('thrust', thrust, n)
        a = [0.0] * n if angle is None else _floats('angle', angle, n)
        self._T = [min(max(t, lo), hi) for t, lo, hi in zip(T, self._t_lo, self._t_hi)]
        self._a = [min(max(x, lo), hi) for x, lo, hi in zip(a, self._a_lo, self._a_hi)]

    def step(self, thrust_cmd: ArrayLike, angle_cmd: ArrayLike, dt: float) -> None:
        """Advance by ``dt`` [s] toward the commands [N], [rad], held for the step.

        Commands are clipped to [-max_reverse, max_forward] and [angle_min, angle_max]. Thrust:
        T <- T_c + (T - T_c) exp(-dt / T_thr), the exact first-order response. Angle: moves
        toward the command by at most max_angle_rate dt (no wrapping: the servo has end stops).
        """
        h = _dt(dt)
        n = len(self.specs)
        Tc = _floats('thrust_cmd', thrust_cmd, n)
        ac = _floats('angle_cmd', angle_cmd, n)
        T_new, a_new = [], []
        for i in range(n):
            tc = min(max(Tc[i], self._t_lo[i]), self._t_hi[i])
            tconst = self._tc[i]
            if tconst > 0.0:
                T_new.append(tc + (self._T[i] - tc) * math.exp(-h / tconst))
            else:
                T_new.append(tc)
            a = self._a[i]
            target = min(max(ac[i], self._a_lo[i]), self._a_hi[i])
            dmax = self._rate[i] * h
            if abs(target - a) <= dmax:
                a_new.append(target)
            else:
                a_new.append(a + dmax if target > a else a - dmax)
        self._T, self._a = T_new, a_new

    def tau(self) -> Vector:
        """Generalized force [X, Y, N] (3,) [N, N, N m] of the current thrust and angle."""
        return np.array(_tau_xyn(self._pos, self._T, self._a))
