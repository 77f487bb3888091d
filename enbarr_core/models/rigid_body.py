"""6-DOF rigid-body model of a small underwater vehicle (Fossen 2021), in REP-103 frames.

    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau + tau_ext

with M = M_RB + M_A, C(nu) = C_RB(nu) + C_A(nu), D(nu) = D_lin + diag(d_quad |nu|) and the
restoring vector g(eta) of weight and buoyancy. In a constant, irrotational current v_c (world
frame) the hydrodynamic terms act on the velocity relative to the water (Fossen 2021, eq. 10.1):

    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau
    nu_r = nu - nu_c,  nu_c = [R^T v_c; 0],  nu_c_dot = [-omega x R^T v_c; 0]

so M nu_dot = tau - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r - g(eta) + M_A nu_c_dot. This
holds for any parametrization of C_RB; with v_c = 0 it is the equation above.

The origin CO of the body frame (FLU) is the point all forces, moments and velocities refer
to. World frame: ENU (z up), so weight acts along world -z and buoyancy along world +z. The
attitude is a unit quaternion ``[x, y, z, w]`` rotating body vectors into the world frame;
eta = (p, q), nu = [u, v, w, p, q, r].

The free surface (``height`` > 0): the water's surface is the world plane z = 0, and the
displaced volume a prism of that height centred on the CB, so the buoyancy is B times the
submerged fraction s = clamp(1/2 - z_b / height, 0, 1) (z_b: the CB's world height; the hull
taken as level for the fraction). A vessel of B > W then floats with the fraction W / B under
water, and one pushed up loses buoyancy as it emerges instead of rising into the air. The
emerged part's CB moves along the vertical, parallel to the force, so the moment stays
(s B) r_b x k. ``height`` 0 is deep water (s = 1 everywhere), as for a vehicle that never
surfaces. Waves, the surface's added mass and damping are not modelled.

Reference: T. I. Fossen, Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed.,
Wiley 2021 (chapter 3 rigid-body kinetics, chapter 4 restoring forces, chapter 6 added mass).

``RigidBodyModel.step`` is written with Python floats instead of small numpy arrays because it
runs at 400 Hz on a Raspberry Pi: per-element arithmetic on 13 states is several times faster
than numpy's per-call overhead. The matrix methods (``coriolis``, ``damping``, ``restoring``)
are the readable reference forms and the tests check the fast path against them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.checks import number, vector
from enbarr_core.framework.kinematics import (
    quat_from_euler,
    quat_normalize,
    quat_to_rotmat,
    skew,
)

Vector = NDArray[np.float64]
Matrix = NDArray[np.float64]
_Six = tuple[float, float, float, float, float, float]  # a 6-DOF vector as floats

# Relative tolerance of the symmetry check on a full 3x3 inertia matrix.
_SYMMETRY_RTOL = 1e-9


def _shape(value: Any) -> tuple[int, ...] | None:
    """``np.shape(value)``, or None for ragged nested sequences."""
    try:
        shape: tuple[int, ...] = np.shape(value)
        return shape
    except ValueError:
        return None


def inertia_matrix(inertia: ArrayLike) -> Matrix:
    """3x3 inertia matrix [kg m^2] from 3 diagonal values or 9 row-major values."""
    a = np.asarray(inertia, dtype=float).ravel()
    if a.shape == (3,):
        return np.diag(a)
    if a.shape == (9,):
        return a.reshape(3, 3).copy()
    raise ValueError(f'inertia: expected 3 or 9 values, got {a.size}')


def coriolis_matrix(M: ArrayLike, nu: ArrayLike) -> Matrix:
    """Parametrization-independent Coriolis-centripetal matrix C(nu) of a 6x6 inertia matrix.

    C(nu) = [[0, -S(M11 nu1 + M12 nu2)], [-S(M11 nu1 + M12 nu2), -S(M21 nu1 + M22 nu2)]]
    (Fossen 2021, Thm 3.2 for M_RB; the same form gives C_A from M_A, ch. 6). C(nu) is
    skew-symmetric for every nu, so nu^T C(nu) nu = 0: C does no work.
    """
    M = np.asarray(M, dtype=float)
    M = 0.5 * (M + M.T)
    nu = np.asarray(nu, dtype=float)
    h = M @ nu  # [dT/dnu1; dT/dnu2] of the kinetic energy T = 1/2 nu^T M nu
    S1 = skew(h[:3])
    C = np.zeros((6, 6))
    C[:3, 3:] = -S1
    C[3:, :3] = -S1
    C[3:, 3:] = -skew(h[3:])
    return C


def coriolis_force(inertia: ArrayLike, nu: ArrayLike) -> Vector:
    """C(nu) nu [N, N m] of a diagonal inertia ``M = diag(inertia)`` at body velocity ``nu``.

    With h = M nu: [w x h_lin; w x h_ang + v x h_lin] (Fossen 2021, Thm 3.2; v = nu[:3],
    w = nu[3:]); the same as ``coriolis_matrix(diag(inertia), nu) @ nu``, written out for a
    control loop at 400 Hz (six products are cheaper than building C).
    """
    nu = np.asarray(nu, dtype=float)
    u, v, w, p, q, r = nu.tolist()
    hu, hv, hw, hp, hq, hr = (np.asarray(inertia, dtype=float) * nu).tolist()
    return np.array([q * hw - r * hv,
                     r * hu - p * hw,
                     p * hv - q * hu,
                     q * hr - r * hq + v * hw - w * hv,
                     r * hp - p * hr + w * hu - u * hw,
                     p * hq - q * hp + u * hv - v * hu])


@dataclass(frozen=True)
class RigidBodyParams:
    """Physical parameters of the vehicle, all about the body origin CO (FLU, SI units)."""

    mass: float  # m [kg]
    inertia: tuple[float, ...]  # I_o about the CO: 9 row-major values or 3 diagonal [kg m^2]
    r_g: tuple[float, float, float]  # centre of gravity CG in body FLU [m]
    r_b: tuple[float, float, float]  # centre of buoyancy CB in body FLU [m]
    buoyancy: float  # B = rho g V [N]
    added_mass: tuple[float, ...]  # diagonal of M_A, positive [kg, kg, kg, kg m^2 x3]
    d_lin: tuple[float, ...]  # linear damping, positive [N s/m x3, N m s/rad x3]
    d_quad: tuple[float, ...]  # quadratic damping, positive [N s^2/m^2 x3, N m s^2/rad^2 x3]
    gravity: float = 9.81  # g [m/s^2]
    height: float = 0.0  # of the displaced volume, for the free surface [m]; 0: deep water

    @property
    def weight(self) -> float:
        """W = m g [N]."""
        return self.mass * self.gravity

    def inertia_matrix(self) -> Matrix:
        """I_o as a 3x3 matrix [kg m^2]."""
        return inertia_matrix(self.inertia)

    def validate(self) -> None:
        """Raise ValueError, starting with the field name, if a parameter is non-physical."""
        mass = number('mass', self.mass)
        if mass <= 0.0:
            raise ValueError(f'mass: must be > 0 kg, got {mass}')
        gravity = number('gravity', self.gravity)
        if gravity <= 0.0:
            raise ValueError(f'gravity: must be > 0 m/s^2, got {gravity}')
        buoyancy = number('buoyancy', self.buoyancy)
        if buoyancy < 0.0:
            raise ValueError(f'buoyancy: must be >= 0 N, got {buoyancy}')
        height = number('height', self.height)
        if height < 0.0:
            raise ValueError(f'height: must be >= 0 m (0: deep water), got {height}')
        r_g = vector('r_g', self.r_g, (3,), finite=True)
        vector('r_b', self.r_b, (3,), finite=True)
        for name in ('added_mass', 'd_lin', 'd_quad'):
            values = vector(name, getattr(self, name), 6, finite=True)
            if np.any(values < 0.0):
                raise ValueError(f'{name}: values must be >= 0, got {values.tolist()}')
        I_o = inertia_matrix(vector('inertia', self.inertia, (3, 9), finite=True))
        scale = float(np.max(np.abs(I_o)))
        if float(np.max(np.abs(I_o - I_o.T))) > _SYMMETRY_RTOL * max(scale, 1.0):
            raise ValueError(f'inertia: matrix is not symmetric: {I_o.tolist()}')
        if float(np.min(np.linalg.eigvalsh(I_o))) <= 0.0:
            raise ValueError(f'inertia: matrix is not positive definite: {I_o.tolist()}')
        # M_RB > 0 needs the inertia about the CG, I_g = I_o + m S(r_g)^2 (parallel axes), > 0.
        S = skew(r_g)
        I_g = I_o + mass * (S @ S)
        if float(np.min(np.linalg.eigvalsh(0.5 * (I_g + I_g.T)))) <= 0.0:
            raise ValueError(
                'inertia: the inertia about the CG, I_o + m S(r_g)^2, is not positive definite '
                f'(inertia {I_o.tolist()} is too small for r_g {r_g.tolist()})')

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any]) -> RigidBodyParams:
        """Build and validate parameters from a mapping whose keys are the field names.

        Sequences (lists, tuples, arrays) are accepted for the vector fields, and a nested 3x3
        list for ``inertia``; ``gravity`` and ``height`` are optional. Unknown or missing keys
        raise ValueError naming them.
        """
        names = [f.name for f in fields(cls)]
        unknown = sorted(str(k) for k in set(d) - set(names))
        if unknown:
            bad, known = ', '.join(unknown), ', '.join(names)
            raise ValueError(f'{bad}: unknown key(s); expected {known}')
        kwargs: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in d:
                if f.name in ('gravity', 'height'):
                    continue
                raise ValueError(f'{f.name}: missing')
            value = d[f.name]
            if f.name in ('mass', 'buoyancy', 'gravity', 'height'):
                kwargs[f.name] = number(f.name, value)
            else:
                if f.name == 'inertia' and _shape(value) == (3, 3):
                    value = np.ravel(value)  # a nested 3x3 list is row-major too
                lengths = {'inertia': (3, 9), 'r_g': (3,), 'r_b': (3,)}.get(f.name, (6,))
                kwargs[f.name] = tuple(vector(f.name, value, lengths, finite=True).tolist())
        params = cls(**kwargs)
        params.validate()
        return params


@dataclass(frozen=True, eq=False)
class RigidBodyState:
    """Vehicle state: eta = (p, q) and nu. Arrays are read-only copies."""

    p: Vector  # (3,) position of the CO in world ENU [m]
    q: Vector  # (4,) attitude [x, y, z, w], body -> world
    nu: Vector  # (6,) body velocities [u, v, w, p, q, r] FLU [m/s, rad/s]

    def __post_init__(self) -> None:
        for name, n in (('p', 3), ('q', 4), ('nu', 6)):
            a = np.array(vector(name, getattr(self, name), n))
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @classmethod
    def at_rest(cls, p: ArrayLike = (0.0, 0.0, 0.0), yaw: float = 0.0) -> RigidBodyState:
        """Level vehicle at ``p`` [m] heading ``yaw`` [rad] (ENU: 0 = east, CCW), nu = 0."""
        return cls(p=np.asarray(p, dtype=float), q=quat_from_euler(0.0, 0.0, yaw),
                   nu=np.zeros(6))


class RigidBodyModel:
    """M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau + tau_ext, with RK4 integration."""

    def __init__(self, params: RigidBodyParams):
        params.validate()
        self.params = params
        m = float(params.mass)
        r_g = np.asarray(params.r_g, dtype=float)
        r_b = np.asarray(params.r_b, dtype=float)
        S_g = skew(r_g)
        # M_RB = [[m I, -m S(r_g)], [m S(r_g), I_o]] about the CO (Fossen 2021, ch. 3).
        M_RB = np.zeros((6, 6))
        M_RB[:3, :3] = m * np.eye(3)
        M_RB[:3, 3:] = -m * S_g
        M_RB[3:, :3] = m * S_g
        I_o = params.inertia_matrix()
        M_RB[3:, 3:] = 0.5 * (I_o + I_o.T)
        M_A = np.diag(np.asarray(params.added_mass, dtype=float))
        M = M_RB + M_A
        M_inv = np.linalg.solve(M, np.eye(6))
        M_inv = 0.5 * (M_inv + M_inv.T)
        for a in (M_RB, M_A, M, M_inv):
            a.flags.writeable = False
        self._M_RB, self._M_A, self._M, self._M_inv = M_RB, M_A, M, M_inv
        self._d_lin = np.asarray(params.d_lin, dtype=float)
        self._d_quad = np.asarray(params.d_quad, dtype=float)
        self._W = m * float(params.gravity)
        self._B = float(params.buoyancy)
        self._r_g = r_g
        self._r_b = r_b
        # Fast-path constants as Python floats.
        self._M_rows = tuple(tuple(row) for row in M.tolist())
        self._M_inv_rows = tuple(tuple(row) for row in M_inv.tolist())
        self._M_RB_rows = tuple(tuple(row) for row in M_RB.tolist())
        self._ma = tuple(float(a) for a in params.added_mass)
        self._dl = tuple(self._d_lin.tolist())
        self._dq = tuple(self._d_quad.tolist())
        self._net_up = self._B - self._W  # net vertical force B - W [N]
        self._h = tuple((self._B * r_b - self._W * r_g).tolist())  # B r_b - W r_g [N m]
        self._height = float(params.height)  # 0: deep water, no free surface
        self._rb = tuple(r_b.tolist())
        self._Wrg = tuple((self._W * r_g).tolist())

    def submerged(self, z_b: float) -> float:
        """Submerged fraction of the displaced volume with the CB at world height ``z_b`` [m]."""
        if self._height <= 0.0:
            return 1.0
        s = 0.5 - z_b / self._height
        return 0.0 if s < 0.0 else 1.0 if s > 1.0 else s

    def _restoring_terms(self, pz: float, r20: float, r21: float,
                         r22: float) -> tuple[float, float, float, float]:
        """(s B - W, s B r_b - W r_g) at CO height ``pz``, k = (r20, r21, r22) = R^T e_z."""
        if self._height <= 0.0:
            hx, hy, hz = self._h
            return self._net_up, hx, hy, hz
        bx, by, bz = self._rb
        bs = self._B * self.submerged(pz + r20 * bx + r21 * by + r22 * bz)
        gx, gy, gz = self._Wrg
        return bs - self._W, bs * bx - gx, bs * by - gy, bs * bz - gz

    @property
    def M(self) -> Matrix:
        """System inertia matrix M = M_RB + M_A (6x6, read-only)."""
        return self._M

    @property
    def M_RB(self) -> Matrix:
        """Rigid-body inertia matrix about the CO (6x6, read-only)."""
        return self._M_RB

    @property
    def M_A(self) -> Matrix:
        """Added-mass matrix, diagonal (6x6, read-only)."""
        return self._M_A

    @property
    def M_inv(self) -> Matrix:
        """Cached inverse of M (6x6, read-only)."""
        return self._M_inv

    def coriolis(self, nu: ArrayLike) -> Matrix:
        """C(nu) = C_RB(nu) + C_A(nu) (6x6) at body velocity ``nu`` [m/s, rad/s]."""
        # C_RB from M_RB (Thm 3.2), C_A from M_A in the same form. C is linear in its inertia
        # matrix, so the fast path in step() uses C(M) = C(M_RB) + C(M_A) directly.
        return coriolis_matrix(self._M_RB, nu) + coriolis_matrix(self._M_A, nu)

    def damping(self, nu: ArrayLike) -> Matrix:
        """D(nu) = D_lin + diag(d_quad |nu|) (6x6) [N s/m, N m s/rad]."""
        nu = np.asarray(nu, dtype=float)
        return np.diag(self._d_lin + self._d_quad * np.abs(nu))

    def restoring(self, q: ArrayLike, p: ArrayLike | None = None) -> Vector:
        """Restoring vector g(eta) (6,) [N, N m] at attitude ``q`` (Fossen 2021, ch. 4).

        f_g = R^T [0, 0, -W], f_b = R^T [0, 0, s B] (ENU: z up),
        g = -[f_g + f_b; r_g x f_g + r_b x f_b]. It sits on the left-hand side, so the force
        acting on the vehicle is -g. ``s``: the submerged fraction with the CO at ``p`` (world
        [m]; None: fully submerged), 1 in deep water (``height`` 0).
        """
        R = quat_to_rotmat(quat_normalize(q))
        s = 1.0 if p is None else self.submerged(
            float(vector('p', p, 3)[2] + (R @ self._r_b)[2]))
        f_g = R.T @ np.array([0.0, 0.0, -self._W])
        f_b = R.T @ np.array([0.0, 0.0, s * self._B])
        return -np.concatenate(
            (f_g + f_b, np.cross(self._r_g, f_g) + np.cross(self._r_b, f_b)))

    def nu_dot(self, q: ArrayLike, nu: ArrayLike, tau: ArrayLike,
               tau_ext: ArrayLike | None = None,
               current: ArrayLike | None = None, p: ArrayLike | None = None) -> Vector:
        """Body acceleration nu_dot (6,) [m/s^2, rad/s^2] at attitude ``q`` and velocity ``nu``.

        nu_dot = M^-1 (tau + tau_ext - C(nu) nu - D(nu) nu - g(eta)); ``tau`` [N, N m]. With a
        ``current`` v_c (3,) [m/s] in the world frame, the relative-velocity form of the module
        docstring. ``p``: the CO's position (world [m]) for the free surface; None: fully
        submerged.
        """
        qv = vector('q', q, 4)
        nuv = vector('nu', nu, 6)
        tau_l = self._total_tau(tau, tau_ext)
        vc = self._current(current)
        pz = -math.inf if p is None else float(vector('p', p, 3)[2])
        x = [0.0, 0.0, pz, *qv.tolist(), *nuv.tolist()]
        return np.array(self._f(x, tau_l, vc)[7:])

    def step(self, state: RigidBodyState, tau: ArrayLike, dt: float,
             tau_ext: ArrayLike | None = None,
             current: ArrayLike | None = None) -> RigidBodyState:
        """Advance ``state`` by ``dt`` [s] with ``tau`` (and ``tau_ext``) [N, N m] held constant.

        Classic RK4 on (p, q, nu) with p_dot = R(q) nu_1, q_dot = 1/2 q (x) [omega, 0]; q is
        renormalized after the step. ``current``: the water's velocity (3,) [m/s] in the world
        frame (ENU), constant; None or zero is still water. ``nu`` stays the velocity over
        ground.
        """
        if not isinstance(dt, (int, float, np.floating, np.integer)) or isinstance(dt, bool):
            raise ValueError(f'dt: expected a number of seconds, got {dt!r}')
        h = float(dt)
        if not (h > 0.0 and math.isfinite(h)):
            raise ValueError(f'dt: must be finite and > 0 s, got {dt!r}')
        tau_l = self._total_tau(tau, tau_ext)
        vc = self._current(current)
        x0 = state.p.tolist() + state.q.tolist() + state.nu.tolist()
        f = self._f
        h2 = 0.5 * h
        k1 = f(x0, tau_l, vc)
        k2 = f([x + h2 * k for x, k in zip(x0, k1)], tau_l, vc)
        k3 = f([x + h2 * k for x, k in zip(x0, k2)], tau_l, vc)
        k4 = f([x + h * k for x, k in zip(x0, k3)], tau_l, vc)
        h6 = h / 6.0
        x1 = [x + h6 * (a + 2.0 * (b + c) + d) for x, a, b, c, d in zip(x0, k1, k2, k3, k4)]
        return RigidBodyState(p=np.array(x1[0:3]), q=quat_normalize(x1[3:7]),
                              nu=np.array(x1[7:13]))

    def specific_force(self, state: RigidBodyState, nu_dot: ArrayLike) -> Vector:
        """Specific force (3,) [m/s^2] an accelerometer at the CO measures, in body FLU.

        f = v_dot + omega x v - R^T [0, 0, -g]; a level vehicle at rest reads [0, 0, +g]
        (REP-145).
        """
        nu_dot = np.asarray(nu_dot, dtype=float)
        R = quat_to_rotmat(quat_normalize(state.q))
        v, omega = state.nu[:3], state.nu[3:]
        gravity: Vector = np.array([0.0, 0.0, -float(self.params.gravity)])
        # skew(omega) @ v is omega x v; np.cross costs several times more on 3-vectors.
        return nu_dot[:3] + skew(omega) @ v - R.T @ gravity

    def kinetic_energy(self, nu: ArrayLike) -> float:
        """T = 1/2 nu^T M nu [J], rigid body plus added mass."""
        nu = np.asarray(nu, dtype=float)
        return 0.5 * float(nu @ self._M @ nu)

    # -- fast path ---------------------------------------------------------------------------

    def _total_tau(self, tau: ArrayLike, tau_ext: ArrayLike | None) -> list[float]:
        t = vector('tau', tau, 6)
        if tau_ext is not None:
            t = t + vector('tau_ext', tau_ext, 6)
        out: list[float] = t.tolist()
        if not math.isfinite(math.fsum(out)):
            raise ValueError(f'tau: values must be finite, got {out}')
        return out

    @staticmethod
    def _current(current: ArrayLike | None) -> tuple[float, float, float] | None:
        """Return the current as 3 floats, or None for still water (None or all zero)."""
        if current is None:
            return None
        vc = vector('current', current, 3, finite=True).tolist()
        return None if not any(vc) else (vc[0], vc[1], vc[2])

    def _f(self, x: list[float], tau: list[float],
           vc: tuple[float, float, float] | None = None) -> list[float]:
        """Time derivative of x = [p(3), q(4), nu(6)] as a list of 13 floats."""
        _, _, pz, qx, qy, qz, qw, u, v, w, wx, wy, wz = x
        # R(q) of a possibly non-unit q: the RK4 stage quaternions drift off the unit sphere by
        # O(dt^2); dividing by |q|^2 keeps every stage's R a rotation.
        s = 2.0 / (qx * qx + qy * qy + qz * qz + qw * qw)
        xx, yy, zz = s * qx * qx, s * qy * qy, s * qz * qz
        xy, xz, yz = s * qx * qy, s * qx * qz, s * qy * qz
        xw, yw, zw = s * qx * qw, s * qy * qw, s * qz * qw
        r20, r21, r22 = xz - yw, yz + xw, 1.0 - xx - yy  # R^T e_z: world up in body
        # p_dot = R(q) nu_1
        pdx = (1.0 - yy - zz) * u + (xy - zw) * v + (xz + yw) * w
        pdy = (xy + zw) * u + (1.0 - xx - zz) * v + (yz - xw) * w
        pdz = r20 * u + r21 * v + r22 * w
        # q_dot = 1/2 q (x) [omega, 0]
        qdx = 0.5 * (qw * wx + qy * wz - qz * wy)
        qdy = 0.5 * (qw * wy - qx * wz + qz * wx)
        qdz = 0.5 * (qw * wz + qx * wy - qy * wx)
        qdw = -0.5 * (qx * wx + qy * wy + qz * wz)
        dl, dq = self._dl, self._dq
        if vc is None:
            n_up, hx, hy, hz = self._restoring_terms(pz, r20, r21, r22)
            # C(nu) nu = [omega x a; v x a + omega x b], [a; b] = M nu (Fossen 2021, Thm 3.2)
            a0, a1, a2, b0, b1, b2 = [m0 * u + m1 * v + m2 * w + m3 * wx + m4 * wy + m5 * wz
                                      for m0, m1, m2, m3, m4, m5 in self._M_rows]
            # rhs = tau - C nu - D nu - g, -g = [(B - W) k; (B r_b - W r_g) x k], k = R^T e_z
            rhs = (
                tau[0] - (wy * a2 - wz * a1) - (dl[0] + dq[0] * abs(u)) * u + n_up * r20,
                tau[1] - (wz * a0 - wx * a2) - (dl[1] + dq[1] * abs(v)) * v + n_up * r21,
                tau[2] - (wx * a1 - wy * a0) - (dl[2] + dq[2] * abs(w)) * w + n_up * r22,
                tau[3] - (v * a2 - w * a1 + wy * b2 - wz * b1)
                - (dl[3] + dq[3] * abs(wx)) * wx + (hy * r22 - hz * r21),
                tau[4] - (w * a0 - u * a2 + wz * b0 - wx * b2)
                - (dl[4] + dq[4] * abs(wy)) * wy + (hz * r20 - hx * r22),
                tau[5] - (u * a1 - v * a0 + wx * b1 - wy * b0)
                - (dl[5] + dq[5] * abs(wz)) * wz + (hx * r21 - hy * r20),
            )
        else:
            rhs = self._rhs_in_current(x, tau, vc, (xx, yy, zz, xy, xz, yz, xw, yw, zw))
        r0, r1, r2, r3, r4, r5 = rhs
        out = [pdx, pdy, pdz, qdx, qdy, qdz, qdw]
        out.extend([m0 * r0 + m1 * r1 + m2 * r2 + m3 * r3 + m4 * r4 + m5 * r5
                    for m0, m1, m2, m3, m4, m5 in self._M_inv_rows])
        return out

    def _rhs_in_current(self, x: list[float], tau: list[float],
                        vc: tuple[float, float, float],
                        r: tuple[float, ...]) -> _Six:
        """Return tau - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r - g + M_A nu_c_dot (6 floats).

        ``r`` holds the products of ``_f`` that make up R(q). The rigid body moves with nu,
        the water's reaction (added mass, damping) with nu_r (Fossen 2021, eq. 10.1).
        """
        _, _, _, _, _, _, _, u, v, w, wx, wy, wz = x
        xx, yy, zz, xy, xz, yz, xw, yw, zw = r
        ex, ey, ez = vc
        # nu_c = R^T v_c (the current in the body frame); R's rows as in _f
        uc = (1.0 - yy - zz) * ex + (xy + zw) * ey + (xz - yw) * ez
        vcb = (xy - zw) * ex + (1.0 - xx - zz) * ey + (yz + xw) * ez
        wc = (xz + yw) * ex + (yz - xw) * ey + (1.0 - xx - yy) * ez
        ur, vr, wr = u - uc, v - vcb, w - wc
        r20, r21, r22 = xz - yw, yz + xw, 1.0 - xx - yy
        # C_RB(nu) nu = [omega x a; v x a + omega x b], [a; b] = M_RB nu
        a0, a1, a2, b0, b1, b2 = [m0 * u + m1 * v + m2 * w + m3 * wx + m4 * wy + m5 * wz
                                  for m0, m1, m2, m3, m4, m5 in self._M_RB_rows]
        # C_A(nu_r) nu_r = [omega x a'; v_r x a' + omega x b'], [a'; b'] = M_A nu_r (diagonal)
        ma = self._ma
        c0, c1, c2 = ma[0] * ur, ma[1] * vr, ma[2] * wr
        d0, d1, d2 = ma[3] * wx, ma[4] * wy, ma[5] * wz
        # M_A nu_c_dot, nu_c_dot = [-omega x nu_c; 0]
        n0 = -ma[0] * (wy * wc - wz * vcb)
        n1 = -ma[1] * (wz * uc - wx * wc)
        n2 = -ma[2] * (wx * vcb - wy * uc)
        dl, dq = self._dl, self._dq
        n_up, hx, hy, hz = self._restoring_terms(x[2], r20, r21, r22)
        return (
            tau[0] - (wy * a2 - wz * a1) - (wy * c2 - wz * c1)
            - (dl[0] + dq[0] * abs(ur)) * ur + n_up * r20 + n0,
            tau[1] - (wz * a0 - wx * a2) - (wz * c0 - wx * c2)
            - (dl[1] + dq[1] * abs(vr)) * vr + n_up * r21 + n1,
            tau[2] - (wx * a1 - wy * a0) - (wx * c1 - wy * c0)
            - (dl[2] + dq[2] * abs(wr)) * wr + n_up * r22 + n2,
            tau[3] - (v * a2 - w * a1 + wy * b2 - wz * b1)
            - (vr * c2 - wr * c1 + wy * d2 - wz * d1)
            - (dl[3] + dq[3] * abs(wx)) * wx + (hy * r22 - hz * r21),
            tau[4] - (w * a0 - u * a2 + wz * b0 - wx * b2)
            - (wr * c0 - ur * c2 + wz * d0 - wx * d2)
            - (dl[4] + dq[4] * abs(wy)) * wy + (hz * r20 - hx * r22),
            tau[5] - (u * a1 - v * a0 + wx * b1 - wy * b0)
            - (ur * c1 - vr * c0 + wx * d1 - wy * d0)
            - (dl[5] + dq[5] * abs(wz)) * wz + (hx * r21 - hy * r20),
        )
