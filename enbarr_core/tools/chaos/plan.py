"""The profile a chaos run is built on: the given one split into process groups.

The core nodes go to group ``control``, the rest (simulator, sensor and actuator plugins,
operator stand-ins) stay in ``main``, and the operator stand-ins are given a steady command
(an ROV drives ahead, a surface vessel holds its pose in automatic) so that the actuators are
busy when a fault comes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from enbarr_core.framework.errors import EnbarrError

#: Plugins that make the control group: what must keep working, and what injection reaches.
CONTROL_PLUGINS = frozenset({
    'command_receiver', 'attitude_filter', 'velocity_control', 'thruster_converter',
    'dp_observer', 'guidance', 'dp_control', 'azimuth_allocation', 'pwm_mapper'})
CONTROL_GROUP = 'control'
#: Core nodes that are neither the control chain nor a plugin: they stay with the plugins.
SUPPORT_PLUGINS = frozenset({'frame_publisher'})
#: The operator stand-ins' steady command during a chaos run (a busy vehicle).
STEADY_SCRIPTS = {
    'scripted_commands': ['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.0', '0.5 io gpio_12 false'],
    # Then the automatic button (hold the pose): the observer's estimate is in the loop.
    'scripted_joy': ['0.0 sticks 0.0 0.0 0.0'],
}
JOY_PRESS_EVERY_S = 3
JOY_SCRIPT_S = 1200


@dataclass(frozen=True)
class Plan:
    """What the split profile holds: its file, control nodes and command sources."""

    path: Path
    control_nodes: frozenset[str]
    joy_buttons: dict[str, int] = field(default_factory=dict)


def _joy_layout(params: dict[str, Any]) -> tuple[dict[str, int], tuple[str, ...]]:
    """Return the profile's joystick indices and, with a named ``joy.layout``, its buttons.

    Indices as ``axis_surge``, ``button_automatic`` ...; empty without a joystick.
    """
    from enbarr_core.control.joy_layouts import get_layout, INDEX_PARAMETERS, mapping_from_params
    if not any(k.startswith('joy.') for k in params):
        return {}, ()
    try:
        mapping, _ = mapping_from_params(params)
    except ValueError:
        return {}, ()
    layout = params.get('joy.layout')
    return ({k: getattr(mapping, k) for k in INDEX_PARAMETERS},
            get_layout(layout).buttons if layout else ())


def write_split_profile(ref: str, out: Path) -> Plan:
    """Write ``out/chaos.yaml``: ``ref`` with its core nodes in group ``control``."""
    from enbarr_core.bringup import profile as profiles
    prof = profiles.load_profile(ref)
    control = [n.name for n in prof.nodes if n.plugin in CONTROL_PLUGINS]
    plugins = [n for n in prof.nodes if n.plugin not in CONTROL_PLUGINS | SUPPORT_PLUGINS]
    if not control or not plugins:
        core = ', '.join(sorted(CONTROL_PLUGINS))
        raise EnbarrError(f'{prof.path}: chaos needs core nodes ({core}) and plugins beside '
                          'them to split the profile')
    nodes: dict[str, Any] = {n: {'group': CONTROL_GROUP} for n in control}
    buttons, names = _joy_layout(prof.parameters)
    for n in prof.nodes:
        if n.plugin in STEADY_SCRIPTS:
            script = list(STEADY_SCRIPTS[n.plugin])
            names = names or n.parameters.get('joy.buttons', ())
            auto = buttons.get('button_automatic')
            if n.plugin == 'scripted_joy' and auto is not None and auto < len(names):
                # Pressed again every few seconds: a control group restarted after a fault
                # starts in manual, and the run goes on in automatic.
                script += [f'{t:.1f} press {names[auto]}'
                           for t in range(1, JOY_SCRIPT_S, JOY_PRESS_EVERY_S)]
            nodes[n.name] = {'parameters': {'script': script}}
    doc = {'profile': f'chaos_{prof.name}', 'description': f'{prof.name} split for chaos',
           'include': [str(Path(prof.path).resolve())], 'nodes': nodes,
           'groups': {CONTROL_GROUP: {'restart_limit': 50, 'restart_delay': 0.2}}}
    path = out / 'chaos.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return Plan(path, frozenset(control), buttons)
