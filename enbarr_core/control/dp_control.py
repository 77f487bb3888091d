"""DP and trajectory-tracking control of a 3-DOF surface vessel: nonlinear PID + feed-forward.

Fossen 2021 (Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed.), ch. 12 and
15 (nonlinear PID for DP, model-based feed-forward). With eta_hat = [x, y, psi] (world ENU),
nu_hat = [u, v, r] (body FLU), the world bias b_hat of the observer and a
:class:`~enbarr_core.guidance.guidance.Reference` (eta_d, nu_d, nu_d_dot, position_mask):

    e        = R(psi)^T [x - x_d, y - y_d, ssa(psi - psi_d)]   (body-frame pose error)
    nu_tilde = nu_hat - nu_d
    tau_ff   = M nu_d_dot + (D + D_n(nu_d) + C(nu_d)) nu_d - R(psi)^T b_hat
    tau      = sat(tau_ff - Kp e - I - Kd nu_tilde),   I_dot = Ki e

D_n(nu) = diag(Dn) |nu|, C(nu) nu = [-M22 v r, M11 u r, (M22 - M11) u v] (the rigid-body
Coriolis of a diagonal M). Gains and model come from the vessel's profile. The bias term is
used when ``bias_feedforward`` is on.

* position_mask: pose-error components (world x, y, psi) where the mask is False are ignored
  before the rotation: that DOF tracks nu_d only (LOS path following uses
  [False, False, True]: surge/sway follow nu_d, heading follows psi_d). eta_d may be NaN
  there (no position reference for that DOF, as ``guidance/reference`` carries it).
* Integral: stored as its contribution I [N, N m] (a new Ki never steps the output). Each step
  I += Ki e dt in the body frame, but between steps it is kept rotated into the world frame
  (z = R(psi) I), so a world-fixed disturbance (current, wind) stays compensated while the
  vessel turns (Fossen's nonlinear PID integrates the world-frame error the same way).
* Anti-windup: conditional integration (a DOF whose output is past tau_max in the direction its
  error pushes integrates only up to the limit, never beyond) plus the clamp
  |I| <= integral_limit.
* Live gains: a new ``settings`` does not act at once. Every numeric field (gains, limits, model,
  the bias feed-forward weight 0/1) moves linearly from the value in use to the new one over
  the new ``gain_ramp_time`` [s], so tau stays continuous. An entry going to or from +inf
  switches at once.
* Bumpless mode entry: ``reset(tau_now)`` makes the next output equal tau_now (e.g. the manual
  force when the operator switches to automatic) by solving for I; the integral then takes
  over. Any part of that I beyond integral_limit bleeds off with time constant
  gain_ramp_time instead of being cut at once; so does all of it in a DOF whose Ki is 0
  (nothing would integrate it away: a PD loop would keep that force for good).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.checks import check_gain_vectors, check_non_negative
from enbarr_core.framework.kinematics import ssa
from enbarr_core.framework.checks import floats

if TYPE_CHECKING:
    from enbarr_core.guidance.guidance import Reference

Vector = NDArray[np.float64]

_VECTOR_FIELDS = ('Kp', 'Ki', 'Kd', 'integral_limit', 'tau_max', 'M', 'D', 'Dn')
_MAY_BE_INFINITE = ('integral_limit', 'tau_max')  # +inf means "no limit"


@dataclass(frozen=True)
class DpControlSettings:
    """Gains, limits and model; every tuple is a diagonal [surge X, sway Y, yaw N]."""

    Kp: tuple[float, ...]              # proportional [N/m, N/m, N m/rad]
    Ki: tuple[float, ...]              # integral [N/(m s), N/(m s), N m/(rad s)]
    Kd: tuple[float, ...]              # derivative (on nu_tilde) [N s/m, N s/m, N m s/rad]
    integral_limit: tuple[float, ...]  # |I| clamp [N, N, N m] (+inf: none)
    tau_max: tuple[float, ...]         # output limits |tau| [N, N, N m] (> 0, +inf: none)
    M: tuple[float, ...]               # inertia M = M_RB + M_A [kg, kg, kg m^2]
    D: tuple[float, ...]               # linear damping [N s/m, N s/m, N m s/rad]
    Dn: tuple[float, ...]              # quadratic damping D_n = diag(Dn) |nu|
    gain_ramp_time: float = 1.0        # time a settings change takes to take full effect [s]
    bias_feedforward: bool = True      # cancel the observer's bias: tau_ff -= R^T b_hat

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        check_gain_vectors(self, _VECTOR_FIELDS, 3, 'X Y N', may_be_infinite=_MAY_BE_INFINITE,
                           positive=('tau_max', 'M'))
        check_non_negative(self, ('gain_ramp_time',))
        if not isinstance(self.bias_feedforward, (bool, np.bool_)):
            raise ValueError(f'bias_feedforward: must be a bool, got {self.bias_feedforward!r}')


@dataclass(frozen=True, eq=False)
class DpOutput:
    """One control step. Arrays are fresh per call (``eq=False``)."""

    tau: Vector                   # (3,) commanded [X, Y, N] after saturation [N, N m]
    tau_ff: Vector                # (3,) feed-forward part [N, N m]
    integral: Vector              # (3,) integral contribution I (body frame) [N, N m]
    saturated: NDArray[np.bool_]  # (3,) |unsaturated tau| > tau_max
    error: Vector                 # (3,) body-frame pose error e (masked) [m, m, rad]


def _params(s: DpControlSettings) -> list[float]:
    """Flat list of everything the ramp interpolates (25 floats, order as unpacked below)."""
    return [float(v) for name in _VECTOR_FIELDS for v in getattr(s, name)] + \
        [1.0 if s.bias_feedforward else 0.0]


class DpController:
    """Three coupled pose loops; call :meth:`step` once per control period."""

    def __init__(self, settings: DpControlSettings) -> None:
        self._z = [0.0, 0.0, 0.0]          # integral contribution, world frame (z = R I)
        self._allow = [0.0, 0.0, 0.0]      # bleeding clamp allowance after a bumpless reset
        self._tau_now: tuple[float, float, float] | None = None
        self._p: list[float] = []
        self._p_from: list[float] = []
        self._p_to: list[float] = []
        self._ramp_t = 0.0                 # time into the current ramp [s]
        self._ramp_T = 0.0                 # ramp duration [s] (0: none in progress)
        self.settings = settings

    @property
    def settings(self) -> DpControlSettings:
        """The settings being blended in (or in use when no ramp is in progress)."""
        return self._settings

    @settings.setter
    def settings(self, settings: DpControlSettings) -> None:
        """Swap settings at run time (validated first); they take effect over gain_ramp_time."""
        settings.validate()
        target = _params(settings)
        self._settings = settings
        ramp = float(settings.gain_ramp_time)
        if not self._p or ramp == 0.0:
            self._p, self._ramp_T = target, 0.0
            return
        self._p_from, self._p_to = list(self._p), target  # from the values in use now
        self._ramp_t, self._ramp_T = 0.0, ramp

    @property
    def ramping(self) -> bool:
        """A settings change is still being blended in."""
        return self._ramp_T > 0.0

    def reset(self, tau_now: ArrayLike | None = None) -> None:
        """Clear the integral; with ``tau_now`` [X, Y, N], the next output equals it (bumpless).

        The integral absorbs the difference between tau_now and what the other terms ask for
        at the next step (tau_now is first limited to tau_max).
        """
        self._z = [0.0, 0.0, 0.0]
        self._allow = [0.0, 0.0, 0.0]
        self._tau_now = None if tau_now is None else _triple(tau_now, 'tau_now')

    @property
    def integral(self) -> Vector:
        """The stored integral contribution, world frame [N, N, N m]."""
        return np.array(self._z)

    def step(self, eta_hat: ArrayLike, nu_hat: ArrayLike, b_hat: ArrayLike, ref: Reference,
             dt: float) -> DpOutput:
        """One control period of ``dt`` [s] (> 0)."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        x, y, psi = _triple(eta_hat, 'eta_hat')
        u, v, r = _triple(nu_hat, 'nu_hat')
        bx, by, bn = _triple(b_hat, 'b_hat')
        mx, my, mpsi = ref.position_mask
        xd, yd, psid = _triple(ref.eta_d, 'ref.eta_d', ref.position_mask)
        ud, vd, rd = _triple(ref.nu_d, 'ref.nu_d')
        ad, bd, cd = _triple(ref.nu_d_dot, 'ref.nu_d_dot')

        if self._ramp_T > 0.0:  # linear blend of every numeric setting
            self._ramp_t += dt
            a = self._ramp_t / self._ramp_T  # from a >= 1 on: the target itself, exactly
            self._p = [t if (a >= 1.0 or not (math.isfinite(f) and math.isfinite(t)))
                       else f + a * (t - f) for f, t in zip(self._p_from, self._p_to)]
            if a >= 1.0:
                self._ramp_T = 0.0
        (kp1, kp2, kp3, ki1, ki2, ki3, kd1, kd2, kd3, il1, il2, il3, tm1, tm2, tm3,
         m1, m2, m3, d1, d2, d3, n1, n2, n3, wb) = self._p

        c, s = math.cos(psi), math.sin(psi)
        # e = R^T [x - x_d, y - y_d, ssa(psi - psi_d)], masked components ignored
        ewx = x - xd if mx else 0.0
        ewy = y - yd if my else 0.0
        e3 = ssa(psi - psid) if mpsi else 0.0
        e1, e2 = c * ewx + s * ewy, -s * ewx + c * ewy
        # tau_ff = M nu_d_dot + (D + D_n(nu_d)) nu_d + C(nu_d) nu_d - w_b R^T b_hat
        f1 = m1 * ad + (d1 + n1 * abs(ud)) * ud - m2 * vd * rd - wb * (c * bx + s * by)
        f2 = m2 * bd + (d2 + n2 * abs(vd)) * vd + m1 * ud * rd - wb * (-s * bx + c * by)
        f3 = m3 * cd + (d3 + n3 * abs(rd)) * rd + (m2 - m1) * ud * vd - wb * bn
        # Everything but the integral: tau_ff - Kp e - Kd nu_tilde
        base = (f1 - kp1 * e1 - kd1 * (u - ud),
                f2 - kp2 * e2 - kd2 * (v - vd),
                f3 - kp3 * e3 - kd3 * (r - rd))
        zx, zy, zn = self._z
        i_old = (c * zx + s * zy, -s * zx + c * zy, zn)  # I = R^T z
        tau_max = (tm1, tm2, tm3)
        err = (e1, e2, e3)

        integral = [0.0, 0.0, 0.0]
        tau = [0.0, 0.0, 0.0]
        saturated = [False, False, False]
        tau_now = self._tau_now  # set by reset(tau_now): this step is a bumpless entry
        if tau_now is not None:
            # Bumpless entry: I = base - sat(tau_now), so that tau = tau_now now.
            for j in range(3):
                t_now = min(max(tau_now[j], -tau_max[j]), tau_max[j])
                integral[j] = base[j] - t_now
                tau[j] = t_now
            lims = (il1, il2, il3)
            self._allow = [abs(i) if abs(i) > lim else 0.0 for i, lim in zip(integral, lims)]
            self._tau_now = None
        else:
            ramp = self._settings.gain_ramp_time
            bleed = math.exp(-dt / ramp) if ramp > 0.0 else 0.0
            allow = self._allow
            for j, (lim, ki) in enumerate(((il1, ki1), (il2, ki2), (il3, ki3))):
                if allow[j] > 0.0:
                    allow[j] *= bleed
                lim = max(lim, allow[j])
                e, i0, b, tm = err[j], i_old[j], base[j], tau_max[j]
                if ki == 0.0:
                    # Nothing integrates back what a bumpless entry put in I: it would be a
                    # constant force for good. It bleeds off over gain_ramp_time instead.
                    i0 *= bleed
                delta = ki * e * dt  # I_dot = Ki e
                i1 = min(max(i0 + delta, -lim), lim)
                out = b - i1
                if abs(out) > tm and out * e < 0.0:
                    # The integral pushes the output past tau_max (in the direction -e):
                    # integrate only up to the limit, never beyond.
                    room = b + math.copysign(tm, e) - i0
                    part = min(max(delta, min(room, 0.0)), max(room, 0.0))
                    i1 = min(max(i0 + part, -lim), lim)
                    out = b - i1
                integral[j] = i1
                saturated[j] = abs(out) > tm
                tau[j] = min(max(out, -tm), tm)

        i1, i2, i3 = integral
        self._z = [c * i1 - s * i2, s * i1 + c * i2, i3]  # z = R I
        if tau_now is None and not (mx and my and mpsi):
            # A DOF without a pose error cannot integrate back what a bumpless entry (or an
            # earlier hold) left in its integral: that would be a permanent offset in
            # velocity tracking (line-of-sight legs). It bleeds off over gain_ramp_time.
            ramp = self._settings.gain_ramp_time
            decay = math.exp(-dt / ramp) if ramp > 0.0 else 0.0
            self._z = [z if m else z * decay for z, m in zip(self._z, (mx, my, mpsi))]
        return DpOutput(np.array(tau), np.array((f1, f2, f3)), np.array(integral),
                        np.array(saturated), np.array(err))


def _triple(value: ArrayLike, what: str,
            used: tuple[bool, bool, bool] = (True, True, True)) -> tuple[float, float, float]:
    """Three floats, finite where ``used`` (an unused one, say NaN, is returned as 0.0)."""
    if used[0] and used[1] and used[2]:
        return floats(what, value, 3)
    xyz = floats(what, value, 3, finite=False)
    for i, (x, u) in enumerate(zip(xyz, used)):
        if u and not math.isfinite(x):
            raise ValueError(f'{what}[{i}]: must be finite, got {x}')
    return (xyz[0] if used[0] else 0.0, xyz[1] if used[1] else 0.0,
            xyz[2] if used[2] else 0.0)
