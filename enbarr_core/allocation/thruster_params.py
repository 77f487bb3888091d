"""Thruster layout parameters, shared by the converter, the simulator and thruster plugins.

A profile gives the layout once in its common ``parameters`` (every node that needs it
declares it)::

    thruster_names: [front_right, front_left, ...]
    thrusters:
      front_right: {position: [0.2, -0.15, 0.0], direction: [0.707, 0.707, 0.0],
                    max_forward: 40.0, max_reverse: 30.0}

Positions are in ``base_link`` (FLU) [m]; a direction is the thrust direction of a positive
command (normalized here); limits are the thrust [N] at command +1 and -1. The layout is read
only: geometry is fixed while the vehicle runs.
"""

from __future__ import annotations

from rclpy.node import Node

from enbarr_core.allocation.fixed import Thruster
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.params import ParamSpec, SettingsBinding


def declare_thrusters(node: Node) -> tuple[Thruster, ...]:
    """Declare ``thruster_names`` and each thruster's parameters; return the layout."""
    names_binding = SettingsBinding(node, [ParamSpec(
        'thruster_names', [''], 'Thruster names, in the order of every per-thruster array',
        read_only=True, element=str)], lambda v: v['thruster_names'], lambda _: None)
    names = list(names_binding.settings)
    if names == [''] or not names:
        raise ConfigurationError(f'node {node.get_name()!r}: parameter thruster_names is not '
                                 'set; the profile must list the thrusters')
    if len(set(names)) != len(names):
        raise ConfigurationError(f'node {node.get_name()!r}: thruster_names has duplicates: '
                                 f'{names}')
    specs: list[ParamSpec] = []
    for n in names:
        p = f'thrusters.{n}.'
        specs += [
            ParamSpec(p + 'position', [0.0, 0.0, 0.0], f'Position of thruster {n} in base_link',
                      'm', -100.0, 100.0, read_only=True),
            ParamSpec(p + 'direction', [1.0, 0.0, 0.0],
                      f'Thrust direction of thruster {n} for a positive command (base_link; '
                      'normalized on use)', '', -1e3, 1e3, read_only=True),
            ParamSpec(p + 'max_forward', 1.0, f'Thrust of {n} at command +1', 'N', 1e-6, 1e6,
                      read_only=True),
            ParamSpec(p + 'max_reverse', 1.0, f'Thrust magnitude of {n} at command -1', 'N',
                      1e-6, 1e6, read_only=True),
        ]

    def build(v: dict) -> tuple[Thruster, ...]:
        out = []
        for n in names:
            p = f'thrusters.{n}.'
            try:
                out.append(Thruster(n, tuple(v[p + 'position']), tuple(v[p + 'direction']),
                                    v[p + 'max_forward'], v[p + 'max_reverse']))
            except (ValueError, ConfigurationError) as err:  # Thruster names itself
                raise ValueError(str(err)) from err
        return tuple(out)

    return SettingsBinding(node, specs, build, lambda _: None).settings
