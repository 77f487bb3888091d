"""Algorithms know nothing of ROS: every module of the algorithm folders (estimation,
control, guidance, allocation, models) except the nodes (``*_node.py``) and their parameter
declarations (``*_params.py``), and the framework's maths and the bag format, imports with
rclpy made unimportable; so do the device transport layer and the pure plugin modules.
"""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest

ALGORITHM_PACKAGES = ('enbarr_core.estimation', 'enbarr_core.control', 'enbarr_core.guidance',
                      'enbarr_core.allocation', 'enbarr_core.models')
ALSO_PURE = ('enbarr_core.framework.kinematics', 'enbarr_core.framework.checks',
             'enbarr_core.framework.errors', 'enbarr_core.framework.frames',
             'enbarr_core.recording.bag', 'enbarr_core.recording.qos',
             'enbarr_core.recording.tf', 'enbarr_core.recording.recorder',
             'enbarr_plugins.transport.i2c',
             'enbarr_plugins.transport.serial_link', 'enbarr_plugins.transport.net',
             'enbarr_plugins.operator.script', 'enbarr_interfaces.modes')

pytestmark = pytest.mark.e2e  # imports in a fresh interpreter, a subprocess


def pure_modules() -> list[str]:
    found = []
    for package in ALGORITHM_PACKAGES:
        path = importlib.import_module(package).__path__
        found += [f'{package}.{m.name}' for m in pkgutil.iter_modules(path)
                  if not m.name.endswith(('_node', '_params'))]
    return sorted(found) + list(ALSO_PURE)


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
