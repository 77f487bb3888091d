"""The CS Saucer written out once more for the algorithm tests, independently of
``enbarr_core.models.vessel3dof``: manual section 1.4, RK4 with tau and a world bias
held over a step. State x = [x, y, psi, u, v, r].
"""

from __future__ import annotations

from functools import cache
import math

import numpy as np

DT = 0.02                                             # 50 Hz [s]
M = np.diag([9.51, 9.51, 0.116])                      # manual eq. 1.2
D = np.diag([1.96, 1.96, 0.168])                      # manual eq. 1.4
M_INV = np.linalg.inv(M)                              # once: rhs runs tens of thousands of times
NOISE = np.array([0.005, 0.005, math.radians(0.5)])   # mocap noise std [m, m, rad]


def rot(psi):
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # manual eq. 1.6


def wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def rhs_matrices(x, tau, b, quadratic=True):
    """The plant's ODE in the manual's matrix form (``rhs`` is this, written out per DOF)."""
    nu = x[3:]
    C = np.array([[0.0, -9.51 * nu[2], 0.0], [9.51 * nu[2], 0.0, 0.0], [0.0, 0.0, 0.0]])
    Dn = 7.095 * np.diag(np.abs(nu)) if quadratic else 0.0 * M     # manual eq. 1.5
    R = rot(x[2])
    nu_dot = M_INV @ (tau + R.T @ b - (C + D + Dn) @ nu)  # eq. 1.3 for C
    return np.concatenate([R @ nu, nu_dot])


_M11, _M22, _M33 = np.diag(M)
_D11, _D22, _D33 = np.diag(D)


def rhs(x, tau, b, quadratic=True):
    """``rhs_matrices`` product by product (a reference runs it tens of thousands of times;
    test_dp_control checks the two agree): eta_dot = R(psi) nu,
    M nu_dot = tau + R^T b - (C(nu) + D + D_n(nu)) nu."""
    psi, u, v, r = x[2], x[3], x[4], x[5]
    c, s = math.cos(psi), math.sin(psi)
    dn = 7.095 if quadratic else 0.0
    fx = tau[0] + c * b[0] + s * b[1] + 9.51 * r * v - (_D11 + dn * abs(u)) * u
    fy = tau[1] - s * b[0] + c * b[1] - 9.51 * r * u - (_D22 + dn * abs(v)) * v
    fn = tau[2] + b[2] - (_D33 + dn * abs(r)) * r
    return np.array([c * u - s * v, s * u + c * v, r, fx / _M11, fy / _M22, fn / _M33])


def step(x, tau, b, dt=DT, quadratic=True):
    """RK4 over dt with tau and b held."""
    k1 = rhs(x, tau, b, quadratic)
    k2 = rhs(x + 0.5 * dt * k1, tau, b, quadratic)
    k3 = rhs(x + 0.5 * dt * k2, tau, b, quadratic)
    k4 = rhs(x + dt * k3, tau, b, quadratic)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


# -- the Saucer's observer and controller settings, from its profile --------------------------

@cache
def _profile(name: str):
    """The loaded profile (loaded once per session: the settings are built from it often)."""
    from enbarr_core.bringup.profile import load_profile
    return load_profile(name, allow_fragment=True)


def profile_settings(node: str, specs, from_params, profile: str = 'saucer_core'):
    """The settings node ``node`` of ``profile`` runs with: the declared defaults of
    ``specs``, the profile's common parameters and the node's own, through ``from_params``.
    """
    p = _profile(profile)
    spec = next(n for n in p.nodes if n.name == node)
    values = {s.name: s.default for s in specs}
    given = {**p.parameters, **spec.parameters}
    values.update({k: v for k, v in given.items() if k in values})
    return from_params(values)


def dp_settings():
    """The CS Saucer's DpControlSettings (gains, limits, model) from saucer_core.yaml."""
    from enbarr_core.control.dp_control_node import DpControlNodeSettings, SPECS
    return profile_settings('dp_control', SPECS, DpControlNodeSettings.from_params).control


def observer_settings():
    """The CS Saucer's gains and model from saucer_core.yaml; the measurement checks are
    ObserverSettings' own defaults (the algorithm tests' choice, not the node's)."""
    import dataclasses
    from enbarr_core.estimation.dp_observer import ObserverSettings
    from enbarr_core.estimation.dp_observer_node import DpObserverNodeSettings, SPECS
    s = profile_settings('observer', SPECS, DpObserverNodeSettings.from_params).observer
    return ObserverSettings(**{f.name: getattr(s, f.name) for f in dataclasses.fields(s)
                               if f.name in ('K1', 'K2', 'K3', 'T_b', 'M', 'D', 'Dn')})


def vessel_params():
    """The CS Saucer's Vessel3DofParams from saucer_core.yaml."""
    from enbarr_core.simulation.vessel3dof_simulator_node import (
        SPECS, Vessel3DofSimulatorSettings)
    from enbarr_core.bringup.profile import load_profile
    p = load_profile('saucer_core', allow_fragment=True)
    values = {s.name: s.default for s in SPECS}
    values.update({k: v for k, v in p.parameters.items() if k in values})
    return Vessel3DofSimulatorSettings.from_params(values).vessel
