"""Algorithms know nothing of ROS: every module under enbarr_core.algorithms (and the bag
writer) imports with rclpy made unimportable."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import enbarr_core.algorithms as algorithms

MODULES = sorted(f'enbarr_core.algorithms.{m.name}' for m in pkgutil.iter_modules(
    algorithms.__path__)) + ['enbarr_core.bag']


def test_algorithms_import_without_rclpy() -> None:
    code = ('import sys\n'
            'sys.modules["rclpy"] = None\n'  # any "import rclpy" now raises ImportError
            + ''.join(f'import {m}\n' for m in MODULES)
            + 'assert not any(k.startswith("rclpy") and sys.modules[k] is not None '
              'for k in sys.modules)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert len(MODULES) >= 6
