"""The vessel parameters of a 3-DOF surface vessel, declared alike by every node that needs them.

The observer, the DP controller and the simulator each declare ``vessel.inertia``,
``vessel.linear_damping`` and ``vessel.nonlinear_damping`` (diagonals [surge, sway, yaw]);
a profile gives them once under its top-level ``parameters: vessel:``. They are required
(``ParamSpec(required=True)``): a node started without them refuses to start, naming the
parameter.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from enbarr_core.framework.checks import floats
from enbarr_core.framework.params import ParamSpec, validate_as_parameters
from enbarr_core.models.vessel3dof import Vessel3DofParams

#: The parameter of each vessel model field, for settings that carry the model (M, D, Dn).
VESSEL_PARAMETERS = {'M': 'vessel.inertia', 'D': 'vessel.linear_damping',
                     'Dn': 'vessel.nonlinear_damping'}

VESSEL_SPECS = [
    ParamSpec('vessel.inertia', [0.0, 0.0, 0.0], 'Inertia M = M_RB + M_A, diagonal (surge, '
              'sway, yaw)', 'kg, kg, kg m^2', 0.0, 1e6, required=True),
    ParamSpec('vessel.linear_damping', [0.0, 0.0, 0.0], 'Linear damping D, diagonal (surge, '
              'sway, yaw)', 'N s/m, N s/m, N m s/rad', 0.0, 1e6, required=True),
    ParamSpec('vessel.nonlinear_damping', [0.0, 0.0, 0.0], 'Quadratic damping D_n(nu) = '
              'diag(values) |nu| (surge, sway, yaw)',
              'N s^2/m^2, N s^2/m^2, N m s^2/rad^2', 0.0, 1e6, required=True),
]


def vessel_from_params(v: Mapping[str, Any]) -> Vessel3DofParams:
    """Build the vessel model of the ``vessel.*`` values (ValueError naming the parameter)."""
    params = Vessel3DofParams(
        M=vector3(v, 'vessel.inertia'),
        D=vector3(v, 'vessel.linear_damping'),
        Dn=vector3(v, 'vessel.nonlinear_damping'))
    validate_as_parameters(params, VESSEL_PARAMETERS)
    return params


def vector3(v: Mapping[str, Any], name: str) -> tuple[float, float, float]:
    """Return ``v[name]`` as 3 floats (surge, sway, yaw); ValueError naming ``name``."""
    return floats(name, v[name], 3)
