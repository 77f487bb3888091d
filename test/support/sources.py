"""The package's own Python sources, parsed once per test session (for the tests that read
the code rather than run it: the dependency list, the public-API rule).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ('enbarr_core', 'enbarr_plugins', 'enbarr_interfaces')  # what setup.py installs
TESTS = 'test'


@dataclass(frozen=True)
class Import:
    """One import statement's top-level module, where it is."""

    module: str   # the top-level name ('cv2' for 'from cv2.typing import X')
    path: str     # relative to the repository root
    line: int


def python_files(*tops: str) -> list[Path]:
    """Every ``.py`` file under the given top-level folders of the repository, sorted."""
    return sorted(p for top in tops for p in (ROOT / top).rglob('*.py'))


@cache
def parse(path: Path) -> ast.Module:
    """The syntax tree of ``path`` (cached: several tests walk the same files)."""
    return ast.parse(path.read_text(encoding='utf-8'), filename=str(path))


def imports(path: Path) -> Iterator[Import]:
    """The absolute imports of ``path``, at any depth (a lazy import inside a function counts:
    it is needed when that function runs), and ``import_module('literal')`` or
    ``__import__('literal')``. A name computed at run time cannot be followed: the recorder
    imports the message package of each recorded type; those of the topic contract are
    imported by name in ``enbarr_interfaces.topics``."""
    rel = str(path.relative_to(ROOT))
    tree = parse(path)
    for node in _statements(tree.body):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(alias.name.split('.')[0], rel, node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield Import(node.module.split('.')[0], rel, node.lineno)
    text = path.read_text(encoding='utf-8')
    if 'import_module(' in text or '__import__(' in text:  # a whole walk only where needed
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and _call_name(node) in ('import_module', '__import__') \
                    and node.args and isinstance(node.args[0], ast.Constant) \
                    and isinstance(node.args[0].value, str):
                yield Import(node.args[0].value.split('.')[0], rel, node.lineno)


def _statements(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """Every statement of ``body``, nested ones (in functions, classes, ifs, trys) included."""
    for stmt in body:
        yield stmt
        for field in ('body', 'orelse', 'finalbody', 'handlers', 'cases'):
            yield from _statements(getattr(stmt, field, None) or [])


def _call_name(call: ast.Call) -> str | None:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
