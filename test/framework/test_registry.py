"""The node registry: built-in names plus ``enbarr.nodes`` entry points of other packages.

Third-party plugins are simulated without touching this repository: a package and its
``*.dist-info`` (METADATA + entry_points.txt) are written into ``tmp_path`` and put on the
PYTHONPATH of a subprocess, which is exactly how an installed distribution is found.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from enbarr_core.framework import registry
from enbarr_core.framework.errors import RegistryError
from support.cli import enbarr, refused

NODE_SOURCE = '''
from enbarr_core.framework.node import EnbarrNode


class MyNode(EnbarrNode):
    """A third-party node with one parameter."""

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_parameter('gain', 1.0)
'''


def make_distribution(site: Path, entry_points: dict[str, str],
                      dist: str = 'thirdparty_enbarr') -> None:
    """``site/thirdparty_enbarr/mod.py`` and ``site/<dist>-0.1.dist-info``."""
    pkg = site / 'thirdparty_enbarr'
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / '__init__.py').write_text('')
    (pkg / 'mod.py').write_text(NODE_SOURCE)
    info = site / f'{dist}-0.1.dist-info'
    info.mkdir()
    (info / 'METADATA').write_text(f'Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n')
    (info / 'entry_points.txt').write_text(
        '[enbarr.nodes]\n' + ''.join(f'{k} = {v}\n' for k, v in entry_points.items()))


def env_with(*paths: Path) -> dict[str, str]:
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [*(str(p) for p in paths), *filter(None, [os.environ.get('PYTHONPATH')])])
    return env


PROBE = textwrap.dedent("""
    import json, sys
    from enbarr_core.framework import registry
    from enbarr_core.framework.errors import RegistryError
    out = {}
    try:
        out['names'] = registry.names()
        entry = registry.entries().get(sys.argv[1])
        out['origin'] = entry and entry.origin
    except RegistryError as err:
        out['entries_error'] = str(err)
    try:
        cls = registry.resolve(sys.argv[1])
        from enbarr_core.framework.node import EnbarrNode
        out['resolved'] = f'{cls.__module__}:{cls.__qualname__}'
        out['is_enbarr_node'] = issubclass(cls, EnbarrNode)
    except RegistryError as err:
        out['resolve_error'] = str(err)
    print(json.dumps(out))
""")


def probe(site: Path, name: str) -> dict:
    r = subprocess.run([sys.executable, '-c', PROBE, name], env=env_with(site),
                       cwd=site, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


# -- in process: the built-in table ------------------------------------------------------------
def test_resolve_builtin_returns_the_class() -> None:
    from enbarr_core.framework.node import EnbarrNode
    from enbarr_plugins.imu.sim import SimImuNode
    assert registry.resolve('sim_imu') is SimImuNode
    assert issubclass(registry.resolve('velocity_control'), EnbarrNode)


def test_builtin_entry_names_its_target_and_origin() -> None:
    entry = registry.entries()['sim_imu']
    assert (entry.target, entry.origin) == ('enbarr_plugins.imu.sim:SimImuNode',
                                            'builtin')


def test_a_distribution_put_on_the_path_later_is_found(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The entry points are scanned once per search path (bringup resolves every node twice,
    0.1 s a scan), not once per process: a path added afterwards is scanned too.
    """
    assert 'late_node' not in registry.entries()  # the scan of the present path is cached
    make_distribution(tmp_path, {'late_node': 'thirdparty_enbarr.mod:MyNode'}, 'late_enbarr')
    monkeypatch.syspath_prepend(str(tmp_path))
    assert registry.entries()['late_node'].origin == 'late_enbarr'


def test_every_builtin_resolves() -> None:
    from enbarr_core.framework.node import EnbarrNode
    for name in registry.BUILTIN:
        assert issubclass(registry.resolve(name), EnbarrNode), name


def test_names_are_sorted_and_include_every_builtin() -> None:
    assert set(registry.BUILTIN) <= set(registry.names())
    assert registry.names() == sorted(registry.names())


def test_unknown_name_suggests_a_close_one_and_lists_known_names() -> None:
    with pytest.raises(RegistryError) as info:
        registry.resolve('sim_imuu')
    msg = str(info.value)
    assert msg.startswith("unknown node 'sim_imuu' (did you mean 'sim_imu'?); known nodes: ")
    assert msg.endswith(', '.join(registry.names()))


def test_unknown_name_with_nothing_close_suggests_nothing() -> None:
    with pytest.raises(RegistryError) as info:
        registry.resolve('zzzzzz')
    assert 'did you mean' not in str(info.value)
    assert 'attitude_filter' in str(info.value)


# -- third-party entry points, in a subprocess -------------------------------------------------
MINE = textwrap.dedent("""
    profile: mine
    nodes:
      mine:
        plugin: my_node
        parameters: {gain: 2.5}
      imu:
        plugin: sim_imu
    """)


def cli(site: Path | None, cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """``enbarr ARGS`` in a process that sees the distributions in ``site`` (None: none)."""
    return enbarr(*args, cwd=cwd, env=env_with(site) if site is not None else None)


@pytest.fixture
def third_party(tmp_path: Path) -> tuple[Path, Path]:
    """A site with the third-party ``my_node`` and a profile ``mine.yaml`` that uses it."""
    site = tmp_path / 'site'
    make_distribution(site, {'my_node': 'thirdparty_enbarr.mod:MyNode'})
    prof = site / 'mine.yaml'
    prof.write_text(MINE)
    return site, prof


@pytest.mark.e2e
def test_third_party_plugin_via_entry_point_is_found(third_party: tuple[Path, Path]) -> None:
    site, _ = third_party
    out = probe(site, 'my_node')
    assert 'my_node' in out['names'] and 'sim_imu' in out['names']
    assert out['origin'] == 'thirdparty_enbarr'
    assert out['resolved'] == 'thirdparty_enbarr.mod:MyNode'
    assert out['is_enbarr_node'] is True


@pytest.mark.e2e
def test_third_party_plugin_builds_in_a_profile(tmp_path: Path,
                                                third_party: tuple[Path, Path]) -> None:
    site, prof = third_party
    r = cli(site, tmp_path, 'bringup', '--profile', str(prof), '--check')
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f'{prof}: ok (2 nodes in 1 group(s))'


@pytest.mark.e2e
def test_list_nodes_names_the_third_party_origin(tmp_path: Path,
                                                 third_party: tuple[Path, Path]) -> None:
    site, _ = third_party
    r = cli(site, tmp_path, 'list', 'nodes')
    assert r.returncode == 0, r.stderr
    assert 'thirdparty_enbarr.mod:MyNode  (thirdparty_enbarr)' in r.stdout


@pytest.mark.e2e
def test_parameter_a_third_party_node_lacks_is_caught(tmp_path: Path,
                                                      third_party: tuple[Path, Path]) -> None:
    site, prof = third_party
    prof.write_text(MINE.replace('gain: 2.5', 'gian: 2.5'))
    stderr = refused(cli(site, tmp_path, 'bringup', '--profile', str(prof), '--check'))
    assert "node 'mine' (my_node) has no parameter 'gian' (did you mean 'gain'?)" in stderr


@pytest.mark.e2e
def test_third_party_name_is_unknown_without_its_distribution(
        tmp_path: Path, third_party: tuple[Path, Path]) -> None:
    _, prof = third_party
    stderr = refused(cli(None, tmp_path, 'bringup', '--profile', str(prof), '--check'))
    assert "nodes.mine.plugin: unknown node 'my_node'" in stderr


@pytest.fixture
def hijack_site(tmp_path: Path) -> Path:
    """A distribution that registers ``sim_imu`` for its own class."""
    site = tmp_path / 'site'
    make_distribution(site, {'sim_imu': 'thirdparty_enbarr.mod:MyNode'}, dist='imu_hijack')
    return site


@pytest.mark.e2e
def test_entry_point_colliding_with_builtin(hijack_site: Path) -> None:
    out = probe(hijack_site, 'sim_imu')
    assert 'names' not in out
    assert out['entries_error'] == (
        "node name 'sim_imu' from entry point 'thirdparty_enbarr.mod:MyNode' (imu_hijack) is "
        "already taken by 'enbarr_plugins.imu.sim:SimImuNode' (builtin)")
    assert 'resolved' not in out and out['resolve_error'] == out['entries_error']


@pytest.mark.e2e
def test_collision_is_a_one_line_profile_error(tmp_path: Path, hijack_site: Path) -> None:
    stderr = refused(cli(hijack_site, tmp_path, 'bringup', '--profile', 'enbarr_sim',
                         '--check'))
    assert stderr.startswith('enbarr bringup: error: ')
    assert 'thirdparty_enbarr.mod:MyNode' in stderr and 'SimImuNode' in stderr


@pytest.mark.e2e
def test_entry_point_repeating_builtin_target_is_not_a_collision(tmp_path: Path) -> None:
    site = tmp_path / 'site'
    make_distribution(site, {'sim_imu': 'enbarr_plugins.imu.sim:SimImuNode'},
                      dist='same_target')
    out = probe(site, 'sim_imu')
    assert out['origin'] == 'builtin'
    assert out['resolved'] == 'enbarr_plugins.imu.sim:SimImuNode'


@pytest.fixture
def broken_site(tmp_path: Path) -> Path:
    """A distribution whose entry points name a missing module and a missing class."""
    site = tmp_path / 'site'
    make_distribution(site, {'ghost': 'no_such_module_xyz.nodes:GhostNode',
                             'phantom': 'thirdparty_enbarr.mod:NoSuchClass'},
                      dist='broken_dist')
    return site


@pytest.mark.e2e
def test_entry_point_to_missing_module(broken_site: Path) -> None:
    out = probe(broken_site, 'ghost')
    assert 'ghost' in out['names'] and 'phantom' in out['names']  # listing still works
    assert out['resolve_error'].startswith(
        "node 'ghost' (broken_dist) points at 'no_such_module_xyz.nodes:GhostNode', "
        'which cannot be loaded: ')
    assert 'no_such_module_xyz' in out['resolve_error'].split('loaded: ')[1]


@pytest.mark.e2e
def test_entry_point_to_missing_class(broken_site: Path) -> None:
    out = probe(broken_site, 'phantom')
    assert out['resolve_error'].startswith(
        "node 'phantom' (broken_dist) points at 'thirdparty_enbarr.mod:NoSuchClass', "
        'which cannot be loaded: ')
    assert 'NoSuchClass' in out['resolve_error'].split('loaded: ')[1]


@pytest.mark.e2e
def test_profile_naming_a_broken_entry_point_fails_check(tmp_path: Path,
                                                         broken_site: Path) -> None:
    # a profile naming it loads (the name is registered) but --check refuses to build it
    prof = broken_site / 'ghost.yaml'
    prof.write_text('nodes:\n  g: {plugin: ghost}\n')
    stderr = refused(cli(broken_site, tmp_path, 'bringup', '--profile', str(prof), '--check'))
    assert stderr.startswith("enbarr bringup: error: node 'ghost' (broken_dist) points at "
                             "'no_such_module_xyz.nodes:GhostNode'")
