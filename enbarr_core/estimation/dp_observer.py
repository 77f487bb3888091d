"""Nonlinear passive DP observer of a 3-DOF surface vessel, without a wave filter.

Fossen 2021 (Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed.), ch. 13,
nonlinear passive observer, here for a calm basin (no first-order wave model). With the pose
measurement y = [x, y, psi] (motion capture, world ENU, psi CCW from east):

    y_tilde     = y - eta_hat                     (heading through ssa)
    eta_hat_dot = R(psi) nu_hat + K1 y_tilde
    b_hat_dot   = -T_b^-1 b_hat + K2 y_tilde      (world-frame bias [N, N, N m])
    M nu_hat_dot = -D nu_hat - D_n(nu_hat) nu_hat - C(nu_hat) nu_hat
                   + R(psi)^T b_hat + tau + R(psi)^T K3 y_tilde

with D_n(nu) = diag(Dn) |nu| and, for a diagonal M (the rigid-body Coriolis for M11 = M22),
C(nu) nu = [-M22 v r, M11 u r, (M22 - M11) u v]. R uses the measured heading when a pose
arrives (the observer is then linear in the estimation error, the basis of its passivity
proof) and psi_hat while dead reckoning.

Gains. For a slowly turning vessel and T_b -> inf the error per DOF obeys
M s^3 + (D + M K1) s^2 + (D K1 + K3) s + K2 = 0, so :func:`place_observer_gains` picks K1, K2,
K3 for chosen error poles. K1 and K3 must have equal x and y entries (then they commute with
R(psi)). The quadratic damping adds dissipation to the error dynamics (D_n(nu) nu is monotone),
but as extra damping D_eff = D + 2 Dn |nu| it also slows the bias poles while the vessel moves:
choose the poles with that in mind (a vessel profile's comments say how its gains were placed).

Measurement handling, in this order:

* ``y is None``: dropout. y_tilde = 0 and the model keeps integrating (dead reckoning).
* y further than ``max_position_jump`` [m] or ``max_heading_jump`` [rad] from eta_hat:
  implausible (a mocap glitch or a marker swap); rejected, counted in ``rejected`` and treated
  as a dropout.
* But when the rejected poses stay mutually consistent (each within the jump limits of the
  previous rejected one) for ``stale_after`` seconds, it is the estimate that is wrong (it
  drifted during a long dropout, or the mocap origin moved): eta_hat is re-initialized to y,
  nu_hat to the finite difference of those poses, b_hat is kept (counted in
  ``reinitializations``). Without this rule a drifted estimate would reject every good
  measurement forever. Random outliers are not consistent with each other and never do this.

Discretization: explicit second-order Runge-Kutta (Heun) over dt, tau held, y interpolated
linearly from the previous accepted pose (first-order hold; held after a dropout). The test
suite shows it matches a fine RK4 of the same ODE at 50 Hz.

Divergence: Heun is only stable for dt well under the fastest error time constant (the
quadratic yaw damping makes that ~2 / (Dn |r| / M) = 0.03 s at 1 rad/s for the CS Saucer). A
dt far beyond it (a pose stamped seconds ahead, before the node's time policy refused such
poses) blows the state up to inf within a few steps. The heading is wrapped at both Heun
stages (so trigonometry never sees inf), and a state that is no longer finite is dropped:
the observer is uninitialized again (stale, age inf, counted in ``divergences``, the step's
estimate says ``diverged``) and the next pose starts it over.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.kinematics import ssa
from enbarr_core.framework.checks import check_gain_vectors, floats

Vector = NDArray[np.float64]



@dataclass(frozen=True)
class ObserverSettings:
    """Gains, model and measurement checks; every tuple is a diagonal [x/X, y/Y, psi/N]."""

    K1: tuple[float, ...]    # position injection [1/s]
    K2: tuple[float, ...]    # bias injection [N/m, N/m, N m/rad per s]
    K3: tuple[float, ...]    # velocity injection [N/m, N/m, N m/rad]
    T_b: tuple[float, ...]   # bias time constants [s] (+inf: pure integrator)
    M: tuple[float, ...]     # inertia M = M_RB + M_A [kg, kg, kg m^2]
    D: tuple[float, ...]     # linear damping [N s/m, N s/m, N m s/rad]
    Dn: tuple[float, ...]    # quadratic damping D_n = diag(Dn) |nu| [N s^2/m^2, ...]
    stale_after: float = 0.5         # age above which the estimate is stale [s]
    max_position_jump: float = 0.5   # |y_xy - eta_hat_xy| above this is implausible [m]
    max_heading_jump: float = 0.5    # |ssa(y_psi - psi_hat)| above this is implausible [rad]

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        check_gain_vectors(self, ('K1', 'K2', 'K3', 'T_b', 'M', 'D', 'Dn'), 3, 'x y psi',
                           may_be_infinite=('T_b',), positive=('T_b', 'M'))
        for name in ('K1', 'K3'):
            raw = getattr(self, name)
            if float(raw[0]) != float(raw[1]):
                raise ValueError(f'{name}: x and y entries must be equal (R(psi) K = K R(psi)),'
                                 f' got {raw!r}')
        for name in ('stale_after', 'max_position_jump', 'max_heading_jump'):
            raw = getattr(self, name)
            try:
                value = float(raw)
            except (TypeError, ValueError) as exc:
                raise ValueError(f'{name}: must be a number, got {raw!r}') from exc
            if not (value > 0.0 and not math.isnan(value)):
                raise ValueError(f'{name}: must be positive, got {raw!r}')


def place_observer_gains(M: ArrayLike, D: ArrayLike,
                         poles: ArrayLike) -> tuple[tuple[float, ...], ...]:
    """K1, K2, K3 giving each DOF the linear error poles s = -p for the 3 values p of ``poles``.

    Matches M s^3 + (D + M K1) s^2 + (D K1 + K3) s + K2 to M (s + p1)(s + p2)(s + p3).
    ``poles`` is (3,) (the same for every DOF) or (3 DOF, 3); complex p come in conjugate
    pairs. Raises ValueError when the poles are slower than the open-loop damping allows.
    """
    m, d = np.asarray(M, dtype=float), np.asarray(D, dtype=float)
    p = np.broadcast_to(np.asarray(poles, dtype=complex), (3, 3))
    coeffs = np.array([np.poly(-row) for row in p])  # [1, c1, c2, c3] per DOF
    if np.abs(coeffs.imag).max() > 1e-9 or (p.real <= 0.0).any():
        raise ValueError(f'poles: need positive real parts and conjugate pairs, got {p.tolist()}')
    c1, c2, c3 = coeffs.real[:, 1], coeffs.real[:, 2], coeffs.real[:, 3]
    k1 = c1 - d / m
    k3 = m * c2 - d * k1
    k2 = m * c3
    if (k1 < 0.0).any() or (k3 < 0.0).any():
        raise ValueError(f'poles: {p.tolist()} too slow for damping D / M = {(d / m).tolist()}')
    return tuple(map(float, k1)), tuple(map(float, k2)), tuple(map(float, k3))


@dataclass(frozen=True, eq=False)
class ObserverEstimate:
    """One observer step. Arrays are fresh per call (``eq=False``)."""

    eta_hat: Vector      # (3,) [x, y, psi] world ENU [m, m, rad], psi in [-pi, pi)
    nu_hat: Vector       # (3,) [u, v, r] body FLU [m/s, m/s, rad/s]
    b_hat: Vector        # (3,) world-frame bias [N, N, N m]
    stale: bool          # age > stale_after: dead reckoning for too long
    age: float           # time since the last accepted measurement [s] (inf: never)
    accepted: bool       # this step's y was used (or re-initialized the estimate)
    rejected_jump: bool  # this step's y was rejected as an implausible jump
    reinitialized: bool = False  # this step's y re-initialized eta_hat
    diverged: bool = False       # the state stopped being finite: dropped, uninitialized


class PassiveObserver:
    """Call :meth:`step` once per control period with the newest pose (or None)."""

    def __init__(self, settings: ObserverSettings) -> None:
        self._x = [0.0] * 9                # [eta_hat, nu_hat, b_hat]
        self._y_prev: tuple[float, float, float] | None = None  # last accepted pose
        self._initialized = False
        self._age = math.inf
        self._far_time = 0.0               # how long consistent far poses have been seen [s]
        self._far_y: tuple[float, float, float] | None = None  # last rejected pose
        self._far_first: tuple[float, float, float] | None = None  # first of the consistent ones
        self.rejected = 0                  # measurements rejected as implausible jumps
        self.reinitializations = 0         # re-initializations from consistent far poses
        self.divergences = 0               # states dropped for not being finite
        self.settings = settings

    @property
    def settings(self) -> ObserverSettings:
        """The settings in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: ObserverSettings) -> None:
        """Swap gains/model at run time (validated first; the state is kept)."""
        settings.validate()
        self._settings = settings
        self._k1 = tuple(map(float, settings.K1))
        self._k2 = tuple(map(float, settings.K2))
        self._k3 = tuple(map(float, settings.K3))
        self._tb_inv = tuple(1.0 / float(t) for t in settings.T_b)  # inf -> 0
        self._m_inv = tuple(1.0 / float(m) for m in settings.M)
        self._m11, self._m22 = float(settings.M[0]), float(settings.M[1])
        self._dl = tuple(map(float, settings.D))
        self._dq = tuple(map(float, settings.Dn))
        self._stale_after = float(settings.stale_after)
        self._max_dp2 = float(settings.max_position_jump) ** 2
        self._max_dpsi = float(settings.max_heading_jump)

    @property
    def initialized(self) -> bool:
        """A first pose (or ``initialize``) has set the state."""
        return self._initialized

    def initialize(self, y: ArrayLike, nu_hat: ArrayLike | None = None,
                   b_hat: ArrayLike | None = None) -> None:
        """Start from the pose ``y`` (and optionally a velocity and a bias guess)."""
        px, py, psi = _triple(y, 'y')
        nu = (0.0, 0.0, 0.0) if nu_hat is None else _triple(nu_hat, 'nu_hat')
        b = (0.0, 0.0, 0.0) if b_hat is None else _triple(b_hat, 'b_hat')
        self._x = [px, py, float(ssa(psi)), *nu, *b]
        self._initialized = True
        self._age = 0.0
        self._y_prev = (px, py, psi)
        self._far_time, self._far_y, self._far_first = 0.0, None, None

    def step(self, y: ArrayLike | None, tau: ArrayLike, dt: float) -> ObserverEstimate:
        """Advance the estimate by ``dt`` [s] to now.

        y: newest pose [x, y, psi] (world ENU, m, rad), taken now, or None (dropout).
        tau: force applied over the interval (the last command) [X, Y, N] body [N, N m].
        Before the first measurement (no :meth:`initialize`) the first y initializes the
        observer; with y None the estimate stays at zero, stale, and nothing integrates.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f'dt must be finite and > 0, got {dt!r}')
        tau = _triple(tau, 'tau')
        if y is not None:
            y = _triple(y, 'y')
        if not self._initialized:
            if y is None:
                return self._estimate(False, False, False)
            self.initialize(y)
            return self._estimate(True, False, False)

        accepted = rejected = False
        if y is not None:
            x = self._x
            dx, dy = y[0] - x[0], y[1] - x[1]
            dpsi = ssa(y[2] - x[2])
            if dx * dx + dy * dy <= self._max_dp2 and abs(dpsi) <= self._max_dpsi:
                accepted = True
                self._far_time, self._far_y = 0.0, None
            else:
                # Far from the estimate. Consistent with the previous far pose? Then the
                # evidence that the estimate (not the sensor) is wrong keeps accumulating.
                prev = self._far_y
                if prev is not None and _close(y, prev, self._max_dp2, self._max_dpsi):
                    self._far_time += dt
                else:
                    self._far_time, self._far_first = 0.0, y
                self._far_y = y
                if self._far_time >= self._stale_after:
                    self._reinitialize(y)
                    return self._estimate(True, False, True)
                rejected = True
                self.rejected += 1
        elif self._far_y is not None:
            self._far_time += dt  # a dropout between far poses does not reset the evidence

        self._integrate(y if accepted else None, tau, dt)
        if not all(map(math.isfinite, self._x)):
            return self._diverged()
        self._age = 0.0 if accepted else self._age + dt
        return self._estimate(accepted, rejected, False)

    # -- internals -------------------------------------------------------------------------

    def _diverged(self) -> ObserverEstimate:
        """Drop a state that is no longer finite: uninitialized, the next pose starts over."""
        self._x = [0.0] * 9
        self._initialized = False
        self._age = math.inf
        self._y_prev = None
        self._far_time, self._far_y, self._far_first = 0.0, None, None
        self.divergences += 1
        x = np.zeros(9)
        return ObserverEstimate(x[0:3], x[3:6], x[6:9], True, math.inf, False, False,
                                diverged=True)

    def _reinitialize(self, y: tuple[float, float, float]) -> None:
        """Set eta_hat = y, nu_hat from the consistent far poses, keep b_hat.

        nu_hat is a finite difference over the window (~0.02 m/s of noise over 0.5 s), as the
        dead-reckoned one is as stale as the pose.
        """
        first, span = self._far_first, self._far_time
        assert first is not None  # set with the first pose of the far run that ends here
        c, s = math.cos(y[2]), math.sin(y[2])
        vx, vy = (y[0] - first[0]) / span, (y[1] - first[1]) / span  # world velocity
        r = (ssa(y[2] - first[2])) / span
        x = self._x
        x[0:6] = [y[0], y[1], ssa(y[2]),
                  c * vx + s * vy, -s * vx + c * vy, r]   # nu = R^T v
        self._y_prev = y
        self._far_time, self._far_y, self._far_first = 0.0, None, None
        self._age = 0.0
        self.reinitializations += 1
    # The state is 9 Python floats: on 3-vectors, scalar arithmetic is several times faster
    # than numpy's per-call overhead, and this runs at up to 400 Hz.

    def _f(self, x: list[float], y: tuple[float, float, float] | None,
           tau: tuple[float, float, float]) -> list[float]:
        """Right-hand side d/dt [eta_hat, nu_hat, b_hat] with y held (None: dropout)."""
        px, py, psi, u, v, r, bx, by, bn = x
        d1, d2, d3 = self._dl
        n1, n2, n3 = self._dq
        m11, m22 = self._m11, self._m22
        # R(psi) of the measured heading when there is one, else of psi_hat
        c, s = math.cos(psi if y is None else y[2]), math.sin(psi if y is None else y[2])
        # M nu_dot = tau + R^T b_hat - (D + D_n(nu)) nu - C(nu) nu (+ R^T K3 y_tilde)
        fx = tau[0] - (d1 + n1 * abs(u)) * u + m22 * v * r + c * bx + s * by
        fy = tau[1] - (d2 + n2 * abs(v)) * v - m11 * u * r - s * bx + c * by
        fn = tau[2] - (d3 + n3 * abs(r)) * r - (m22 - m11) * u * v + bn
        # eta_hat_dot = R nu_hat (+ K1 y_tilde), b_hat_dot = -T_b^-1 b_hat (+ K2 y_tilde)
        ex, ey, ep = c * u - s * v, s * u + c * v, r
        tb1, tb2, tb3 = self._tb_inv
        gx, gy, gn = -tb1 * bx, -tb2 * by, -tb3 * bn
        if y is not None:
            tx, ty = y[0] - px, y[1] - py
            tp = ssa(y[2] - psi)
            k11, k12, k13 = self._k1
            k21, k22, k23 = self._k2
            k31, k32, k33 = self._k3
            ex, ey, ep = ex + k11 * tx, ey + k12 * ty, ep + k13 * tp
            gx, gy, gn = gx + k21 * tx, gy + k22 * ty, gn + k23 * tp
            kx, ky = k31 * tx, k32 * ty
            fx += c * kx + s * ky
            fy += -s * kx + c * ky
            fn += k33 * tp
        mi1, mi2, mi3 = self._m_inv
        return [ex, ey, ep, mi1 * fx, mi2 * fy, mi3 * fn, gx, gy, gn]

    def _integrate(self, y: tuple[float, float, float] | None,
                   tau: tuple[float, float, float], dt: float) -> None:
        # Heun: k1 = f(x), k2 = f(x + dt k1), x += dt (k1 + k2) / 2.
        # The pose between samples is the line from the previous accepted pose to y (a
        # first-order hold, exact at both Heun stages): an O(dt^2) discretization. A plain
        # zero-order hold of y (the newest sample over the whole interval) would bias the
        # estimate by O(speed dt). After a dropout y is held.
        x = self._x
        y0 = self._y_prev if (y is not None and self._y_prev is not None) else y
        k1 = self._f(x, y0, tau)
        x1 = [xi + dt * ki for xi, ki in zip(x, k1)]
        x1[2] = ssa(x1[2])  # cos(inf) raises, ssa(inf) is NaN (see Divergence)
        k2 = self._f(x1, y, tau)
        self._y_prev = y
        h = 0.5 * dt
        x = [xi + h * (a + b) for xi, a, b in zip(x, k1, k2)]
        x[2] = ssa(x[2])
        self._x = x

    def _estimate(self, accepted: bool, rejected: bool, reinit: bool) -> ObserverEstimate:
        x = np.array(self._x)
        return ObserverEstimate(x[0:3], x[3:6], x[6:9], self._age > self._stale_after,
                                self._age, accepted, rejected, reinit)


def _triple(value: ArrayLike, what: str) -> tuple[float, float, float]:
    """``value`` as 3 finite floats (``ValueError`` naming ``what``)."""
    return floats(what, value, 3)

def _close(a: tuple[float, float, float], b: tuple[float, float, float], max_dp2: float,
           max_dpsi: float) -> bool:
    dx, dy = a[0] - b[0], a[1] - b[1]
    return (dx * dx + dy * dy <= max_dp2
            and abs(ssa(a[2] - b[2])) <= max_dpsi)
