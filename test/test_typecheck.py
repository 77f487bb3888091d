"""The type check of the lint step (``mypy.ini``, run by ``./dev lint``) covers what it says:
the flags of ``mypy --strict`` on every module of the framework and the interfaces and on every
pure algorithm module (``support.layering``), and ``files`` (what ``mypy`` checks) and the
strict section name the same modules. A new algorithm module left out fails here.
"""

from __future__ import annotations

import configparser
from pathlib import Path

from support.layering import ALGORITHM_PACKAGES, algorithm_modules

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('enbarr_core', 'enbarr_interfaces', 'enbarr_plugins')
STRICT_PACKAGES = ('enbarr_core.framework', 'enbarr_interfaces')  # every module of them
# What `mypy --strict` turns on (mypy 2.4.1 --help), less warn_redundant_casts, a global flag.
STRICT_FLAGS = ('disallow_any_generics', 'disallow_subclassing_any', 'disallow_untyped_calls',
                'disallow_untyped_defs', 'disallow_incomplete_defs', 'check_untyped_defs',
                'disallow_untyped_decorators', 'warn_unused_ignores', 'warn_return_any',
                'no_implicit_reexport', 'strict_equality', 'extra_checks')


def module_of(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def modules_under(path: Path) -> set[str]:
    return {module_of(p) for p in ([path] if path.is_file() else path.rglob('*.py'))}


ALL_MODULES = set().union(*(modules_under(ROOT / p) for p in PACKAGES))


def matches(pattern: str, module: str) -> bool:
    """mypy's ``[mypy-pattern]``: ``a.b.*`` is a.b and everything in it."""
    if pattern.endswith('.*'):
        return module == pattern[:-2] or module.startswith(pattern[:-1])
    return module == pattern


def config() -> configparser.ConfigParser:
    parser = configparser.ConfigParser()
    assert parser.read(ROOT / 'mypy.ini')
    return parser


def strict_patterns(parser: configparser.ConfigParser) -> list[str]:
    sections = [s for s in parser.sections()
                if parser.getboolean(s, 'disallow_untyped_defs', fallback=False)]
    assert len(sections) == 1, f'one strict section expected, got {sections}'
    return sections[0].removeprefix('mypy-').split(',')


def test_the_strict_section_sets_every_flag_of_strict() -> None:
    parser = config()
    section = 'mypy-' + ','.join(strict_patterns(parser))
    unset = [f for f in STRICT_FLAGS if not parser.getboolean(section, f, fallback=False)]
    assert unset == []
    assert parser.getboolean('mypy', 'warn_redundant_casts')


def test_strict_on_the_framework_the_interfaces_and_the_algorithms() -> None:
    patterns = strict_patterns(config())
    wanted = {m for m in ALL_MODULES if any(matches(p + '.*', m) for p in STRICT_PACKAGES)}
    wanted |= set(ALGORITHM_PACKAGES) | set(algorithm_modules())
    assert len(wanted) >= 30
    missing = sorted(m for m in wanted if not any(matches(p, m) for p in patterns))
    assert missing == [], 'add them to the strict section of mypy.ini and to its files'
    stale = [p for p in patterns if not any(matches(p, m) for m in ALL_MODULES)]
    assert stale == [], 'mypy.ini names modules that do not exist'


def test_mypy_checks_exactly_the_strict_modules() -> None:
    parser = config()
    paths = [p.strip() for p in parser.get('mypy', 'files').split(',') if p.strip()]
    assert [p for p in paths if not (ROOT / p).exists()] == []
    checked = set().union(*(modules_under(ROOT / p) for p in paths))
    strict = {m for m in ALL_MODULES if any(matches(p, m) for p in strict_patterns(parser))}
    assert sorted(strict - checked) == [], 'strict but not in files'
    assert sorted(checked - strict) == [], 'in files but not strict'
