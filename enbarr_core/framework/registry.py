"""Find node classes by name: a built-in table extended by Python entry points.

A third-party package adds a plugin without touching this repository by declaring, in its
own ``setup.py``::

    entry_points={'enbarr.nodes': ['my_imu = my_package.my_imu:MyImuNode']}

after which a profile can say ``plugin: my_imu``. A name given twice is an error (the entry
point cannot silently replace a built-in). An unknown name is an error that lists the known
ones.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
import difflib
import functools
import importlib
from importlib import metadata
import sys
from typing import Any, cast

from enbarr_core.framework.errors import RegistryError

ENTRY_POINT_GROUP = 'enbarr.nodes'

#: name -> 'module:Class' of the nodes this package ships.
BUILTIN: dict[str, str] = {
    # core
    'attitude_filter': 'enbarr_core.estimation.attitude_filter_node:AttitudeFilterNode',
    'command_receiver': 'enbarr_core.control.command_receiver_node:CommandReceiverNode',
    'velocity_control': 'enbarr_core.control.velocity_control_node:VelocityControlNode',
    'thruster_converter': 'enbarr_core.allocation.thruster_converter_node:ThrusterConverterNode',
    'failsafe': 'enbarr_core.control.failsafe_node:FailsafeNode',
    'thruster_monitor': 'enbarr_core.control.thruster_monitor_node:ThrusterMonitorNode',
    'rov_simulator': 'enbarr_core.simulation.rov_simulator_node:RovSimulatorNode',
    'scripted_commands': 'enbarr_plugins.operator.scripted_commands:ScriptedCommandsNode',
    'recorder': 'enbarr_core.recording.recorder_node:RecorderNode',
    'frame_publisher': 'enbarr_core.framework.frame_publisher_node:FramePublisherNode',
    'vessel3dof_simulator':
        'enbarr_core.simulation.vessel3dof_simulator_node:Vessel3DofSimulatorNode',
    'dp_observer': 'enbarr_core.estimation.dp_observer_node:DpObserverNode',
    'dp_control': 'enbarr_core.control.dp_control_node:DpControlNode',
    'guidance': 'enbarr_core.guidance.guidance_node:GuidanceNode',
    'azimuth_allocation': 'enbarr_core.allocation.azimuth_allocation_node:AzimuthAllocationNode',
    'pwm_mapper': 'enbarr_core.allocation.pwm_mapper_node:PwmMapperNode',
    'scan_obstacles': 'enbarr_core.perception.scan_obstacles_node:ScanObstaclesNode',
    'detector': 'enbarr_core.vision.detector_node:DetectorNode',
    'fusion': 'enbarr_core.vision.fusion_node:FusionNode',
    # plugins
    'sim_imu': 'enbarr_plugins.imu.sim:SimImuNode',
    'sim_thrusters': 'enbarr_plugins.thrusters.sim:SimThrustersNode',
    'sim_stepper': 'enbarr_plugins.io.sim_stepper:SimStepperNode',
    'sim_gpio': 'enbarr_plugins.io.sim_gpio:SimGpioNode',
    'sim_leak': 'enbarr_plugins.io.sim_leak:SimLeakNode',
    'sim_hull': 'enbarr_plugins.hull.sim:SimHullNode',
    'sim_mocap': 'enbarr_plugins.mocap.sim:SimMocapNode',
    'sim_lidar': 'enbarr_plugins.lidar.sim:SimLidarNode',
    'sim_camera': 'enbarr_plugins.camera.sim:SimCameraNode',
    'sim_depth': 'enbarr_plugins.pressure.sim:SimDepthNode',
    'sim_battery': 'enbarr_plugins.power.sim:SimBatteryNode',
    'sim_arduino': 'enbarr_plugins.arduino.sim:SimArduinoNode',
    'scripted_joy': 'enbarr_plugins.joystick.scripted:ScriptedJoyNode',
    'keyboard_teleop': 'enbarr_plugins.operator.keyboard:KeyboardTeleopNode',
    'rov_gamepad': 'enbarr_plugins.operator.gamepad:RovGamepadNode',
    'foxglove_bridge': 'enbarr_plugins.foxglove.bridge:FoxgloveBridgeNode',
    'surface_station': 'enbarr_plugins.station.node:SurfaceStationNode',
    # device drivers, each with its emulator (docs/hardware.md)
    'pca9685_thrusters': 'enbarr_plugins.thrusters.pca9685:Pca9685ThrustersNode',
    'pca9685_emulator': 'enbarr_plugins.thrusters.pca9685_emulator:Pca9685EmulatorNode',
    'lsm9ds1_imu': 'enbarr_plugins.imu.lsm9ds1:Lsm9ds1ImuNode',
    'lsm9ds1_emulator': 'enbarr_plugins.imu.lsm9ds1_emulator:Lsm9ds1EmulatorNode',
    'fxos8700_imu': 'enbarr_plugins.imu.fxos8700:Fxos8700ImuNode',
    'fxos8700_emulator': 'enbarr_plugins.imu.fxos8700_emulator:Fxos8700EmulatorNode',
    'ms5837_depth': 'enbarr_plugins.pressure.ms5837:Ms5837Node',
    'ms5837_emulator': 'enbarr_plugins.pressure.ms5837_emulator:Ms5837EmulatorNode',
    'ina219_battery': 'enbarr_plugins.power.ina219:Ina219Node',
    'ina219_emulator': 'enbarr_plugins.power.ina219_emulator:Ina219EmulatorNode',
    'bmp280_hull': 'enbarr_plugins.hull.bmp280:Bmp280Node',
    'bmp280_emulator': 'enbarr_plugins.hull.bmp280_emulator:Bmp280EmulatorNode',
    'arduino_pwm': 'enbarr_plugins.arduino.link:ArduinoPwmNode',
    'arduino_emulator': 'enbarr_plugins.arduino.emulator:ArduinoEmulatorNode',
    'rplidar': 'enbarr_plugins.lidar.rplidar:RplidarNode',
    'rplidar_emulator': 'enbarr_plugins.lidar.rplidar_emulator:RplidarEmulatorNode',
    'camera': 'enbarr_plugins.camera.opencv_camera:CameraNode',
    'camera_emulator': 'enbarr_plugins.camera.emulator:CameraEmulatorNode',
    'qualisys': 'enbarr_plugins.mocap.qualisys:QualisysNode',
    'qtm_emulator': 'enbarr_plugins.mocap.qtm_emulator:QtmEmulatorNode',
    'ds4_evdev': 'enbarr_plugins.joystick.ds4_evdev:Ds4EvdevNode',
    'ds4_emulator': 'enbarr_plugins.joystick.ds4_emulator:Ds4EmulatorNode',
    'gpio_lights': 'enbarr_plugins.io.gpio_lights:GpioLightsNode',
    'leak_gpio': 'enbarr_plugins.io.leak:LeakGpioNode',
    'stepper': 'enbarr_plugins.io.stepper:StepperNode',
}


@dataclass(frozen=True)
class NodeEntry:
    """A node type known by name, and where it comes from."""

    name: str
    target: str
    origin: str  # 'builtin' or the distribution that declared the entry point


@functools.lru_cache(maxsize=4)
def _declared(path: tuple[str, ...]) -> tuple[metadata.EntryPoint, ...]:
    """Return the ``ENTRY_POINT_GROUP`` entry points of the distributions on ``path``.

    Scanning every installed distribution reads each one's metadata from disk
    (``docs/benchmarks.md``), and bringup resolves each node of a profile twice: once per
    process and search path is enough.
    """
    return tuple(metadata.entry_points(group=ENTRY_POINT_GROUP))


def entries() -> dict[str, NodeEntry]:
    """Every known node name, built-ins first, then entry points."""
    known = {name: NodeEntry(name, target, 'builtin') for name, target in BUILTIN.items()}
    for ep in _declared(tuple(sys.path)):
        dist = getattr(ep.dist, 'name', None) or 'unknown distribution'
        if ep.name in known and known[ep.name].target != ep.value:
            raise RegistryError(
                f'node name {ep.name!r} from entry point {ep.value!r} ({dist}) is already '
                f'taken by {known[ep.name].target!r} ({known[ep.name].origin})')
        known.setdefault(ep.name, NodeEntry(ep.name, ep.value, dist))
    return known


def names() -> list[str]:
    """Return the known node type names, sorted."""
    return sorted(entries())


def resolve(name: str) -> type[Any]:
    """Return the node class registered as ``name``."""
    known = entries()
    entry = known.get(name)
    if entry is None:
        raise RegistryError(f'unknown node {name!r}{did_you_mean(name, known)}; known nodes: '
                            f'{", ".join(sorted(known))}')
    module_name, _, attr = entry.target.partition(':')
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split('.'):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as err:
        raise RegistryError(
            f'node {name!r} ({entry.origin}) points at {entry.target!r}, '
            f'which cannot be loaded: {err}') from err
    return cast('type[Any]', obj)  # what the entry point names: trusted to be a node class


def did_you_mean(word: str, candidates: Iterable[str], what: str = '') -> str:
    """Return `` (did you mean WHAT'x'?)`` naming the closest of ``candidates``, or ``''``.

    The one wording of every suggestion (a plugin, a node, a key): ``difflib``'s closest
    match above its default similarity cutoff (0.6).
    """
    close = difflib.get_close_matches(word, list(candidates), n=1)
    return f' (did you mean {what}{close[0]!r}?)' if close else ''
