"""Shared test setup: test tiers, ROS traffic kept on this machine in a private domain, and a
private rclpy context with a bounded spin helper for node tests.

Test tiers (markers registered in ``setup.cfg``, run one with ``./dev test -m unit``):

- ``unit``: pure Python, no rclpy context, no subprocess (seconds; the edit-test loop).
- ``sim``: pure Python as ``unit``, but a closed loop or a long horizon integrated step by
  step (a vessel, its observer and controller over a manoeuvre; a filter converging over
  minutes of samples): seconds each. Marked explicitly (``@pytest.mark.sim``), so the
  edit-test loop stays fast; ``./dev test`` runs it with the others.
- ``node``: nodes built on an in-process executor (the ``context``/``executor`` fixtures).
- ``e2e``: whole profiles or the command line, run in processes as a user runs them.

Every test gets exactly one tier, derived at collection (``pytest_collection_modifyitems``):
a tier marker on the test (``pytestmark = pytest.mark.e2e`` in the module, or a decorator)
wins; otherwise a test under ``test/e2e/`` is ``e2e``, a test that uses the ``context`` or
``executor`` fixture is ``node``, and anything else is ``unit``. Collection fails (exit code
4, naming the tests) when a test carries two tiers, or is marked ``unit`` or ``sim`` but asks
for an rclpy context. A ``unit`` or ``sim`` test that starts a process or initializes rclpy
fails at that call (``_unit_tier_guard``): mark it ``e2e`` (processes) or use the
``context`` fixture (node).
``test/test_tiers.py`` checks these rules.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator

# Before anything imports rclpy: never leave the machine, never meet another run.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
os.environ.pop('ROS_LOCALHOST_ONLY', None)
sys.path.insert(0, os.path.dirname(__file__))  # shared test helpers: the support package

import itertools  # noqa: E402
from pathlib import Path  # noqa: E402
import subprocess  # noqa: E402

import pytest  # noqa: E402
from support.waiting import spin_until  # noqa: E402

TIERS = ('unit', 'sim', 'node', 'e2e')
PURE_TIERS = ('unit', 'sim')  # no rclpy context, no process
NODE_FIXTURES = frozenset({'context', 'executor'})
E2E_DIR = Path('test', 'e2e')  # relative to the root directory (where setup.cfg is)


def tier_of(item: pytest.Item) -> tuple[str | None, str | None]:
    """The tier of ``item`` and ``None``, or ``None`` and why it has no single tier."""
    marked = sorted({m.name for m in item.iter_markers() if m.name in TIERS})
    uses_node = sorted(NODE_FIXTURES & set(getattr(item, 'fixturenames', ())))
    if len(marked) > 1:
        return None, f'two tiers ({", ".join(marked)}); a test has exactly one'
    if len(marked) == 1 and marked[0] in PURE_TIERS and uses_node:
        return None, (f'marked {marked[0]} but uses the {uses_node[0]!r} fixture (an rclpy '
                      'context): that is the node tier')
    if marked:
        return marked[0], None
    if (item.config.rootpath / E2E_DIR) in Path(item.path).parents:
        return 'e2e', None
    return ('node' if uses_node else 'unit'), None


def pytest_configure(config: pytest.Config) -> None:
    """Build matplotlib's font cache before any test, where no tier guard is on.

    Where the cache does not exist yet (a fresh machine or CI runner, a new user), the first
    ``import matplotlib.pyplot`` runs ``fc-list``: a process, which ``_unit_tier_guard``
    refuses in a unit test (2026-11-27, a new VM: every plot test of the unit tier failed).
    """
    import matplotlib.font_manager  # noqa: F401 - the import builds the cache


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Give every test its tier marker (see the module docstring); refuse two or none."""
    problems = []
    for item in items:
        tier, why = tier_of(item)
        if tier is None:
            problems.append(f'{item.nodeid}: {why or "no tier"}')
        elif item.get_closest_marker(tier) is None:
            item.add_marker(tier)
    if problems:
        raise pytest.UsageError('test tiers (see test/conftest.py):\n  '
                                + '\n  '.join(problems))


class TierError(AssertionError):
    """A unit- or sim-tier test did what only the node or e2e tier may do."""


@pytest.fixture(autouse=True)
def _unit_tier_guard(request: pytest.FixtureRequest,
                     monkeypatch: pytest.MonkeyPatch) -> None:
    """In a unit or sim test, starting a process or initializing rclpy raises ``TierError``."""
    if not any(request.node.get_closest_marker(t) for t in PURE_TIERS):
        return

    def refuse(what: str) -> Callable[..., None]:
        def refused(*args: object, **kwargs: object) -> None:
            raise TierError(f'a unit test {what}: mark it pytest.mark.e2e (processes) or use '
                            'the context fixture (node tier); see test/conftest.py')
        return refused

    monkeypatch.setattr(subprocess, 'Popen', refuse('started a process'))
    from rclpy.context import Context
    monkeypatch.setattr(Context, 'init', refuse('initialized an rclpy context'))

# Test runs side by side on one machine keep apart with ENBARR_TEST_DOMAINS=first-last.
_first, _, _last = os.environ.get('ENBARR_TEST_DOMAINS', '1-100').partition('-')
_DOMAIN_FIRST, _DOMAIN_COUNT = int(_first), int(_last) - int(_first) + 1
# Under pytest-xdist (``-n N``) every worker takes its own slice of the range: two workers'
# runs must never meet on one domain.
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
if _WORKER.startswith('gw') and int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1')) > 1:
    _workers = int(os.environ['PYTEST_XDIST_WORKER_COUNT'])
    _slice = max(1, _DOMAIN_COUNT // _workers)
    _DOMAIN_FIRST += int(_WORKER[2:]) * _slice % _DOMAIN_COUNT
    _DOMAIN_COUNT = _slice
    os.environ['ROS_DOMAIN_ID'] = str(_DOMAIN_FIRST)
# The e2e tier's processes draw from the upper half of the range, everything else (node tests
# in this process) from the lower half: a node of the pytest process itself, still on the ROS
# graph after its test, once refused a later e2e run of the same vessel (a /pwm) whose domain
# number had come round again. Which test left it is not known yet; the halves keep the two
# kinds of test from meeting whatever it was.
_HALF = max(1, _DOMAIN_COUNT // 2)
_domains = {False: itertools.count(int(os.environ['ROS_DOMAIN_ID'])),
            True: itertools.count(int(os.environ['ROS_DOMAIN_ID']))}


def _next_domain(e2e: bool = False) -> str:
    if _DOMAIN_COUNT < 2:
        return str(_DOMAIN_FIRST)
    first, count = (_DOMAIN_FIRST + _HALF, _DOMAIN_COUNT - _HALF) if e2e \
        else (_DOMAIN_FIRST, _HALF)
    return str(first + next(_domains[e2e]) % count)


def _is_e2e(node: pytest.Item | pytest.Collector) -> bool:
    return node.get_closest_marker('e2e') is not None \
        or (node.config.rootpath / E2E_DIR) in Path(node.path).parents


@pytest.fixture(autouse=True, scope='module')
def module_domain(request: pytest.FixtureRequest) -> Iterator[str]:
    """A fresh ROS_DOMAIN_ID for a module's shared fixtures (a run started once per module).

    Without it they ran in the session's domain, which the per-test domains below also hand
    out: a run started by a module fixture was refused as a second vessel because a node
    test before it had a node of the same name in that domain.
    """
    old = os.environ['ROS_DOMAIN_ID']
    os.environ['ROS_DOMAIN_ID'] = domain = _next_domain(_is_e2e(request.node))
    try:
        yield domain
    finally:
        os.environ['ROS_DOMAIN_ID'] = old


@pytest.fixture(autouse=True)
def private_domain(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """A fresh ROS_DOMAIN_ID (1..100) for every test and the processes it starts: a test
    that SIGKILLs a run leaves DDS participants (and shared-memory ports) behind until their
    leases expire, and the next test must not meet them.
    """
    domain = _next_domain(_is_e2e(request.node))
    monkeypatch.setenv('ROS_DOMAIN_ID', domain)
    return domain


@pytest.fixture
def context() -> Iterator[object]:
    """A private, initialized rclpy Context, shut down after the test."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context: object) -> Iterator[object]:
    """A ``SingleThreadedExecutor`` in ``context``; destroys its nodes after the test."""
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor(context=context)
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


@pytest.fixture
def spin() -> Callable[..., bool]:
    """``spin_until`` (``support.waiting``), as a fixture."""
    return spin_until
