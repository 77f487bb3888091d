"""The vehicle parameters of a 6-DOF vehicle (the ROV), declared alike by every node needing them.

The velocity control loop (its model feed-forward) and the ROV simulator both declare
``vehicle.mass``, ``vehicle.inertia``, ``vehicle.added_mass``, ``vehicle.d_lin`` and
``vehicle.d_quad`` (``VEHICLE_SPECS``); the simulator also the restoring forces
``vehicle.r_g``, ``vehicle.r_b``, ``vehicle.buoyancy`` and, for the free surface,
``vehicle.height`` (``RESTORING_SPECS``). They are vessel data: a profile gives them once
(the common ``parameters: vehicle:`` block reaches both nodes) and all but ``vehicle.height``
(0: deep water) are required (``ParamSpec(required=True)``): a node started without them
refuses to start, naming the parameter. Vectors are [surge, sway, heave, roll, pitch, yaw], FLU.
"""

from __future__ import annotations

from enbarr_core.framework.params import ParamSpec

_SIX = 'surge, sway, heave, roll, pitch, yaw'

VEHICLE_SPECS = [
    ParamSpec('vehicle.mass', 0.0, 'Rigid-body mass m', 'kg', 0.01, 1e5, required=True),
    ParamSpec('vehicle.inertia', [0.0], 'Inertia about the CO: 3 diagonal or 9 row-major values '
              "(the velocity loop's feed-forward uses the diagonal)", 'kg m^2', -1e5, 1e5,
              required=True),
    ParamSpec('vehicle.added_mass', [0.0], f'Diagonal of the added mass M_A ({_SIX})',
              'kg, kg m^2', 0.0, 1e5, required=True),
    ParamSpec('vehicle.d_lin', [0.0], f'Linear damping, diagonal ({_SIX})',
              'N s/m, N m s/rad', 0.0, 1e5, required=True),
    ParamSpec('vehicle.d_quad', [0.0], f'Quadratic damping, diagonal ({_SIX})',
              'N s^2/m^2, N m s^2/rad^2', 0.0, 1e5, required=True),
]

RESTORING_SPECS = [
    ParamSpec('vehicle.r_g', [0.0], 'Centre of gravity in base_link', 'm', -100.0, 100.0,
              required=True),
    ParamSpec('vehicle.r_b', [0.0], 'Centre of buoyancy in base_link', 'm', -100.0, 100.0,
              required=True),
    ParamSpec('vehicle.buoyancy', 0.0, 'Buoyancy B = rho g V', 'N', 0.0, 1e6, required=True),
    ParamSpec('vehicle.height', 0.0, 'Height of the displaced volume, centred on the CB: the '
              'buoyancy falls as it emerges at the free surface (0: deep water, none)', 'm',
              0.0, 100.0),
]
