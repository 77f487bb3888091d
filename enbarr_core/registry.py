"""Find node classes by name: a built-in table extended by Python entry points.

A third-party package adds a plugin without touching this repository by declaring, in its
own ``setup.py``::

    entry_points={'enbarr.nodes': ['my_imu = my_package.my_imu:MyImuNode']}

after which a profile can say ``plugin: my_imu``. A name given twice is an error (the entry
point cannot silently replace a built-in). An unknown name is an error that lists the known
ones.
"""

from __future__ import annotations

from dataclasses import dataclass
import difflib
import importlib
from importlib import metadata
from typing import Any

from .errors import RegistryError

ENTRY_POINT_GROUP = 'enbarr.nodes'

#: name -> 'module:Class' of the nodes this package ships.
BUILTIN: dict[str, str] = {
    # core
    'attitude_filter': 'enbarr_core.nodes.attitude_filter:AttitudeFilterNode',
    'command_receiver': 'enbarr_core.nodes.command_receiver:CommandReceiverNode',
    'velocity_control': 'enbarr_core.nodes.velocity_control:VelocityControlNode',
    'thruster_converter': 'enbarr_core.nodes.thruster_converter:ThrusterConverterNode',
    'rov_simulator': 'enbarr_core.nodes.rov_simulator:RovSimulatorNode',
    'scripted_commands': 'enbarr_core.nodes.scripted_commands:ScriptedCommandsNode',
    'recorder': 'enbarr_core.nodes.recorder:RecorderNode',
    'saucer_simulator': 'enbarr_core.nodes.saucer_simulator:SaucerSimulatorNode',
    'dp_observer': 'enbarr_core.nodes.dp_observer:DpObserverNode',
    'dp_control': 'enbarr_core.nodes.dp_control:DpControlNode',
    'azimuth_allocation': 'enbarr_core.nodes.azimuth_allocation:AzimuthAllocationNode',
    'pwm_mapper': 'enbarr_core.nodes.pwm_mapper:PwmMapperNode',
    # plugins
    'sim_imu': 'enbarr_plugins.sensors.sim_imu:SimImuNode',
    'sim_thrusters': 'enbarr_plugins.motors.sim_thrusters:SimThrustersNode',
    'sim_stepper': 'enbarr_plugins.io.sim_stepper:SimStepperNode',
    'sim_gpio': 'enbarr_plugins.io.sim_gpio:SimGpioNode',
    'sim_mocap': 'enbarr_plugins.mocap.sim_mocap:SimMocapNode',
    'sim_arduino': 'enbarr_plugins.motors.sim_arduino:SimArduinoNode',
    'scripted_joy': 'enbarr_plugins.joystick.scripted_joy:ScriptedJoyNode',
    'keyboard_teleop': 'enbarr_plugins.teleop.keyboard:KeyboardTeleopNode',
}


@dataclass(frozen=True)
class NodeEntry:
    name: str
    target: str
    origin: str  # 'builtin' or the distribution that declared the entry point


def entries() -> dict[str, NodeEntry]:
    """Every known node name, built-ins first, then entry points."""
    known = {name: NodeEntry(name, target, 'builtin') for name, target in BUILTIN.items()}
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep.dist, 'name', None) or 'unknown distribution'
        if ep.name in known and known[ep.name].target != ep.value:
            raise RegistryError(
                f'node name {ep.name!r} from entry point {ep.value!r} ({dist}) is already '
                f'taken by {known[ep.name].target!r} ({known[ep.name].origin})')
        known.setdefault(ep.name, NodeEntry(ep.name, ep.value, dist))
    return known


def names() -> list[str]:
    return sorted(entries())


def resolve(name: str) -> type[Any]:
    """The node class registered as ``name``."""
    known = entries()
    entry = known.get(name)
    if entry is None:
        close = difflib.get_close_matches(name, known, n=1)
        hint = f' (did you mean {close[0]!r}?)' if close else ''
        raise RegistryError(
            f'unknown node {name!r}{hint}; known nodes: {", ".join(sorted(known))}')
    module_name, _, attr = entry.target.partition(':')
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split('.'):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as err:
        raise RegistryError(
            f'node {name!r} ({entry.origin}) points at {entry.target!r}, '
            f'which cannot be loaded: {err}') from err
    return obj
