"""The ROV's and the Saucer's actuator layouts read straight from their profiles' YAML.

No rclpy: the pure tiers use these (``support.rov`` and ``support.saucer`` build ROS
parameters and import rclpy).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from enbarr_core.allocation.fixed import Thruster
from enbarr_core.models.vessel3dof import AzimuthSpec

PARAMS = Path(__file__).resolve().parents[2] / 'params'


def common_parameters(profile: str) -> dict[str, Any]:
    """The ``parameters`` section of ``params/<profile>``, as written (nested)."""
    with open(PARAMS / profile, encoding='utf-8') as f:
        return yaml.safe_load(f)['parameters']


ROV = common_parameters('enbarr_sim.yaml')
SAUCER = common_parameters('saucer_core.yaml')


def rov_thrusters() -> list[Thruster]:
    """The simulated ROV's eight thrusters, in ``thruster_names`` order."""
    t = ROV['thrusters']
    return [Thruster(n, t[n]['position'], t[n]['direction'], t[n]['max_forward'],
                     t[n]['max_reverse']) for n in ROV['thruster_names']]


def saucer_specs() -> list[AzimuthSpec]:
    """The CS Saucer's three azimuths, in ``azimuth_names`` order."""
    a = SAUCER['azimuths']
    return [AzimuthSpec(n, tuple(a[n]['position']), a[n]['max_forward'], a[n]['max_reverse'],
                        a[n]['angle_min'], a[n]['angle_max'], a[n]['time_constant'],
                        a[n]['max_angle_rate']) for n in SAUCER['azimuth_names']]
