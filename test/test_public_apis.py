"""The code uses rclpy's public API: a private name of rclpy (a method or attribute with one
leading underscore, as rclpy's own sources define them) is read nowhere in the package or the
tests, and rclpy's implementation module is imported only where ``PRIVATE_ALLOWED`` says why.

A private name that this repository also defines is not flagged (a static walk cannot tell
whose attribute ``x._lock`` is); every other one is, wherever it appears.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import rclpy

from support.sources import PACKAGES, parse, python_files, ROOT, TESTS

# Where rclpy has no public way, with the version and the reason (as the code's comment says).
PRIVATE_ALLOWED = {
    ('enbarr_interfaces/links.py', 'rclpy.impl'):
        'rclpy 7.1 has no public way to create a subscription that no executor waits on '
        '(the shadow reader of a link subscription)',
}


def private_names(tree: ast.AST) -> set[str]:
    """Methods and attributes with one leading underscore that ``tree`` defines."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
    return {n for n in names if n.startswith('_') and not n.startswith('__')}


@cache
def rclpy_private_names() -> frozenset[str]:
    root = Path(rclpy.__file__).parent
    return frozenset(set().union(*(private_names(parse(p)) for p in root.rglob('*.py'))))


@dataclass(frozen=True)
class Names:
    """What one file defines, and the attributes it reads, with their lines."""

    defined: frozenset[str]
    attributes: tuple[tuple[int, str], ...]
    rclpy_impl: tuple[tuple[int, str], ...]  # imports of rclpy's implementation


def names(tree: ast.AST) -> Names:
    """One walk of ``tree`` (the test reads about 50 000 lines: once each)."""
    defined, attributes, impl = set(), [], []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, ast.Attribute):
            if isinstance(node.ctx, ast.Store):
                defined.add(node.attr)
            elif node.attr.startswith('_'):
                attributes.append((node.lineno, node.attr))
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            defined.add(node.id)
        elif isinstance(node, ast.ImportFrom) and (node.module or '').startswith('rclpy.impl'):
            impl.append((node.lineno, node.module))
    return Names(frozenset(defined), tuple(attributes), tuple(impl))


def private_uses(trees: dict[str, ast.AST], private: frozenset[str]) -> list[str]:
    """``path:line name`` of each use of a name in ``private`` that ``trees`` (by path) do
    not define, and of each import of rclpy's implementation that ``PRIVATE_ALLOWED`` does
    not explain."""
    found = {rel: names(tree) for rel, tree in trees.items()}
    theirs = private - set().union(*(n.defined for n in found.values()))
    out = []
    for rel, n in found.items():
        out += [f'{rel}:{line} {attr}' for line, attr in n.attributes if attr in theirs]
        out += [f'{rel}:{line} {module}' for line, module in n.rclpy_impl
                if (rel, 'rclpy.impl') not in PRIVATE_ALLOWED]
    return out


def test_no_private_rclpy_api() -> None:
    trees = {str(p.relative_to(ROOT)): parse(p) for p in python_files(*PACKAGES, TESTS)}
    found = private_uses(trees, rclpy_private_names())
    assert not found, 'private rclpy API (use the public one):\n  ' + '\n  '.join(found)


def test_the_private_names_are_rclpys() -> None:
    """The walk finds what the simulated clock used to call, and leaves public names alone."""
    private = rclpy_private_names()
    assert {'_set_ros_time_is_active', '_subscribe_to_clock_topic'} <= private
    assert 'set_ros_time_override' not in private and 'clock_callback' not in private


def test_each_kind_of_private_use_is_named() -> None:
    trees = {'a.py': ast.parse('clock._set_ros_time_is_active(True)\n'
                               'clock.set_ros_time_override(t)\n'
                               'self._lock = None\n'
                               'node._lock.acquire()\n'),   # ours too: not flagged
             'b.py': ast.parse('from rclpy.impl.implementation_singleton import x\n')}
    private = frozenset({'_set_ros_time_is_active', '_lock'})
    assert private_uses(trees, private) == [
        'a.py:1 _set_ros_time_is_active', 'b.py:1 rclpy.impl.implementation_singleton']
    assert private_uses({'links.py': trees['b.py']}, private) == [
        'links.py:1 rclpy.impl.implementation_singleton']  # allowed in one file only
