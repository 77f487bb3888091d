"""Vessel profiles: YAML files naming the nodes to run, their parameters and how they group.

A profile (see ``params/*.yaml`` and ``docs/profiles.md``)::

    profile: enbarr_sim                  # a name for logs
    description: ...                     # one line, shown by ``enbarr list``
    fragment: false                      # true: include-only (bringup refuses to run it)
    include: [core.yaml]                 # merged first, in order; this file overrides them
    environment: {ROS_AUTOMATIC_DISCOVERY_RANGE: LOCALHOST}   # set before ROS starts (null:
                                         # drop an included profile's, the shell's applies)
    parameters: {...}                    # given to every node (like '/**' in a ROS params file)
    nodes:
      imu:                               # node name
        plugin: sim_imu                  # registry name (enbarr_core.framework.registry)
        namespace: ''                    # optional
        remappings: {imu/data_raw: imu0/data_raw}
        parameters: {rate: 400.0}        # nested mappings become dotted ROS parameter names
        group: main                      # process group (default: main)
        enabled: true                    # false drops a node an included profile declared
    groups: {main: {restart_limit: 3, restart_delay: 1.0}}
    record: {path: bags/run, topics: [], flush_seconds: 1.0, split_size: 0, split_seconds: 0}
    frames: {odom: {}, base_link: {parent: odom, pose: observer/odometry}, ...}
                                         # the frame tree (enbarr_core.framework.frames)
    world: {basin: {kind: walls, points: [...], closed: true}, buoy: {kind: circle, ...}}
                                         # the simulated world (enbarr_core.world.parse)

Everything is checked before any node starts; an error names the file, the key path and
what was expected. YAML is read with 1.2 numbers (``enbarr_core.framework.yaml12``: ``1e9``
is a float); every number must be finite and within its key's range.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
import ipaddress
import math
import os
from pathlib import Path
import re
import reprlib
import sys
from typing import Any

import yaml

from enbarr_core.framework import registry, yaml12
from enbarr_core.framework.errors import ProfileError, RegistryError
from enbarr_core.framework.frames import DEFAULT_TREE, FrameTree, parse_frames
from enbarr_core.world.model import EMPTY_WORLD, World
from enbarr_core.world.parse import parse_world

#: The top-level keys of a profile file. A new section adds its key here and its per-file
#: check to ``_check_structure``; any other key is refused with the list (and a close match).
TOP_KEYS = ('profile', 'description', 'fragment', 'include', 'environment', 'parameters',
            'nodes', 'groups', 'record', 'scenario', 'frames', 'world')
NODE_KEYS = ('plugin', 'namespace', 'remappings', 'parameters', 'group', 'enabled')
GROUP_KEYS = ('restart_limit', 'restart_delay')
RECORD_KEYS = ('path', 'topics', 'flush_seconds', 'split_size', 'split_seconds',
               'skip_raw_images')
DEFAULT_GROUP = 'main'
_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_NAMESPACE = re.compile(r'^(/?[A-Za-z][A-Za-z0-9_]*)*/?$')

#: The ranges of the profile's own numbers: (low, high, what) with ``low`` excluded when the
#: value must be positive. A supervisor that sleeps ``restart_delay`` or a recorder that waits
#: ``flush_seconds`` must be given a time it can wait; the bounds are far beyond any use.
MAX_RESTART_LIMIT = 10_000          # restarts of a group
MAX_WAIT_S = 3_600.0                # [s] restart_delay, flush_seconds
MAX_SPLIT_SIZE_MB = 1_000_000.0     # [MB] a bag file (1 TB)
MAX_SPLIT_S = 1_000_000.0           # [s] of messages in one bag file (11.6 days)
#: ROS parameters are 64-bit: a larger integer cannot be sent (rclpy raises deep inside).
INT64 = (-(1 << 63), (1 << 63) - 1)

#: ROS_DOMAIN_ID: Fast-DDS maps the domain to UDP ports (7400 + 250 domain + ...); on Linux
#: 232 is the highest domain whose ports fit (ROS 2 docs, "The ROS_DOMAIN_ID").
MAX_DOMAIN_ID = 232
DISCOVERY_RANGES = ('SUBNET', 'LOCALHOST', 'OFF', 'SYSTEM_DEFAULT')
_ENV_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')
_HOST_LABEL = re.compile(r'^(?!-)[A-Za-z0-9-]{1,63}(?<!-)$')


@dataclass(frozen=True)
class NodeSpec:
    """One node of a profile: which plugin, where, with what parameters, in which group."""

    name: str
    plugin: str
    namespace: str = ''
    remappings: tuple[tuple[str, str], ...] = ()
    parameters: Mapping[str, Any] = field(default_factory=dict)  # this node's own
    group: str = DEFAULT_GROUP
    origin: str = ''  # the file that named the plugin, for error messages


@dataclass(frozen=True)
class GroupSpec:
    """A process group of a profile and how its supervisor restarts it."""

    name: str
    restart_limit: int = 3
    restart_delay: float = 1.0  # [s]


@dataclass(frozen=True)
class RecordSpec:
    """The profile's ``record`` section: where to write a bag, and which topics."""

    path: str
    topics: tuple[str, ...] = ()  # empty: every topic
    flush_seconds: float = 1.0  # [s] a kill loses at most this much
    split_size: float = 0.0     # [MB] a new file of the bag past this size; 0: one file
    split_seconds: float = 0.0  # [s] a new file past this much message time; 0: one file
    skip_raw_images: bool = True  # all topics: a raw image with a compressed sibling left out


@dataclass(frozen=True)
class Profile:
    """A loaded, validated vessel profile (its includes merged, ``--set`` applied)."""

    name: str
    path: str
    description: str
    environment: Mapping[str, str]
    parameters: Mapping[str, Any]  # given to every node that declares them
    nodes: tuple[NodeSpec, ...]
    groups: Mapping[str, GroupSpec]
    record: RecordSpec | None
    files: tuple[str, ...]
    origins: Mapping[str, str] = field(default_factory=dict, repr=False)
    scenario: Mapping[str, Any] | None = None  # only scenario profiles (enbarr scenario)
    frames: FrameTree = DEFAULT_TREE  # the ``frames`` section (framework.frames)
    world: World = EMPTY_WORLD  # the ``world`` section (enbarr_core.world)
    #: Groups were left out (``select_groups``): a common parameter may be theirs alone.
    partial: bool = False

    def node(self, name: str) -> NodeSpec:
        """Return the node called ``name``; ``ProfileError`` listing the nodes if none."""
        for n in self.nodes:
            if n.name == name:
                return n
        raise ProfileError(f'no node {name!r}; nodes: {", ".join(self.node_names())}',
                           path=self.path)

    def node_names(self) -> list[str]:
        """Name the nodes, in profile order."""
        return [n.name for n in self.nodes]

    def group_names(self) -> list[str]:
        """Name the groups that have nodes, sorted."""
        return sorted({n.group for n in self.nodes})

    def where(self, key: str) -> str:
        """Return the file that set ``key`` (a dotted key path), for error messages."""
        return _origin(self.origins, key, self.path)


# -- locating --------------------------------------------------------------------------------
def search_dirs() -> list[Path]:
    """Where bare profile names are looked up, in order.

    The package's installed ``share/enbarr/params`` (found through the ament index the way
    ``ros2 run`` finds packages, then under this Python's prefix), then the source tree.
    """
    dirs: list[Path] = []
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('enbarr')) / 'params')
    except Exception:  # noqa: BLE001 - not installed through ament: fall through
        pass
    dirs.append(Path(sys.prefix) / 'share' / 'enbarr' / 'params')
    dirs.append(Path(__file__).resolve().parents[2] / 'params')
    return [d for d in dirs if d.is_dir()]


def resolve_profile(ref: str, relative_to: Path | None = None) -> Path:
    """Find a profile: a path (absolute, or relative to ``relative_to``/cwd) or a bare name."""
    candidates: list[Path] = []
    p = Path(ref).expanduser()
    if p.is_absolute():
        candidates.append(p)
    else:
        if relative_to is not None:
            candidates.append(relative_to / p)
        candidates.append(Path.cwd() / p)
        if len(p.parts) == 1:
            names = [ref] if ref.endswith(('.yaml', '.yml')) else [ref + '.yaml', ref]
            candidates += [d / n for d in search_dirs() for n in names]
    for c in candidates:
        if c.is_file():
            return c.resolve()
    runnable = [p.name for p in installed_profiles() if not p.fragment]
    raise ProfileError(
        f'profile {_show(ref)} not found{did_you_mean(ref, runnable)} (looked in: '
        f'{", ".join(str(c.parent) for c in candidates)}); '
        f'installed profiles: {", ".join(runnable) or "none"}')


# -- loading ---------------------------------------------------------------------------------
def load_profile(ref: str, overrides: Sequence[str] = (), *,
                 allow_fragment: bool = False) -> Profile:
    """Load, merge and validate a profile; apply ``--set node.param=value`` overrides.

    A fragment (``fragment: true``, include-only) is refused unless ``allow_fragment`` (to
    read its parameters, as a test does).
    """
    path = resolve_profile(ref)
    origins: dict[str, str] = {}
    files: list[str] = []
    merged = _load_merged(path, (), origins, files, allow_fragment=allow_fragment)
    for item in overrides:
        _apply_set(merged, item, origins)
    return _build(merged, str(path), origins, tuple(files))


def _load_merged(path: Path, stack: tuple[Path, ...], origins: dict[str, str],
                 files: list[str], *, allow_fragment: bool = True) -> dict[str, Any]:
    if path in stack:
        chain = ' -> '.join(str(p) for p in (*stack, path))
        raise ProfileError(f'include cycle: {chain}', path=str(path))
    raw = _read_yaml(path)
    where = str(path)
    # A file's own marks, never merged into the profiles that include it.
    fragment = raw.pop('fragment', False)
    if not isinstance(fragment, bool):
        raise ProfileError('expected true or false', path=where, key='fragment')
    if fragment and not allow_fragment:
        raise ProfileError(f'a fragment, only for include: [{path.stem}] in a vessel '
                           'profile; run one that includes it (enbarr list profiles)',
                           path=where)
    includes = raw.pop('include', None) or []
    if isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list) or not all(isinstance(i, str) for i in includes):
        raise ProfileError('expected a list of profile names or paths', path=where,
                           key='include')
    merged: dict[str, Any] = {}
    for inc in includes:
        try:
            inc_path = resolve_profile(inc, relative_to=path.parent)
        except ProfileError as err:
            raise ProfileError(str(err), path=where, key='include') from err
        _deep_merge(merged, _load_merged(inc_path, (*stack, path), origins, files), '', {}, '')
    _check_structure(raw, where)
    _deep_merge(merged, raw, '', origins, where)
    files.append(where)
    return merged


#: Limits on an untrusted profile: what a vessel profile needs many times over, and bounded
#: memory, time and output whatever a file holds.
MAX_FILE_BYTES = 256 << 10      # a profile file [bytes] (the largest shipped: 5 KB)
MAX_NODES = 100_000             # YAML nodes of one document, with aliases expanded
MAX_DEPTH = 32                  # nesting of mappings and lists
MAX_ITEMS = 4_096               # items of one mapping or list
MAX_KEY = 200                   # characters of a key
MAX_SCALAR = 20_000             # characters of a value
MAX_MESSAGE = 2_000             # characters of an error message's echo of a value


class _Refused(Exception):
    """What the loader refuses, and where (turned into a ``ProfileError`` by its caller)."""

    def __init__(self, message: str, mark: Any) -> None:
        super().__init__(message)
        self.mark = mark


# The one YAML loader of what users write (libyaml's parser when PyYAML has it, YAML 1.2
# numbers): profiles, scenarios and --set values all come through here.
_Loader: Any = yaml12.Yaml12Loader


class _ProfileLoader(_Loader):  # type: ignore[misc, valid-type]
    """``Yaml12Loader`` that refuses duplicate keys (merge keys ``<<`` aside)."""

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == 'tag:yaml.org,2002:merge':
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:  # an unhashable key: SafeLoader says so itself
                    continue
                if first is not key_node:
                    raise _Refused(f'duplicate key {_show(key)} (first at line '
                                   f'{first.start_mark.line + 1})', key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def _check_events(text: str) -> None:
    """Refuse nesting deeper than ``MAX_DEPTH`` or a scalar longer than ``MAX_SCALAR``.

    On the flat event stream, before anything recursive (composing, constructing) runs.
    """
    depth = 0
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise _Refused(f'nested deeper than {MAX_DEPTH} levels', event.start_mark)
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
        elif isinstance(event, yaml.ScalarEvent) and len(event.value) > MAX_SCALAR:
            raise _Refused(f'a value longer than {MAX_SCALAR} characters', event.start_mark)


def _check_size(root: Any) -> None:
    """Refuse a document whose expanded size, collections or scalars pass the limits.

    Counts every node as often as aliases repeat it (an alias bomb expands exponentially)
    without expanding anything: each node's expanded size is computed once.
    """
    sizes: dict[int, int] = {}
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in sizes:
            continue
        if isinstance(node, yaml.ScalarNode):
            if len(node.value) > MAX_SCALAR:
                raise _Refused(f'a value longer than {MAX_SCALAR} characters', node.start_mark)
            sizes[id(node)] = 1
            continue
        children = ([c for kv in node.value for c in kv] if isinstance(node, yaml.MappingNode)
                    else list(node.value))
        if not done:
            if len(node.value) > MAX_ITEMS:
                raise _Refused(f'more than {MAX_ITEMS} items', node.start_mark)
            if isinstance(node, yaml.MappingNode):
                for k, _ in node.value:
                    if isinstance(k, yaml.ScalarNode) and len(k.value) > MAX_KEY:
                        raise _Refused(f'a key longer than {MAX_KEY} characters', k.start_mark)
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in sizes)
            continue
        total = 1 + sum(sizes[id(c)] for c in children)
        if total > MAX_NODES:
            raise _Refused(f'expands to more than {MAX_NODES} values (aliases included)',
                           node.start_mark)
        sizes[id(node)] = total


def _safe_load(text: str) -> Any:
    """``yaml.safe_load`` that refuses duplicate keys and anything past the limits above."""
    _check_events(text)
    loader = _ProfileLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_size(node)
        return loader.construct_document(node)
    finally:
        loader.dispose()


_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = 200
_REPR.maxlist = _REPR.maxdict = 20
_REPR.maxlevel = 4


def _show(value: Any) -> str:
    """``repr(value)``, bounded: error messages echo untrusted values."""
    return _REPR.repr(value)


def _where(mark: Any) -> str:
    return f'line {mark.line + 1}, column {mark.column + 1}: ' if mark else ''


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise ProfileError(f'too large: {path.stat().st_size} bytes (at most '
                               f'{MAX_FILE_BYTES})', path=str(path))
        with path.open('rb') as f:  # a file that grows after stat is still cut off
            data = f.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise ProfileError(f'too large: more than {MAX_FILE_BYTES} bytes', path=str(path))
        text = data.decode('utf-8')
    except OSError as err:
        raise ProfileError(f'cannot read: {err.strerror or err}', path=str(path)) from err
    except UnicodeDecodeError as err:
        raise ProfileError(f'not UTF-8 text: byte {err.start}: {err.reason}',
                           path=str(path)) from err
    try:
        raw = _safe_load(text)
    except _Refused as err:
        raise ProfileError(f'{_where(err.mark)}{err}', path=str(path)) from None
    except RecursionError:
        raise ProfileError(f'nested deeper than {MAX_DEPTH} levels', path=str(path)) from None
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        problem = getattr(err, 'problem', None) or str(err)
        raise ProfileError(f'{_where(mark)}invalid YAML: {_cut(problem)}',
                           path=str(path)) from err
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ProfileError(f'expected a mapping at the top level, got {_kind(raw)}',
                           path=str(path))
    return raw


def _cut(text: str, limit: int = MAX_MESSAGE) -> str:
    """``text``, cut to ``limit`` characters: messages echo values, and values are untrusted."""
    return text if len(text) <= limit else f'{text[:limit]}... ({len(text) - limit} more)'


def _check_structure(raw: dict[str, Any], where: str) -> None:
    """Per-file checks of shape and types (semantics come after the merge)."""
    for key in raw:
        if key not in TOP_KEYS:
            _unknown_key(key, TOP_KEYS, where, str(key))
    for key in ('profile', 'description'):
        if key in raw and not isinstance(raw[key], str):
            raise ProfileError(f'expected a string, got {_kind(raw[key])}', path=where, key=key)
    env = raw.get('environment')
    if env is not None:
        raw['environment'] = _check_environment(env, where)
    if 'parameters' in raw:
        raw['parameters'] = _flatten_parameters(raw['parameters'], where, 'parameters')
    nodes = raw.get('nodes')
    if nodes is not None:
        _expect_mapping(nodes, where, 'nodes')
        for name, node in nodes.items():
            key = f'nodes.{name}'
            if not isinstance(name, str) or not _NAME.match(name):
                raise ProfileError('node names are letters, digits and _ and start with a '
                                   'letter', path=where, key=key)
            if node is None:
                node = nodes[name] = {}
            _expect_mapping(node, where, key)
            for k in node:
                if k not in NODE_KEYS:
                    _unknown_key(k, NODE_KEYS, where, f'{key}.{k}')
            for k in ('plugin', 'namespace', 'group'):
                if k in node and not isinstance(node[k], str):
                    raise ProfileError(f'expected a string, got {_kind(node[k])}', path=where,
                                       key=f'{key}.{k}')
            if 'namespace' in node and not _NAMESPACE.match(node['namespace']):
                raise ProfileError(f'{_show(node["namespace"])} is not a valid ROS namespace',
                                   path=where, key=f'{key}.namespace')
            if 'group' in node and not _NAME.match(node['group']):
                raise ProfileError('group names are letters, digits and _', path=where,
                                   key=f'{key}.group')
            if 'enabled' in node and not isinstance(node['enabled'], bool):
                raise ProfileError('expected true or false', path=where, key=f'{key}.enabled')
            remaps = node.get('remappings')
            if remaps is not None:
                _expect_mapping(remaps, where, f'{key}.remappings')
                for src, dst in remaps.items():
                    for t in (src, dst):
                        reason = topic_name_problem(t, remap=True)
                        if reason:
                            raise ProfileError(f'{_show(t)} is not a valid topic name to remap: '
                                               f'{reason}', path=where,
                                               key=f'{key}.remappings')
            if 'parameters' in node:
                node['parameters'] = _flatten_parameters(node['parameters'], where,
                                                         f'{key}.parameters')
    groups = raw.get('groups')
    if groups is not None:
        _expect_mapping(groups, where, 'groups')
        for gname, g in groups.items():
            gkey = f'groups.{gname}'
            if not isinstance(gname, str) or not _NAME.match(gname):
                raise ProfileError('group names are letters, digits and _', path=where, key=gkey)
            if g is None:
                g = groups[gname] = {}
            _expect_mapping(g, where, gkey)
            for k in g:
                if k not in GROUP_KEYS:
                    _unknown_key(k, GROUP_KEYS, where, f'{gkey}.{k}')
            _expect_number(g, 'restart_limit', where, gkey, high=MAX_RESTART_LIMIT,
                           integer=True)
            _expect_number(g, 'restart_delay', where, gkey, high=MAX_WAIT_S)
    if 'scenario' in raw:
        _expect_mapping(raw['scenario'], where, 'scenario')
    record = raw.get('record')
    if record is not None:
        _expect_mapping(record, where, 'record')
        for k in record:
            if k == 'segment_seconds':
                raise ProfileError('renamed flush_seconds: a bag is one file now, flushed '
                                   'every flush_seconds; split it with split_size (MB) or '
                                   'split_seconds', path=where, key='record.segment_seconds')
            if k not in RECORD_KEYS:
                _unknown_key(k, RECORD_KEYS, where, f'record.{k}')
        if 'path' in record and not isinstance(record['path'], str):
            raise ProfileError('expected a directory path', path=where, key='record.path')
        t = record.get('topics', [])
        if not isinstance(t, list) or not all(isinstance(x, str) for x in t):
            raise ProfileError('expected a list of topic names', path=where, key='record.topics')
        for x in t:
            reason = topic_name_problem(x)
            if reason:
                raise ProfileError(f'{_show(x)} is not a valid topic name: {reason}',
                                   path=where, key='record.topics')
        _expect_number(record, 'flush_seconds', where, 'record', high=MAX_WAIT_S,
                       positive=True)
        _expect_number(record, 'split_size', where, 'record', high=MAX_SPLIT_SIZE_MB)
        _expect_number(record, 'split_seconds', where, 'record', high=MAX_SPLIT_S)
        if not isinstance(record.get('skip_raw_images', True), bool):
            raise ProfileError(f'expected true or false, got {record["skip_raw_images"]!r}',
                               path=where, key='record.skip_raw_images')


def _unknown_key(key: Any, allowed: Sequence[str], where: str, path: str) -> None:
    """Refuse ``key``, naming a close match among ``allowed`` and listing them all."""
    raise ProfileError(f'unknown key{did_you_mean(str(key), allowed)}; expected one of: '
                       f'{", ".join(allowed)}', path=where, key=path)


def did_you_mean(word: str, candidates: Sequence[str], what: str = '') -> str:
    """Return `` (did you mean 'x'?)`` for the closest of ``candidates``, or ``''``."""
    return registry.did_you_mean(word, candidates, what)


def _check_environment(env: Any, where: str) -> dict[str, str | None]:
    """Return the ``environment`` section as strings, the ROS variables' values checked.

    A null value stays None: it drops the variable an included profile set (the merged
    profile leaves it out).
    """
    _expect_mapping(env, where, 'environment')
    out: dict[str, str | None] = {}
    for k, v in env.items():
        key = f'environment.{k}'
        if not isinstance(k, str) or not _ENV_NAME.match(k):
            raise ProfileError('an environment variable name is letters, digits and _ and '
                               'does not start with a digit', path=where, key=key)
        if v is None:  # drops what an included profile set: the shell's value applies
            out[k] = None
            continue
        if isinstance(v, float) and not math.isfinite(v):
            raise ProfileError(f'expected a finite number, got {v}', path=where, key=key)
        if not isinstance(v, (str, int, float, bool)):
            raise ProfileError(f'expected a scalar, got {_kind(v)}', path=where, key=key)
        text = str(v)
        reason = environment_problem(k, text)
        if reason:
            raise ProfileError(reason, path=where, key=key)
        out[k] = text
    return out


def environment_problem(name: str, value: str) -> str | None:
    """Why ``value`` cannot be the environment variable ``name``, or None.

    Any value is a string without NUL (the C environment ends a value there). The ROS
    variables a profile may set are checked as ROS reads them: ``ROS_DOMAIN_ID`` an integer
    0-232, ``ROS_AUTOMATIC_DISCOVERY_RANGE`` one of SUBNET, LOCALHOST, OFF, SYSTEM_DEFAULT,
    ``ROS_STATIC_PEERS`` a ``;``-separated list of hosts (names or IP addresses).
    """
    if '\0' in value:
        return 'a value cannot hold a NUL character'
    if name == 'ROS_DOMAIN_ID':
        if not re.fullmatch(r'[0-9]{1,3}', value) or int(value) > MAX_DOMAIN_ID:
            return (f'expected an integer from 0 to {MAX_DOMAIN_ID} (Fast-DDS maps the domain '
                    f'to UDP ports; higher ones do not fit), got {_show(value)}')
    elif name == 'ROS_AUTOMATIC_DISCOVERY_RANGE':
        if value not in DISCOVERY_RANGES:
            return (f'expected one of {", ".join(DISCOVERY_RANGES)}'
                    f'{did_you_mean(value.upper(), DISCOVERY_RANGES)}, got {_show(value)}')
    elif name == 'ROS_STATIC_PEERS' and value:
        for peer in value.split(';'):
            if not _is_host(peer.strip()):
                return (f'expected hosts (names or IP addresses) separated by ";", got '
                        f'{_show(peer)} in {_show(value)}')
    return None


def _is_host(text: str) -> bool:
    """Whether ``text`` is an IPv4/IPv6 address or a DNS host name (RFC 1123)."""
    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        pass
    labels = text[:-1].split('.') if text.endswith('.') else text.split('.')
    return 0 < len(text) <= 253 and all(_HOST_LABEL.match(label) for label in labels)


def topic_name_problem(name: Any, *, remap: bool = False) -> str | None:
    """Why ``name`` is not a valid ROS 2 topic name (``remap``: in a remap rule), or None.

    rclpy's own checks (``validate_topic_name``, then ``validate_full_topic_name`` of the
    name expanded for a node ``/n``), and for a remap rule what rcl's remap lexer refuses on
    top: substitutions (``{node}``), a reserved ``__`` and a ``~`` not followed by ``/``.
    """
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name
    from rclpy.validate_topic_name import validate_topic_name

    if not isinstance(name, str):
        return f'expected a string, got {_kind(name)}'
    try:
        validate_topic_name(name)
        validate_full_topic_name(expand_topic_name(name, 'n', '/'))
    except Exception as err:  # noqa: BLE001 - rclpy raises several types, each with a reason
        return _rclpy_reason(err)
    if remap:
        if '{' in name or '}' in name:
            return 'a remap rule takes no substitutions ({...})'
        if '__' in name:
            return '"__" is reserved in a remap rule'
        if name.startswith('~') and not name.startswith('~/'):
            return 'a remap rule takes "~" only as "~/"'
    return None


def _rclpy_reason(err: Exception) -> str:
    """Return rclpy's reason without its restatement of the name and its caret line."""
    text = str(err).split('\n')[0].strip().rstrip(':').removeprefix('Invalid topic name:')
    return re.sub(r"^topic name '.*' is invalid: ", '', text.strip())


def _expect_mapping(value: Any, where: str, key: str) -> None:
    if not isinstance(value, dict):
        raise ProfileError(f'expected a mapping, got {_kind(value)}', path=where, key=key)


def _expect_number(d: dict[str, Any], k: str, where: str, key: str, *, high: float,
                   integer: bool = False, positive: bool = False) -> None:
    """Refuse ``d[k]`` unless a finite number in ``[0, high]`` (``(0, high]``: positive)."""
    if k not in d:
        return
    v = d[k]
    ok = isinstance(v, int) if integer else isinstance(v, (int, float))
    # The comparisons refuse NaN (every one is false) and do not overflow on a huge integer.
    if isinstance(v, bool) or not ok or not 0 <= v <= high or (positive and v == 0):
        what = 'an integer' if integer else 'a number'
        low = '0 <' if positive else '0 <='
        raise ProfileError(f'expected {what} with {low} value <= {high:.0f}, got {_show(v)}',
                           path=where, key=f'{key}.{k}')


def _kind(v: Any) -> str:
    return {dict: 'a mapping', list: 'a list', str: 'a string', type(None): 'nothing'}.get(
        type(v), f'{type(v).__name__} {_show(v)}')


def _flatten_parameters(params: Any, where: str, key: str) -> dict[str, Any]:
    """Nested mappings -> dotted ROS parameter names; check every value has a ROS type."""
    if params is None:
        return {}
    _expect_mapping(params, where, key)
    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f'{prefix}.{k}' if prefix else str(k), v)
            return
        flat[prefix] = _parameter_value(value, where, f'{key}.{prefix}')

    walk('', params)
    return flat


def _parameter_value(v: Any, where: str, key: str) -> Any:
    if isinstance(v, (bool, int, float, str)):
        _check_parameter_number(v, where, key)
        return v
    if isinstance(v, list):
        if not v:
            raise ProfileError('an empty list has no ROS parameter type; leave the parameter '
                               'out to keep its default', path=where, key=key)
        if all(isinstance(x, bool) for x in v) or all(isinstance(x, str) for x in v):
            return list(v)
        if all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
            for i, x in enumerate(v):
                _check_parameter_number(x, where, key, f'[{i}]')
            return list(v) if all(isinstance(x, int) for x in v) else [float(x) for x in v]
        raise ProfileError('a list parameter holds values of one type (numbers, strings or '
                           f'booleans), got {_show(v)}', path=where, key=key)
    raise ProfileError(f'expected a number, string, boolean or list of them, got {_kind(v)}',
                       path=where, key=key)


def _check_parameter_number(v: Any, where: str, key: str, index: str = '') -> None:
    """Refuse a parameter number that is not finite or does not fit a ROS (64-bit) integer.

    Its range is the node's to check (``ParamSpec``); these two no node could be given.
    """
    at = f'element {index}: ' if index else ''
    if isinstance(v, float) and not math.isfinite(v):
        raise ProfileError(f'{at}expected a finite number, got {v}', path=where, key=key)
    if isinstance(v, int) and not isinstance(v, bool) and not INT64[0] <= v <= INT64[1]:
        raise ProfileError(f'{at}{_show(v)} does not fit a 64-bit ROS integer', path=where,
                           key=key)


def _deep_merge(dst: dict[str, Any], src: dict[str, Any], prefix: str,
                origins: dict[str, str], where: str) -> None:
    for k, v in src.items():
        path = f'{prefix}.{k}' if prefix else str(k)
        if isinstance(v, dict) and isinstance(dst.get(k), dict):
            _deep_merge(dst[k], v, path, origins, where)
        else:
            dst[k] = _copy(v)
            if where:
                _record_origins(origins, path, v, where)


def _record_origins(origins: dict[str, str], path: str, v: Any, where: str) -> None:
    origins[path] = where
    if isinstance(v, dict):
        for k, sub in v.items():
            _record_origins(origins, f'{path}.{k}', sub, where)


def _copy(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _copy(x) for k, x in v.items()}
    if isinstance(v, list):
        return list(v)
    return v


def _apply_set(merged: dict[str, Any], item: str, origins: dict[str, str]) -> None:
    """``node.param=value`` (value parsed as YAML) into the merged profile."""
    if len(item) > MAX_SCALAR:
        raise ProfileError(f'--set {_show(item)}: longer than {MAX_SCALAR} characters')
    target, sep, text = item.partition('=')
    node, dot, param = target.partition('.')
    if not sep or not dot or not node or not param:
        raise ProfileError(f'--set {_show(item)}: expected NODE.PARAM=VALUE, e.g. '
                           'velocity_control.kp=[1.0,1.0,1.0,1.0,1.0,1.0]')
    nodes = merged.get('nodes') or {}
    if node not in nodes:
        raise ProfileError(f'--set {_show(item)}: no node {_show(node)}; nodes: '
                           f'{", ".join(sorted(nodes))}')
    try:
        value = _safe_load(text)
    except _Refused as err:
        raise ProfileError(f'--set {_show(item)}: value {err}') from None
    except RecursionError:
        raise ProfileError(f'--set {_show(item)}: value nested deeper than {MAX_DEPTH} '
                           'levels') from None
    except yaml.YAMLError as err:
        mark = getattr(err, 'problem_mark', None)
        at = f' at column {mark.column + 1}' if mark else ''
        problem = getattr(err, 'problem', None) or str(err).replace('\n', ' ')
        raise ProfileError(f'--set {_show(item)}: value is not valid YAML{at}: '
                           f'{_cut(problem)}') from err
    value = _parameter_value(value, '--set', f'{node}.{param}')
    nodes[node].setdefault('parameters', {})[param] = value
    origins[f'nodes.{node}.parameters.{param}'] = '--set'


def _build(merged: dict[str, Any], path: str, origins: dict[str, str],
           files: tuple[str, ...]) -> Profile:
    common = merged.get('parameters') or {}
    nodes_raw = merged.get('nodes') or {}
    try:
        known = registry.entries()
    except RegistryError as err:
        raise ProfileError(str(err), path=path) from err
    nodes: list[NodeSpec] = []
    for name, n in nodes_raw.items():
        if not n.get('enabled', True):
            continue
        key = f'nodes.{name}.plugin'
        where = _origin(origins, key, path)
        plugin = n.get('plugin')
        if not plugin:
            # Most often a typo in the name of a node an included file declares (dp_contrl
            # for dp_control): that file's nodes come first, the plugin list after.
            declared = [m for m, spec in nodes_raw.items() if m != name and spec.get('plugin')]
            hint = did_you_mean(name, declared, 'the node ')
            raise ProfileError(f'no plugin{hint}; a new node needs one (a registered node '
                               f'name, enbarr list nodes): {", ".join(sorted(known))}',
                               path=_origin(origins, f'nodes.{name}', path),
                               key=f'nodes.{name}' if hint else key)
        if plugin not in known:
            try:
                registry.resolve(plugin)
            except RegistryError as err:
                raise ProfileError(str(err), path=where, key=key) from None
        nodes.append(NodeSpec(
            name=name, plugin=plugin, namespace=n.get('namespace', ''),
            remappings=tuple((n.get('remappings') or {}).items()),
            parameters=dict(n.get('parameters') or {}),
            group=n.get('group', DEFAULT_GROUP), origin=where))
    if not nodes:
        raise ProfileError('the profile runs no nodes', path=path, key='nodes')
    seen: dict[tuple[str, str], str] = {}
    for n in nodes:
        fq = (n.namespace.strip('/'), n.name)
        if fq in seen:
            raise ProfileError(f'two nodes named {n.name!r} in namespace {n.namespace!r}',
                               path=path, key=f'nodes.{n.name}')
        seen[fq] = n.name
    groups_raw = merged.get('groups') or {}
    used = {n.group for n in nodes}
    for g in groups_raw:
        if g not in used:
            raise ProfileError(f'group {g!r} has no nodes; groups in use: '
                               f'{", ".join(sorted(used))}', path=_origin(
                                   origins, f'groups.{g}', path), key=f'groups.{g}')
    groups = {g: GroupSpec(name=g, **(groups_raw.get(g) or {})) for g in sorted(used)}
    record = None
    if merged.get('record'):
        r = merged['record']
        if 'path' not in r:
            raise ProfileError('expected a directory path', path=_origin(
                origins, 'record', path), key='record.path')
        record = RecordSpec(path=r['path'], topics=tuple(r.get('topics', ())),
                            flush_seconds=float(r.get('flush_seconds', 1.0)),
                            split_size=float(r.get('split_size', 0.0)),
                            split_seconds=float(r.get('split_seconds', 0.0)),
                            skip_raw_images=r.get('skip_raw_images', True))
    return Profile(
        name=merged.get('profile') or Path(path).stem, path=path,
        description=merged.get('description', ''),
        environment={k: v for k, v in (merged.get('environment') or {}).items()
                     if v is not None},
        parameters=dict(common),
        nodes=tuple(nodes), groups=groups,
        record=record, files=files, origins=dict(origins),
        scenario=merged.get('scenario'),
        frames=parse_frames(merged.get('frames'), lambda key: _origin(origins, key, path)),
        world=parse_world(merged.get('world'), lambda key: _origin(origins, key, path)))


def _origin(origins: Mapping[str, str], key: str, default: str) -> str:
    """Return the file that set ``key`` or the nearest enclosing key (the last to set it)."""
    best = default
    for k, origin in origins.items():
        if key == k or key.startswith(k + '.'):
            best = origin
    return best


def with_record(profile: Profile, path: str, topics: Sequence[str] = (),
                split_size: float | None = None, split_seconds: float | None = None,
                origin: str = '--output') -> Profile:
    """Return the profile with recording to ``path`` switched on (``--output``).

    ``split_size`` [MB] and ``split_seconds`` (``--record-split-size / -seconds``) override
    the profile's; the rest of its ``record`` section is kept. ``origin`` is what an error
    about the recording names (``profile.where('record.path')``).
    """
    for t in topics:
        reason = topic_name_problem(t)
        if reason:
            raise ProfileError(f'--record-topic {_show(t)}: not a valid topic name: {reason}')
    for option, v, high in (('--record-split-size', split_size, MAX_SPLIT_SIZE_MB),
                            ('--record-split-seconds', split_seconds, MAX_SPLIT_S)):
        if v is not None and not (math.isfinite(v) and 0 <= v <= high):
            raise ProfileError(f'{option} must be a number from 0 (no split) to {high:.0f}, '
                               f'got {v}')
    old = profile.record or RecordSpec(path=path)
    return replace(profile, record=replace(
        old, path=path, topics=tuple(topics) or old.topics,
        split_size=old.split_size if split_size is None else split_size,
        split_seconds=old.split_seconds if split_seconds is None else split_seconds),
        origins={**profile.origins, 'record.path': origin})


def select_groups(profile: Profile, only: Sequence[str] = (),
                  skip: Sequence[str] = ()) -> Profile:
    """Return the profile with the nodes of ``only``'s groups (all when empty), less ``skip``'s.

    ``--only-group`` / ``--skip-group`` of bringup: one profile split between two computers
    (the vessel runs every group but ``operator``, the operator computer only ``operator``),
    as if the other groups' nodes were dropped with ``enabled: false``. A name that is no
    group of the profile is refused with the list of its groups.
    """
    names = profile.group_names()
    for option, given in (('--only-group', only), ('--skip-group', skip)):
        for g in given:
            if g not in names:
                raise ProfileError(f'{option} {_show(g)}: no such group; the groups of the '
                                   f'profile are {", ".join(names)}{did_you_mean(g, names)}',
                                   path=profile.path)
    keep = [n for n in profile.nodes
            if (not only or n.group in only) and n.group not in skip]
    if not keep:
        raise ProfileError(f'no group left to run (groups: {", ".join(names)})',
                           path=profile.path)
    kept = {n.group for n in keep}
    return replace(profile, nodes=tuple(keep), partial=kept != set(names),
                   groups={g: spec for g, spec in profile.groups.items() if g in kept})


def apply_environment(profile: Profile, environ: Any = os.environ) -> None:
    """Set the profile's ``environment`` before ROS starts (overrides what is set)."""
    for k, v in profile.environment.items():
        environ[k] = v


# -- listing ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProfileSummary:
    """What ``enbarr list`` shows of one profile file: its own keys, nothing merged."""

    name: str          # the bare name (the file's stem)
    path: Path
    description: str   # '' when it has none; the reason when it cannot be read
    fragment: bool     # include-only
    readable: bool = True


def summarize(path: Path) -> ProfileSummary:
    """Read ``path``'s own ``description`` and ``fragment`` (no include, no validation)."""
    try:
        raw = _read_yaml(path)
    except ProfileError as err:
        return ProfileSummary(path.stem, path, f'unreadable: {err}', False, readable=False)
    description = raw.get('description')
    return ProfileSummary(path.stem, path, description if isinstance(description, str) else '',
                          raw.get('fragment') is True)


def installed_profiles(subdir: str = '') -> list[ProfileSummary]:
    """Summarize the profiles (``subdir='scenarios'``: the scenarios) that bare names find.

    Sorted by name; a name in several search directories is the first one's (as
    ``resolve_profile`` finds it).
    """
    found: dict[str, ProfileSummary] = {}
    for d in search_dirs():
        for f in sorted((d / subdir).glob('*.yaml')):
            if f.stem not in found:
                found[f.stem] = summarize(f)
    return [found[name] for name in sorted(found)]
