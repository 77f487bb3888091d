"""Collision avoidance at the force level: a high-order CBF on the 3-DOF model (an option).

The guidance-level filter (:mod:`guidance.cbf`) keeps the *desired* position clear and relies
on the controller tracking it within a margin. This one filters the controller's force
instead, so it needs no tracking margin but relies on the model (Xiao and Belta 2019, High
order control barrier functions; Fossen 2021 for the model). With p the position (world),
p_dot = R(psi) nu_xy and, for the 3-DOF model of :mod:`models.vessel3dof` (no current),

    nu_dot = M^-1 (tau - C(nu) nu - (D + D_n(nu)) nu)
    p_ddot = R(psi) (nu_dot_xy + r J nu_xy),      J = [[0, -1], [1, 0]]

the barrier h_i = |p - c_i| - r_i has relative degree two in tau. With n_i the unit normal and
w = p_dot - v_o,i (constant obstacle velocity), h_dot = n_i^T w and
h_ddot = n_i^T p_ddot + (|w|^2 - (n_i^T w)^2) / |p - c_i| >= n_i^T p_ddot (the curvature term
is never negative; leaving it out is conservative). The HOCBF condition
psi_1 = h_dot + a1 h, psi_1_dot + a2 psi_1 >= 0 then holds when

    n_i^T R(psi) M^-1 [tau_x, tau_y]  >=  - n_i^T R(psi) (M^-1 f(nu) + r J nu)_xy
                                          - (a1 + a2) h_dot - a1 a2 h,

f(nu) = -C(nu) nu - (D + D_n(nu)) nu: linear in tau. Per step
tau* = argmin |tau - tau_nom|^2 s.t. those rows and |tau_j| <= tau_max_j (the thrust limits
as the controller's output box), solved by daqp; infeasible: a brake, tau_xy = -k M nu_xy
clipped to the box (yaw as nominal), with a reason.

Passing (``pass_gain``; 0 turns it off), as the guidance-level filter does it: the QP alone
stops the vessel in front of an obstacle that lies across tau_nom (the CBF's local minimum),
so the force lost to a binding barrier, |tau_nom,xy| - |tau*_xy|, times ``pass_gain``, is
added along that barrier's tangent (the side chosen once per engagement: starboard unless
tau_nom leans clearly to port) and the QP solved again from there: every constraint and the
box still hold. Stateful for that side only: :meth:`ForceSafetyFilter.step` once per force.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import daqp
import numpy as np
from numpy.typing import NDArray

from enbarr_core.guidance.cbf import constraints, CbfSettings

Vector = NDArray[np.float64]
_BRAKE_RATE = 5.0   # k of the brake [1/s]: as hard as the force box lets it


@dataclass(frozen=True)
class ForceCbfSettings:
    """Settings of :class:`ForceSafetyFilter`."""

    M: tuple[float, float, float]        # inertia diagonal [kg, kg, kg m^2]
    D: tuple[float, float, float]        # linear damping diagonal
    Dn: tuple[float, float, float]       # quadratic damping diagonal
    tau_max: tuple[float, float, float]  # |tau| box [N, N, N m]
    safety_radius: float = 0.2           # hull clearance to keep [m]
    vessel_radius: float = 0.0           # hull radius [m]
    a1: float = 1.0                      # class-K rates [1/s]
    a2: float = 1.0
    pass_gain: float = 0.0               # tangential force / force lost at a blocking obstacle

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ('M', 'D', 'Dn', 'tau_max'):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(x) for x in value):
                raise ValueError(f'{name}: expected three finite numbers, got {value!r}')
        for name in ('M', 'tau_max'):
            if min(getattr(self, name)) <= 0.0:
                raise ValueError(f'{name}: every element must be > 0, got '
                                 f'{getattr(self, name)!r}')
        for name in ('safety_radius', 'vessel_radius', 'a1', 'a2', 'pass_gain'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name}: must be a finite number >= 0, got {value!r}')
        if self.a1 <= 0.0 or self.a2 <= 0.0:
            raise ValueError(f'a1, a2: must be > 0, got {self.a1!r}, {self.a2!r}')


@dataclass(frozen=True)
class ForceOutput:
    """The filtered force and what happened."""

    tau: Vector
    engaged: bool
    infeasible: bool
    min_barrier: float
    reason: str = ''
    active: int = 0         # obstacle constraints binding at tau


class ForceSafetyFilter:
    """tau_nom -> tau* keeping every obstacle's HOCBF condition (module docstring)."""

    def __init__(self, settings: ForceCbfSettings) -> None:
        self.settings = settings
        self.infeasible_count = 0
        self.side = 0   # passing side of this engagement (world): +1 starboard, -1 port, 0 none

    @property
    def settings(self) -> ForceCbfSettings:
        """The settings in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: ForceCbfSettings) -> None:
        """Swap settings (validated first), the zones' geometry with them."""
        settings.validate()
        self._settings = settings
        self._geometry = CbfSettings(safety_radius=settings.safety_radius,
                                     vessel_radius=settings.vessel_radius, tracking_margin=0.0,
                                     gamma=1.0)

    def step(self, eta: Vector, nu: Vector, tau_nom: Vector, rows: Vector) -> ForceOutput:
        """Filter ``tau_nom`` at the state (eta, nu) against obstacle ``rows`` (world)."""
        s = self.settings
        psi, (u, v, r) = float(eta[2]), (float(nu[0]), float(nu[1]), float(nu[2]))
        c, sn = math.cos(psi), math.sin(psi)
        R = np.array([[c, -sn], [sn, c]])
        m1, m2 = s.M[0], s.M[1]
        # f(nu) = -C(nu) nu - (D + D_n) nu, C(nu) nu = [-m22 v r, m11 u r, .] (diagonal M)
        fx = m2 * v * r - (s.D[0] + s.Dn[0] * abs(u)) * u
        fy = -m1 * u * r - (s.D[1] + s.Dn[1] * abs(v)) * v
        drift = R @ np.array((fx / m1 - r * v, fy / m2 + r * u))   # p_ddot at tau = 0
        gain = R @ np.diag((1.0 / m1, 1.0 / m2))                   # d p_ddot / d tau_xy
        p, p_dot = np.asarray(eta[:2], dtype=float), R @ np.array((u, v))
        n, _, h = constraints(p, rows, self._geometry)
        if not len(h):
            self.side = 0
            return ForceOutput(np.asarray(tau_nom, dtype=float), False, False, math.inf)
        h_dot = n @ p_dot - np.einsum('ij,ij->i', n, rows[:, 5:7])
        A = n @ gain                                                # (k, 2)
        lower = -(n @ drift) - (s.a1 + s.a2) * h_dot - s.a1 * s.a2 * h
        t_xy = np.asarray(tau_nom[:2], dtype=float)
        if np.all(A @ t_xy >= lower) and np.all(np.abs(t_xy) <= s.tau_max[:2]):
            self.side = 0
            return ForceOutput(np.asarray(tau_nom, dtype=float), False, False, float(h.min()))
        x, flag = self._solve(t_xy, A, lower)
        if flag == 1 and s.pass_gain > 0.0:
            binding = A @ x - lower <= 1e-7
            lost = float(np.hypot(*t_xy)) - float(np.hypot(*x))
            if binding.any() and lost > 0.0:
                i = int(np.argmin(np.where(binding, h, np.inf)))
                t = R.T @ np.array((-n[i, 1], n[i, 0]))   # the tangent, body frame
                if self.side == 0:
                    lean = float(t @ t_xy) >= -0.2 * float(np.hypot(*t_xy))
                    self.side = 1 if lean else -1
                again, ok = self._solve(x + s.pass_gain * lost * self.side * t, A, lower)
                if ok == 1:
                    x = again
        if flag != 1:
            self.infeasible_count += 1
            brake = np.clip(-_BRAKE_RATE * np.array((m1 * u, m2 * v)),
                            -np.asarray(s.tau_max[:2]), np.asarray(s.tau_max[:2]))
            return ForceOutput(np.array((brake[0], brake[1], float(tau_nom[2]))), True, True,
                               float(h.min()), 'infeasible: braking')
        active = int(np.count_nonzero(A @ x - lower <= 1e-7))
        return ForceOutput(np.array((x[0], x[1], float(tau_nom[2]))), True, False,
                           float(h.min()), active=active)

    def _solve(self, t_xy: Vector, A: Vector, lower: Vector) -> tuple[Vector, int]:
        """Solve min |tau - t_xy|^2 s.t. A tau >= lower and the box: (tau_xy, daqp exit flag)."""
        box = np.asarray(self.settings.tau_max[:2], dtype=float)
        bu = np.concatenate((box, np.full(len(lower), 1e30)))
        bl = np.concatenate((-box, lower))
        x, _, flag, _ = daqp.solve(np.eye(2), -t_xy, A, bu, bl,
                                   np.zeros(len(bu), dtype=np.int32))
        return np.asarray(x, dtype=float), int(flag)
