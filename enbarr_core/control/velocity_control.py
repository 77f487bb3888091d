"""Body-velocity control of an ROV: PID with anti-windup and model-based feed-forward.

Per DOF j (decoupled, diagonal model; Fossen 2021, ch. 12 for the feed-forward + PID
structure), with e = nu_r - nu:

    tau_ff = M nu_d_dot + D_lin nu_d + D_quad |nu_d| nu_d [+ C(nu_d) nu_d]
             (holds nu_d of  M nu_dot + C(nu) nu + D(nu) nu = tau)
    I_k    = I_k-1 + k_i e_k dt                             (stored as the contribution [N, N m])
    tau    = sat(tau_ff + k_p e + I - k_d y_dot_f)          (D on measurement: no setpoint kick)

C(nu_d) nu_d is the Coriolis-centripetal force of the diagonal M = M_RB + M_A (Fossen 2021,
Thm 3.2 and ch. 6), added when ``coriolis`` is on: with h = M nu_d it is
[w x h_lin; w x h_ang + v x h_lin] (v, w: linear and angular parts of nu_d). It matters
wherever the unmeasured linear DOFs run on the feed-forward alone: in a turn at surge speed u
and yaw rate r the sway force M_u u r holds the vehicle on its circle, without it the vehicle
slides out of the turn (sway) and loses surge.

``y_dot_f`` is the measured velocity differentiated through the first-order filter
1 / (T_f s + 1) (backward Euler). Roll/pitch leveling adds the rate setpoints
p_r = p_d - k_lvl phi and q_r = q_d - k_lvl theta before the error (small-angle attitude loop).

Anti-windup is conditional integration (a DOF integrates only up to the point where its output
reaches tau_max in the direction its error pushes, then holds) plus the clamp
|I| <= integral_limit. Because the
integral is stored as its contribution (sum of k_i e dt, not k_i times sum of e dt), changing
k_i does not step the output (bumpless); a new k_p or k_d acts at once on e and y_dot_f.

A measured velocity entry that is NaN means "not measured" (e.g. no DVL): that DOF gets the
feed-forward only, its integral and derivative states are held at zero. With
``freeze_lost_integral`` set (the ROV's pilot modes, where a depth hold that loses its depth
falls back to stabilize) a DOF that loses its measurement keeps its integral instead, frozen:
the steady force it learnt (a vehicle trimmed light) is still needed, and dropping it steps the
output by as much. Its k_p e goes: a reaction to an error that can no longer be measured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.checks import check_gain_vectors, check_non_negative, vector
from enbarr_core.models.rigid_body import coriolis_force

Vector = NDArray[np.float64]

_VECTOR_FIELDS = ('kp', 'ki', 'kd', 'integral_limit', 'tau_max', 'd_lin', 'd_quad', 'inertia')
_MAY_BE_INFINITE = ('integral_limit', 'tau_max')  # +inf means "no limit"


@dataclass(frozen=True)
class VelocityControlSettings:
    """Gains, limits and model of the velocity loop; every tuple has 6 entries [X Y Z K M N]."""

    kp: tuple[float, ...]              # proportional gains [N/(m/s), N m/(rad/s)]
    ki: tuple[float, ...]              # integral gains [N/m, N m/rad]
    kd: tuple[float, ...]              # derivative gains on measurement [N/(m/s^2), N m/(rad/s^2)]
    integral_limit: tuple[float, ...]  # |I| clamp [N, N m] (+inf: no clamp)
    tau_max: tuple[float, ...]         # output limits |tau| [N, N m] (> 0, +inf: none)
    d_lin: tuple[float, ...]           # linear damping of the model [N/(m/s), N m/(rad/s)]
    d_quad: tuple[float, ...]          # quadratic damping [N/(m/s)^2, N m/(rad/s)^2]
    inertia: tuple[float, ...]         # diagonal of M = M_RB + M_A [kg, kg m^2]
    level_gain: float = 0.0            # roll/pitch leveling gain k_lvl [1/s]
    coriolis: bool = True              # add C(nu_d) nu_d of the diagonal M to the feed-forward
    derivative_filter: float = 0.02    # time constant T_f of the derivative filter [s]

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        check_gain_vectors(self, _VECTOR_FIELDS, 6, 'X Y Z K M N',
                           may_be_infinite=_MAY_BE_INFINITE, positive=('tau_max',))
        check_non_negative(self, ('level_gain', 'derivative_filter'))
        if not isinstance(self.coriolis, bool):
            raise ValueError(f'coriolis: must be true or false, got {self.coriolis!r}')


@dataclass(frozen=True, eq=False)
class ControlOutput:
    """One control step. Arrays are fresh per call (``eq=False``: compare the arrays yourself)."""

    tau: Vector        # (6,) commanded generalized force after saturation [N, N m]
    tau_ff: Vector     # (6,) feed-forward part [N, N m]
    integral: Vector   # (6,) integral contribution I [N, N m]
    saturated: NDArray[np.bool_]  # (6,) |unsaturated tau| > tau_max


def _all_finite(v: Vector) -> bool:
    return bool(np.isfinite(v).all())


class VelocityController:
    """Six decoupled velocity loops; call :meth:`step` once per control period."""

    def __init__(self, settings: VelocityControlSettings) -> None:
        self._integral = np.zeros(6)             # I [N, N m]
        self._y_prev = np.full(6, np.nan)        # last measured nu (NaN: none)
        self._y_dot = np.zeros(6)                # filtered d(nu)/dt
        self._prev_all_measured = False
        #: Keep a DOF's integral, frozen, when its measurement goes (module docstring).
        self.freeze_lost_integral = False
        self.settings = settings

    @property
    def settings(self) -> VelocityControlSettings:
        """Return the gains, limits and model in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: VelocityControlSettings) -> None:
        """Swap gains/limits/model at run time (validated first; the integral is kept)."""
        settings.validate()
        self._settings = settings
        self._kp = np.array(settings.kp, dtype=float)
        self._ki = np.array(settings.ki, dtype=float)
        self._kd = np.array(settings.kd, dtype=float)
        self._i_lim = np.array(settings.integral_limit, dtype=float)
        self._i_lo = -self._i_lim
        self._tau_max = np.array(settings.tau_max, dtype=float)
        self._tau_lo = -self._tau_max
        self._d_lin = np.array(settings.d_lin, dtype=float)
        self._d_quad = np.array(settings.d_quad, dtype=float)
        self._inertia = np.array(settings.inertia, dtype=float)
        self._k_lvl = float(settings.level_gain)
        self._t_f = float(settings.derivative_filter)
        self._coriolis = settings.coriolis
        np.clip(self._integral, -self._i_lim, self._i_lim, out=self._integral)

    def reset(self) -> None:
        """Forget the integral and the derivative history."""
        self._integral[:] = 0.0
        self._y_prev[:] = np.nan
        self._y_dot[:] = 0.0
        self._prev_all_measured = False

    def step(
        self,
        nu_d: ArrayLike,
        nu: ArrayLike,
        dt: float,
        *,
        nu_d_dot: ArrayLike | None = None,
        roll: float = 0.0,
        pitch: float = 0.0,
    ) -> ControlOutput:
        """One control period.

        nu_d: desired body velocity [u v w p q r] (m/s, rad/s), finite.
        nu: measured body velocity, NaN entries = not measured (feed-forward only there).
        dt: time since the previous step [s], > 0.
        nu_d_dot: desired body acceleration (m/s^2, rad/s^2) for the inertia feed-forward.
        roll, pitch: attitude [rad] for leveling (only used when level_gain > 0).
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        nu_d = vector('nu_d', nu_d, 6)
        if not _all_finite(nu_d):
            raise ValueError(f'nu_d must be finite, got {nu_d}')
        y = vector('nu', nu, 6)
        all_measured = _all_finite(y)
        if not all_measured and np.isinf(y).any():
            raise ValueError(f'nu must be finite or NaN (not measured), got {y}')
        if not (math.isfinite(roll) and math.isfinite(pitch)):
            raise ValueError(f'roll and pitch must be finite, got {roll!r}, {pitch!r}')

        # tau_ff = M nu_d_dot + D_lin nu_d + D_quad |nu_d| nu_d [+ C(nu_d) nu_d]
        tau_ff = (self._d_lin + self._d_quad * np.abs(nu_d)) * nu_d
        if self._coriolis:
            tau_ff += coriolis_force(self._inertia, nu_d)
        if nu_d_dot is not None:
            nu_d_dot = vector('nu_d_dot', nu_d_dot, 6)
            if not _all_finite(nu_d_dot):
                raise ValueError(f'nu_d_dot must be finite, got {nu_d_dot}')
            tau_ff += self._inertia * nu_d_dot

        # Leveling: p_r = p_d - k_lvl phi, q_r = q_d - k_lvl theta.
        nu_r = nu_d
        if self._k_lvl != 0.0:
            nu_r = nu_d.copy()
            nu_r[3] -= self._k_lvl * roll
            nu_r[4] -= self._k_lvl * pitch

        # e = nu_r - nu; NaN (not measured) -> 0.
        e = nu_r - y
        # Filtered derivative of the measurement, backward Euler of s / (T_f s + 1):
        # y_dot_k = (T_f y_dot_k-1 + y_k - y_k-1) / (T_f + dt); NaN where y_k or y_k-1 is
        # missing -> 0 (no kick when a measurement (re)appears).
        y_dot = (self._t_f * self._y_dot + (y - self._y_prev)) / (self._t_f + dt)
        if not all_measured:
            unmeasured = np.isnan(y)
            e[unmeasured] = 0.0
        if not (all_measured and self._prev_all_measured):
            y_dot[np.isnan(y_dot)] = 0.0

        base = tau_ff + self._kp * e - self._kd * y_dot  # everything but the integral

        # I_k = I_k-1 + k_i e dt, clamped to |I| <= integral_limit.
        i_old = self._integral
        delta = self._ki * e * dt
        integral = np.minimum(np.maximum(i_old + delta, self._i_lo), self._i_lim)
        u = base + integral
        # Conditional integration: where the output would pass tau_max in the direction e
        # pushes (k_i >= 0), integrate only up to the limit (room = sgn(e) tau_max - base - I),
        # never beyond; with no room left the integral is held.
        windup = (np.abs(u) > self._tau_max) & (e * u > 0.0)
        if windup.any():
            w = windup
            room = np.copysign(self._tau_max[w], e[w]) - base[w] - i_old[w]
            partial = np.minimum(np.maximum(delta[w], np.minimum(room, 0.0)),
                                 np.maximum(room, 0.0))
            integral[w] = np.minimum(np.maximum(i_old[w] + partial, self._i_lo[w]),
                                     self._i_lim[w])
            u = base + integral
        if not all_measured:
            integral[unmeasured] = i_old[unmeasured] if self.freeze_lost_integral else 0.0
            u = base + integral
        tau = np.minimum(np.maximum(u, self._tau_lo), self._tau_max)

        self._integral = integral
        self._y_prev = y.copy()
        self._y_dot = y_dot
        self._prev_all_measured = all_measured
        return ControlOutput(tau, tau_ff, integral.copy(), np.abs(u) > self._tau_max)


class VelocityReference:
    """Reference model for the velocity goal: a first-order filter with an acceleration limit.

    nu_ref_dot = sat((nu_goal - nu_ref) / T, a_max),  nu_ref += nu_ref_dot dt  (per DOF)

    A step in the operator's goal becomes a reachable trajectory; the controller's
    feed-forward then uses nu_ref and nu_ref_dot (Fossen 2021, ch. 12, reference models),
    so a vehicle whose model is right follows nu_ref without waiting for feedback.
    """

    def __init__(self, time_constant: ArrayLike, max_accel: ArrayLike) -> None:
        self.time_constant = vector('time_constant', time_constant, 6)
        self.max_accel = vector('max_accel', max_accel, 6)
        # An infinite time constant would never move; an infinite max_accel is no limit.
        if not np.all(np.isfinite(self.time_constant) & (self.time_constant > 0.0)):
            raise ValueError(f'time_constant must be finite and > 0, got {self.time_constant}')
        if not np.all(self.max_accel > 0.0):
            raise ValueError(f'max_accel must be > 0, got {self.max_accel}')
        self.nu_ref = np.zeros(6)
        self.nu_ref_dot = np.zeros(6)

    def reset(self, nu: ArrayLike | None = None) -> None:
        """Start the reference at ``nu`` (zero when None)."""
        self.nu_ref = np.zeros(6) if nu is None else vector('nu', nu, 6).copy()
        self.nu_ref_dot = np.zeros(6)

    def step(self, nu_goal: ArrayLike, dt: float) -> tuple[Vector, Vector]:
        """Advance by ``dt`` [s] toward ``nu_goal``; return (nu_ref, nu_ref_dot)."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        goal = vector('nu_goal', nu_goal, 6)
        if not _all_finite(goal):  # one NaN would poison the reference for good
            raise ValueError(f'nu_goal must be finite, got {goal}')
        # Never step past the goal: the rate is also limited to (goal - ref) / dt.
        rate = (goal - self.nu_ref) / np.maximum(self.time_constant, dt)
        self.nu_ref_dot = np.clip(rate, -self.max_accel, self.max_accel)
        self.nu_ref = self.nu_ref + self.nu_ref_dot * dt
        return self.nu_ref, self.nu_ref_dot
