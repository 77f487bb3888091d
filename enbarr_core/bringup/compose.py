"""Composition: a profile's nodes built in one process, on one executor, always taken down.

All nodes of a process group are built in this process on one executor (rclpy's
``EventsExecutor``, ``make_executor``) and share one link bus, so the IMU -> thruster chain
runs as direct calls (``docs/architecture.md``). Leaving ``composed`` runs the one exit path of
every run (``shutdown_nodes``): stop the sources, ``safe_state()`` on every node (thrusters
neutral, while the graph can still carry that), close recorders, destroy the nodes, shut the
context down.

Constructing a node opens nothing and publishes nothing (devices open in ``start()``), so
``validate`` builds every node of a profile to check its parameters in a context whose DDS
participant discovers nothing and is discovered by nobody (``isolated_context``): a check run
beside a vessel cannot disturb it, and a check of a real-hardware profile touches no device.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
import difflib
import logging
import os
import sys
import time
from typing import Any

from rcl_interfaces.srv import ListParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import Executor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from enbarr_interfaces.links import LinkBus

from enbarr_core.framework import registry
from enbarr_core.framework.driver import DeviceNode
from enbarr_core.framework.errors import EnbarrError, ProfileError
from enbarr_core.framework.node import EnbarrNode, install_frame_tree, install_world
from enbarr_core.framework.threads import name_os_threads
from enbarr_core.bringup.guard import DuplicateVesselError, VesselGuard
from enbarr_core.bringup.profile import GroupSpec, NodeSpec, Profile, RecordSpec
from enbarr_core.recording.recorder import Recorder

log = logging.getLogger('enbarr.bringup')
RECORDER_NODE = 'recorder'
_RCLPY_PARAMETERS = ('use_sim_time', 'start_type_description_service')
RECORDER_GROUP = 'recorder'


def add_recorder(profile: Profile) -> Profile:
    """Return the profile with a recorder node for its ``record`` section.

    The recorder runs in its own group when the profile is split into several.
    """
    if profile.record is None or any(n.name == RECORDER_NODE for n in profile.nodes):
        return profile
    r: RecordSpec = profile.record
    params: dict[str, Any] = {'path': os.path.abspath(r.path),
                              'flush_seconds': r.flush_seconds, 'split_size': r.split_size,
                              'split_seconds': r.split_seconds,
                              'skip_raw_images': r.skip_raw_images}
    if r.topics:
        params['topics'] = list(r.topics)
    group = RECORDER_GROUP if len(profile.group_names()) > 1 else profile.nodes[0].group
    node = NodeSpec(name=RECORDER_NODE, plugin='recorder', parameters=params, group=group,
                    origin=profile.where('record.path'))
    groups = dict(profile.groups)
    groups.setdefault(group, GroupSpec(group))
    return replace(profile, nodes=(*profile.nodes, node), groups=groups)


def build_nodes(profile: Profile, context: Context,
                group: str | None = None) -> list[Node]:
    """Construct the nodes of ``group`` (all when None); check their profile parameters.

    Every parameter a profile sets must be one that its node declares. On error, destroys
    what it built and raises ``ProfileError``.
    """
    nodes: list[Node] = []
    specs = [s for s in profile.nodes if group is None or s.group == group]
    # Device emulators first: they are started in this order too, and a driver opens its
    # device at start, so an emulated device is "plugged in" (enbarr_plugins.emulation)
    # before its driver looks. They are destroyed last, so they still take the drivers'
    # neutral commands.
    specs.sort(key=lambda s: not _is_emulator(s.plugin))
    try:
        for spec in specs:
            nodes.append(_construct(profile, spec, context))
        _check_parameters(profile, nodes, group)
    except BaseException:
        for n in reversed(nodes):
            _safely(n.destroy_node, f'destroying {n.get_name()}')
        raise
    return nodes


def _is_emulator(plugin: str) -> bool:
    """Whether ``plugin`` is a device emulator (its class sets ``device_emulator = True``)."""
    try:
        return bool(getattr(registry.resolve(plugin), 'device_emulator', False))
    except EnbarrError:
        return False  # _construct reports the unknown plugin, in profile order


def _construct(profile: Profile, spec: NodeSpec, context: Context) -> Node:
    cls = registry.resolve(spec.plugin)
    # No type description service unless a profile asks: every service is one more entity
    # that the executor walks at each wake-up, and the types here are all standard ones.
    values = {'start_type_description_service': False, **profile.parameters, **spec.parameters}
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    cli_args = ['--ros-args']
    for src, dst in spec.remappings:
        cli_args += ['-r', f'{src}:={dst}']
    where, key = spec.origin or profile.path, f'nodes.{spec.name}'
    try:
        return cls(node_name=spec.name, namespace=spec.namespace, context=context,
                   parameter_overrides=overrides, cli_args=cli_args,
                   use_global_arguments=False)
    except EnbarrError as err:
        where, key = blame(profile, spec, getattr(err, 'parameter', None))
        raise ProfileError(str(err), path=where, key=key) from err
    except (ValueError, TypeError) as err:  # rclpy refusing a name, a remap, a value
        raise ProfileError(f'{spec.plugin}: {err}', path=where,
                           key=f'nodes.{spec.name}') from err


def blame(profile: Profile, spec: NodeSpec, parameter: str | None) -> tuple[str, str]:
    """Return where (file or '--set') and which key a node's refused configuration came from.

    A node names the parameter at fault, as a full name, a prefix ('azimuths') or a member
    field ('angle_max'); often a check of several values together names just one of them.
    So: the latest source (the user's file after its includes, ``--set`` last) among the
    values the node was given that match the parameter; and when a later source gave the
    node any other value, that one, since it is what changed the combination. Without a
    matching value: the file that named the plugin, unless a later source gave values.
    """
    keys = [(f'nodes.{spec.name}.parameters.{k}', k) for k in spec.parameters]
    keys += [(f'parameters.{k}', k) for k in profile.parameters if k not in spec.parameters]
    rank = {f: i for i, f in enumerate(profile.files)}
    rank['--set'] = len(profile.files)
    rank.setdefault(spec.origin, len(profile.files) + 1)  # a node no file named: '--output'
    from_files = f'nodes.{spec.name}' in profile.origins

    def where(k: str) -> str:
        own = k.startswith(f'nodes.{spec.name}.')
        return profile.where(k) if from_files or not own else spec.origin

    def source(k: str) -> tuple[int, str]:
        origin = where(k)
        return rank.get(origin, -1), origin

    def matches(name: str) -> bool:
        return parameter is not None and (
            name == parameter or name.startswith(parameter + '.')
            or name.endswith('.' + parameter))

    matching = [k for k, name in keys if matches(name)]
    best = max(matching, key=lambda k: source(k)[0], default=None)
    floor = source(best)[0] if best is not None else rank.get(spec.origin, -1)
    later = [k for k, _ in keys if source(k)[0] > floor]
    if later:
        top = max(source(k)[0] for k in later)
        best = next(k for k in later if source(k)[0] == top)
    if best is None:
        return spec.origin or profile.path, f'nodes.{spec.name}'
    return where(best), best


def _check_parameters(profile: Profile, nodes: list[Node], group: str | None) -> None:
    by_name = {n.get_name(): n for n in nodes}
    for spec in profile.nodes:
        node = by_name.get(spec.name)
        if node is None:
            continue
        declared = sorted(p for p in declared_parameters(node) if p not in _RCLPY_PARAMETERS)
        for name in spec.parameters:
            if not node.has_parameter(name):
                key = f'nodes.{spec.name}.parameters.{name}'
                close = difflib.get_close_matches(name, declared, n=1)
                hint = f' (did you mean {close[0]!r}?)' if close else ''
                raise ProfileError(
                    f'node {spec.name!r} ({spec.plugin}) has no parameter {name!r}{hint}; '
                    f'it has: {", ".join(declared)}',
                    path=profile.where(key), key=key)
    if group is None and not profile.partial:  # a part may leave a common one to the rest
        for name in profile.parameters:
            if not any(n.has_parameter(name) for n in nodes):
                key = f'parameters.{name}'
                raise ProfileError(f'no node declares the common parameter {name!r}',
                                   path=profile.where(key), key=key)


def declared_parameters(node: Node) -> list[str]:
    """Name every parameter ``node`` declared, as ``ros2 param list`` does."""
    return list(node.list_parameters([], ListParameters.Request.DEPTH_RECURSIVE).names)


#: How long a process keeps its publishers after publishing the safe state [s].
SAFE_STATE_LINGER = 0.1


def shutdown_nodes(nodes: Sequence[Node]) -> None:
    """Take nodes down: stop sources, safe state, then destroy (emulators, recorders last).

    The one exit path of every run: recorders (``Recorder``) go after the other nodes so
    that the bag holds their safe state, and device emulators after the drivers, which may
    still write their neutral bytes while closing.
    """
    for n in nodes:
        if isinstance(n, EnbarrNode):
            _safely(n.stop, f'stopping {n.get_name()}')
    for n in nodes:
        if isinstance(n, EnbarrNode):
            _safely(n.safe_state, f'safe state of {n.get_name()}')
    recorders = [n for n in nodes if isinstance(n, Recorder)]
    if len(recorders) < len(nodes):
        # The safe state was published to other processes too (a recorder group, a thruster
        # process): give DDS a moment to send it before the publishers are destroyed, without
        # spinning (no command may be taken after the safe state).
        time.sleep(SAFE_STATE_LINGER)
    emulators = [n for n in nodes if getattr(n, 'device_emulator', False)]
    for n in [*(n for n in nodes if n not in recorders and n not in emulators), *emulators,
              *recorders]:
        _safely(n.destroy_node, f'destroying {n.get_name()}')


def _safely(fn: Callable[[], Any], what: str) -> None:
    try:
        fn()
    except Exception as err:  # noqa: BLE001 - the remaining shutdown steps must still run
        log.error('%s failed: %r', what, err)


#: How long a Python thread may hold the GIL while another waits [s] (CPython default 5 ms).
#: The chain thread wakes 400 times a second and must not wait behind a busy recorder or
#: executor thread for a whole default interval: that alone would break the 2 ms latency goal.
GIL_SWITCH_INTERVAL = 0.0005


def configure_process() -> None:
    """Process-wide settings for running nodes (bringup and the benchmark both call it).

    Threads carry their names in the OS from here on (``top -H``, py-spy, ``enbarr bench``).
    """
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)
    name_os_threads()


def make_executor(context: Context) -> Executor:
    """Return the executor of a composed process: rclpy's ``EventsExecutor``.

    The ``SingleThreadedExecutor`` rebuilds its wait set in Python at every wake-up, walking
    every entity of every node (parameter services, timers, subscriptions), so an idle
    composed process spends most of its CPU there; the ``EventsExecutor`` queues events from
    the middleware in C++ (the figures: ``docs/benchmarks.md``, the Raspberry Pi budget). Its
    ``spin()`` cannot be stopped cleanly, so it is driven with ``spin_once`` like the other.
    """
    return EventsExecutor(context=context)


@dataclass(frozen=True)
class Composition:
    """The nodes of one process, on one executor, their link bus connected."""

    context: Context
    executor: Executor
    nodes: list[Node]
    #: The vessel guard of a run (``composed(guard=True)``), None for scenarios and benchmarks.
    guard: VesselGuard | None = None

    def node(self, name: str) -> Node:
        """Return the node called ``name``."""
        return next(n for n in self.nodes if n.get_name() == name)

    def start(self, *, skip: Sequence[Node] = ()) -> None:
        """Start every node's sources (those in ``skip`` are driven by the caller).

        In build order: device emulators first, so that a driver opening its device at start
        finds it plugged in.
        """
        for n in self.nodes:
            if isinstance(n, EnbarrNode) and n not in skip:
                n.start()


def node_names(profile: Profile, group: str | None = None) -> list[str]:
    """Return the fully qualified names of ``group``'s nodes (all when None), unbuilt.

    As rclpy forms them: the namespace made absolute, then the name.
    """
    names = []
    for spec in profile.nodes:
        if group is None or spec.group == group:
            ns = '/' + (spec.namespace or '').strip('/')
            names.append(f'{ns.rstrip("/")}/{spec.name}')
    return sorted(names)


@contextmanager
def composed(profile: Profile, group: str | None = None, *, guard: bool = False,
             executor: Callable[[Context], Executor] = make_executor,
             world_epoch_ns: int | None = None) -> Iterator[Composition]:
    """Build the nodes of ``group`` (all when None) in a fresh context; always take them down.

    ``guard``: before any node exists, watch the graph for another run with the same node
    names (``VesselGuard``) and refuse to build if there is one: a refused process must not
    create a publisher on a running vessel's topics (a second joystick publisher alone makes
    the running controller refuse its joystick as contested). On leaving: ``shutdown_nodes``
    (safe state first), or, when refused before anything started, just destroy them. bringup,
    the benchmark and scenarios all use it.

    ``world_epoch_ns``: the clock time [ns] at which the profile's world time is 0 (a
    scenario: its simulated start); None: now, as the nodes' ROS clock reads it.
    """
    configure_process()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    spinner = executor(context)
    nodes: list[Node] = []
    vessel_guard: VesselGuard | None = None
    quiet = False
    install_frame_tree(context, profile.frames)  # EnbarrNode.frame_tree, in every group
    install_world(context, profile.world,
                  time.time_ns() if world_epoch_ns is None else world_epoch_ns)
    try:
        if guard:
            vessel_guard = VesselGuard(context, node_names(profile, group))
            # On the executor from the start: claims that arrive while it watches wait for
            # the first spin instead of being missed.
            spinner.add_node(vessel_guard.node)
            vessel_guard.check_start()
        nodes.extend(build_nodes(profile, context, group))
        if vessel_guard is not None:
            vessel_guard.check_built(nodes)
        for n in nodes:
            spinner.add_node(n)
        LinkBus.of(context).connect()
        yield Composition(context, spinner, nodes, vessel_guard)
    except DuplicateVesselError as err:
        quiet = not err.started  # never publish into another vessel's graph
        raise
    finally:
        if quiet:  # nothing ran: no safe state to publish, nothing to record
            for n in reversed(nodes):
                _safely(n.destroy_node, f'destroying {n.get_name()}')
        else:
            shutdown_nodes(nodes)
        if vessel_guard is not None:
            _safely(vessel_guard.destroy, 'destroying the vessel guard')
        spinner.shutdown()
        rclpy.try_shutdown(context=context)


#: What a check takes out of the environment while its context starts: every way of naming a
#: peer or a discovery server to Fast-DDS (a profile's XML could list initial peers).
_DISCOVERY_VARIABLES = ('ROS_STATIC_PEERS', 'ROS_DISCOVERY_SERVER', 'ROS_SUPER_CLIENT',
                        'FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                        'RMW_FASTRTPS_USE_QOS_FROM_XML')


@contextmanager
def isolated_context() -> Iterator[Context]:
    """Give an rclpy context whose DDS participant discovers nobody and nobody discovers.

    ``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF`` (REP-2020's range, read by rmw when the context
    starts) with no static peers: nothing it creates is seen on the vessel's graph, on this
    machine or beyond, whatever discovery range the profile asks for. The environment is
    restored at once: a supervisor's children still get the profile's.
    """
    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                            *_DISCOVERY_VARIABLES)}
    context = Context()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    for k in _DISCOVERY_VARIABLES:
        os.environ.pop(k, None)
    try:
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@dataclass(frozen=True)
class Validation:
    """What ``validate`` checked, and the devices it did not open."""

    nodes: int
    groups: int
    #: (node name, its device), for every driver whose device a check leaves alone.
    devices: tuple[tuple[str, str], ...]


def validate(profile: Profile, group: str | None = None) -> Validation:
    """Build every node of ``group`` (all when None) to check the profile; start nothing.

    Raises ``ProfileError`` naming file and key. Opens no device and no socket (constructors
    open nothing), publishes nothing (constructors publish nothing) and is invisible to every
    other participant (``isolated_context``).
    """
    with isolated_context() as context:
        install_frame_tree(context, profile.frames)
        install_world(context, profile.world)
        nodes = build_nodes(profile, context, group)
        try:
            devices = tuple((n.get_name(), n.device) for n in nodes
                            if isinstance(n, DeviceNode) and n.device != 'simulated'
                            and not getattr(n, 'device_emulator', False))
        finally:
            for n in reversed(nodes):
                _safely(n.destroy_node, f'destroying {n.get_name()}')
    groups = {s.group for s in profile.nodes if group is None or s.group == group}
    return Validation(len(nodes), len(groups), devices)
