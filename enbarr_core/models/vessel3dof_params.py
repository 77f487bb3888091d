"""The vessel parameters of a 3-DOF surface vessel, declared alike by every node that needs them.

The observer, the DP controller and the simulator each declare ``vessel.inertia``,
``vessel.linear_damping`` and ``vessel.nonlinear_damping`` (diagonals [surge, sway, yaw]);
a profile gives them once under its top-level ``parameters: vessel:``. They have no generic
default: a node started without them refuses to start, naming the parameter.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from enbarr_core.framework.params import ParamSpec
from enbarr_core.models.vessel3dof import Vessel3DofParams

_UNSET = [0.0]  # what a node holds when the profile gave nothing: refused by from_params
_PARAMETER = {'M': 'inertia', 'D': 'linear_damping', 'Dn': 'nonlinear_damping'}

VESSEL_SPECS = [
    ParamSpec('vessel.inertia', list(_UNSET), 'Inertia M = M_RB + M_A, diagonal (surge, sway, '
              'yaw); required', 'kg, kg, kg m^2', 0.0, 1e6),
    ParamSpec('vessel.linear_damping', list(_UNSET), 'Linear damping D, diagonal (surge, sway, '
              'yaw); required', 'N s/m, N s/m, N m s/rad', 0.0, 1e6),
    ParamSpec('vessel.nonlinear_damping', list(_UNSET), 'Quadratic damping D_n(nu) = '
              'diag(values) |nu| (surge, sway, yaw); required',
              'N s^2/m^2, N s^2/m^2, N m s^2/rad^2', 0.0, 1e6),
]


def vessel_from_params(v: Mapping[str, Any]) -> Vessel3DofParams:
    """Build the vessel model of the ``vessel.*`` values (ValueError naming the parameter)."""
    params = Vessel3DofParams(
        M=required_vector(v, 'vessel.inertia'),  # type: ignore[arg-type]
        D=required_vector(v, 'vessel.linear_damping'),  # type: ignore[arg-type]
        Dn=required_vector(v, 'vessel.nonlinear_damping'))  # type: ignore[arg-type]
    try:
        params.validate()
    except ValueError as err:
        field = str(err).split(':')[0]
        raise ValueError(f'vessel.{_PARAMETER[field]}: {err}') from err
    return params


def required_vector(v: Mapping[str, Any], name: str, n: int = 3) -> tuple[float, ...]:
    """Return ``v[name]`` as ``n`` floats; refuse the unset default, saying what is missing."""
    value = list(v[name])
    if value == _UNSET:
        raise ValueError(f'{name} is not set; the profile must give it ({n} values)')
    if len(value) != n:
        raise ValueError(f'{name}: expected {n} values (surge, sway, yaw), got {len(value)}')
    return tuple(float(x) for x in value)
