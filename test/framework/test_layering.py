"""Algorithms know nothing of ROS: every module of the algorithm folders (estimation,
control, guidance, allocation, models, world) except the nodes (``*_node.py``) and their parameter
declarations (``*_params.py``), and the framework's maths and the bag format, imports with
rclpy made unimportable; so do the device transport layer and the pure plugin modules.
A real driver never imports its emulator (the check-device command lives apart).
"""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys

import pytest
from support.layering import algorithm_modules, imports_in

ALSO_PURE = ('enbarr_core.framework.kinematics', 'enbarr_core.framework.checks',
             'enbarr_core.framework.errors', 'enbarr_core.framework.frames',
             'enbarr_core.recording.bag', 'enbarr_core.recording.qos',
             'enbarr_core.recording.tf', 'enbarr_core.recording.recorder',
             'enbarr_plugins.transport.i2c',
             'enbarr_plugins.transport.serial_link', 'enbarr_plugins.transport.net',
             'enbarr_plugins.operator.script', 'enbarr_interfaces.modes',
             'enbarr_core.framework.yaml12', 'enbarr_core.tools.chaos.judge',
             'enbarr_core.commands.arguments',
             'enbarr_plugins.lidar.rplidar_protocol', 'enbarr_plugins.lidar.scan',
             'enbarr_plugins.lidar.sim_scan',
             'enbarr_plugins.mocap.qtm_protocol', 'enbarr_plugins.mocap.qtm_frame',
             'enbarr_plugins.camera.capture', 'enbarr_plugins.camera.calibration',
             'enbarr_plugins.camera.sim_render',
             'enbarr_plugins.transport.reader')

pytestmark = pytest.mark.e2e  # imports in a fresh interpreter, a subprocess


def pure_modules() -> list[str]:
    return algorithm_modules() + list(ALSO_PURE)


def test_algorithms_import_without_rclpy() -> None:
    modules = pure_modules()
    code = ('import sys\n'
            'sys.modules["rclpy"] = None\n'  # any "import rclpy" now raises ImportError
            + ''.join(f'import {m}\n' for m in modules)
            + 'assert not any(k.startswith("rclpy") and sys.modules[k] is not None '
              'for k in sys.modules)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert len(modules) >= 14


#: driver module -> its emulator modules: neither side imports the other, anywhere in the
#: file (a function-level import is a cycle too); what both need is the protocol module's.
DRIVERS_AND_EMULATORS = {
    'enbarr_plugins.lidar.rplidar': ('enbarr_plugins.lidar.rplidar_emulator',),
    'enbarr_plugins.mocap.qualisys': ('enbarr_plugins.mocap.qtm_emulator',),
    'enbarr_plugins.camera.opencv_camera': ('enbarr_plugins.camera.emulator',
                                            'enbarr_plugins.camera.pattern_video',
                                            'enbarr_plugins.camera.sim',
                                            'enbarr_plugins.camera.sim_render'),
}


def imported_modules(module: str) -> set[str]:
    """Every module ``module``'s source imports, at any depth of its code."""
    return imports_in(importlib.util.find_spec(module).origin)


@pytest.mark.parametrize('driver', sorted(DRIVERS_AND_EMULATORS))
def test_a_driver_and_its_emulator_do_not_import_each_other(driver: str) -> None:
    emulators = DRIVERS_AND_EMULATORS[driver]
    assert not imported_modules(driver) & set(emulators)
    for emulator in emulators:
        assert driver not in imported_modules(emulator), emulator
