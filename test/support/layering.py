"""Which modules are pure algorithms: every module of the algorithm packages (estimation,
control, guidance, allocation, models) except the nodes (``*_node``) and their parameter
declarations (``*_params``). The layering rule (``test/framework/test_layering.py``: they
import without rclpy) and the strict type check (``mypy.ini``, ``test/test_typecheck.py``)
both stand on this one definition.
"""

from __future__ import annotations

import importlib
import pkgutil

ALGORITHM_PACKAGES = ('enbarr_core.estimation', 'enbarr_core.control', 'enbarr_core.guidance',
                      'enbarr_core.allocation', 'enbarr_core.models')


def algorithm_modules() -> list[str]:
    """The pure algorithm modules (dotted names), sorted; the packages themselves left out."""
    found = []
    for package in ALGORITHM_PACKAGES:
        path = importlib.import_module(package).__path__
        found += [f'{package}.{m.name}' for m in pkgutil.iter_modules(path)
                  if not m.name.endswith(('_node', '_params'))]
    return sorted(found)
