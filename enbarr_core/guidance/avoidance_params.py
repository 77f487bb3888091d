"""The collision avoidance's parameters that two nodes declare alike.

``/guidance`` (the guidance-level barrier functions and the blind hold) and ``/dp_control``
(the force-level filter) each read these from the profile's common ``parameters:``, so that
they agree on where the barrier functions act and on the clearance they keep. One declaration
here keeps their names, ranges and descriptions from drifting apart.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from enbarr_core.framework.params import ParamSpec

#: Where the barrier functions act (``avoidance.level``): on the desired position in the
#: guidance node, or on the DP controller's force.
AVOIDANCE_LEVELS = ('guidance', 'force')

ENABLED = ParamSpec('avoidance.enabled', False, 'Collision avoidance on, in automatic and '
                    'guidance modes: the barrier functions filter the reference (level '
                    "guidance) or the DP controller's force (level force)")
LEVEL = ParamSpec('avoidance.level', 'guidance', 'Where the barrier functions act: guidance '
                  '(the desired position, in the guidance node) or force (the force, in the '
                  'DP control node; the guidance then keeps only its blind hold)',
                  read_only=True)
SAFETY_RADIUS = ParamSpec('avoidance.safety_radius', 0.2, 'Clearance that must hold between '
                          'the hull and every obstacle', 'm', 0.0, 10.0)
VESSEL_RADIUS = ParamSpec('avoidance.vessel_radius', 0.0, 'Hull radius about the CO '
                          '(required > 0 where the barrier functions act)', 'm', 0.0, 50.0)


def level_of(values: Mapping[str, Any]) -> str:
    """Return ``avoidance.level`` of the declared values (ValueError naming it when unknown)."""
    level = values['avoidance.level']
    if level not in AVOIDANCE_LEVELS:
        raise ValueError(f'avoidance.level: expected one of {", ".join(AVOIDANCE_LEVELS)}, '
                         f'got {level!r}')
    return str(level)
