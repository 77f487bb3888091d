"""Which modules are pure algorithms: every module of the algorithm packages (estimation,
control, guidance, allocation, models, world, perception, vision) except the nodes (``*_node``) and
their parameter declarations (``*_params``). The layering rule
(``test/framework/test_layering.py``: they import without rclpy) and the strict type check
(``mypy.ini``, ``test/test_typecheck.py``) both stand on this one definition. ``imports_in``:
what a source file imports, for the import rules of the layering and device tests.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path
import pkgutil

ALGORITHM_PACKAGES = ('enbarr_core.estimation', 'enbarr_core.control', 'enbarr_core.guidance',
                      'enbarr_core.allocation', 'enbarr_core.models', 'enbarr_core.world',
                      'enbarr_core.perception', 'enbarr_core.vision')


def algorithm_modules() -> list[str]:
    """The pure algorithm modules (dotted names), sorted; the packages themselves left out."""
    found = []
    for package in ALGORITHM_PACKAGES:
        path = importlib.import_module(package).__path__
        found += [f'{package}.{m.name}' for m in pkgutil.iter_modules(path)
                  if not m.name.endswith(('_node', '_params'))]
    return sorted(found)


def imports_in(path: str | Path) -> set[str]:
    """Every module the source file ``path`` imports, at any depth of its code, dotted; for
    ``from a import b`` both ``a`` and ``a.b`` (``b`` may be a module)."""
    tree = ast.parse(Path(path).read_text(encoding='utf-8'), str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f'{node.module}.{alias.name}' for alias in node.names)
    return found
