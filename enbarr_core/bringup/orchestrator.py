"""The orchestrator: builds a profile's nodes, runs them, and always leaves thrusters neutral.

One process group (the default, every node in ``main``): all nodes are built in this process
on one executor (rclpy's ``EventsExecutor``, ``make_executor``) and share one link bus, so
the IMU -> thruster chain runs as direct calls (``docs/architecture.md``). Several groups:
this process becomes a supervisor that first builds every node once to validate the profile,
then runs each group as a child process (``enbarr bringup --group NAME``), reports a group
that dies, restarts it up to the group's ``restart_limit``, and stops them all with SIGINT
(SIGKILL after a grace period).

Every exit path of a group (SIGINT, SIGTERM, the end of ``--duration``, an exception) runs the
same ``finally``: stop the sources, ``safe_state()`` on every node (thrusters neutral, while
the graph can still carry that), close recorders, destroy the nodes, shut the context down. A
group that is killed outright cannot do that: then the thruster plugin's own command timeout
(a separate process) or, for a crashed thruster process, the restart (plugins start neutral)
and the device's watchdog take over.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
import difflib
import json
import logging
import os
from pathlib import Path
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from typing import Any

from rcl_interfaces.srv import ListParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String

from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus

from enbarr_core.framework import registry
from enbarr_core.framework.errors import EnbarrError, ProfileError
from enbarr_core.framework.node import EnbarrNode, install_frame_tree
from enbarr_core.framework.threads import name_os_threads
from enbarr_core.bringup.profile import GroupSpec, NodeSpec, Profile, RecordSpec
from enbarr_core.recording.recorder import Recorder

log = logging.getLogger('enbarr.bringup')
RECORDER_NODE = 'recorder'
_RCLPY_PARAMETERS = ('use_sim_time', 'start_type_description_service')
RECORDER_GROUP = 'recorder'
GRACE_SECONDS = 10.0


def add_recorder(profile: Profile) -> Profile:
    """Return the profile with a recorder node for its ``record`` section.

    The recorder runs in its own group when the profile is split into several.
    """
    if profile.record is None or any(n.name == RECORDER_NODE for n in profile.nodes):
        return profile
    r: RecordSpec = profile.record
    params: dict[str, Any] = {'path': os.path.abspath(r.path),
                              'flush_seconds': r.flush_seconds, 'split_size': r.split_size,
                              'split_seconds': r.split_seconds}
    if r.topics:
        params['topics'] = list(r.topics)
    group = RECORDER_GROUP if len(profile.group_names()) > 1 else profile.nodes[0].group
    node = NodeSpec(name=RECORDER_NODE, plugin='recorder', parameters=params, group=group,
                    origin='--record')
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
    # Device emulators first: a driver opens its device in its constructor, and an emulated
    # device is "plugged in" when its emulator node registers it (enbarr_plugins.emulation).
    # They are destroyed last, so they still take the drivers' neutral commands.
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
    rank.setdefault(spec.origin, len(profile.files) + 1)  # a node no file named: '--record'
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
    if group is None:
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


class _Stop:
    """SIGINT/SIGTERM set a flag that the spin loop and every wait of the supervisor check.

    rclpy's own handlers are off so that the context still works while thrusters are put in
    their safe state. ``count`` counts the requests: a second one while children are being
    stopped ends their grace period.
    """

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None
        self.count = 0
        self._old: dict[int, Any] = {}
        self._outer: _Stop | None = None

    #: The stop of the run in progress in this process, if any (``VesselGuard`` waits on it).
    active: _Stop | None = None

    def __enter__(self) -> _Stop:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        self._outer, _Stop.active = _Stop.active, self
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        self.signal = signum
        self.count += 1

    def sleep(self, seconds: float) -> bool:
        """Sleep ``seconds`` or until a stop is requested; True when one was."""
        deadline = time.monotonic() + seconds
        while not self.requested:
            left = deadline - time.monotonic()
            if left <= 0.0:
                break
            time.sleep(min(left, STOP_POLL))
        return self.requested

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        _Stop.active = self._outer


#: The longest slice of any wait of the supervisor [s]: a stop request is served within it.
STOP_POLL = 0.1


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
    every entity of every node (parameter services, timers, subscriptions): measured on
    ``saucer_sim`` composed with nothing started, 20.6 % of a core against 2.7 % for the
    ``EventsExecutor``, which queues events from the middleware in C++. Its ``spin()`` cannot
    be stopped cleanly, so it is driven with ``spin_once`` like the other.
    """
    return EventsExecutor(context=context)


@dataclass(frozen=True)
class Composition:
    """The nodes of one process, on one executor, their link bus connected."""

    context: Context
    executor: Executor
    nodes: list[Node]

    def node(self, name: str) -> Node:
        """Return the node called ``name``."""
        return next(n for n in self.nodes if n.get_name() == name)

    def start(self, *, skip: Sequence[Node] = ()) -> None:
        """Start every node's sources (those in ``skip`` are driven by the caller)."""
        for n in self.nodes:
            if isinstance(n, EnbarrNode) and n not in skip:
                n.start()


@contextmanager
def composed(profile: Profile, group: str | None = None, *, check_only: bool = False,
             executor: Callable[[Context], Executor] = make_executor,
             ) -> Iterator[Composition]:
    """Build the nodes of ``group`` (all when None) in a fresh context; always take them down.

    On leaving: ``shutdown_nodes`` (safe state first), or, when nothing was started
    (``check_only``), just destroy them. bringup, the benchmark and scenarios all use it.
    """
    configure_process()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    spinner = executor(context)
    nodes: list[Node] = []
    quiet = check_only
    install_frame_tree(context, profile.frames)  # EnbarrNode.frame_tree, in every group
    try:
        nodes.extend(build_nodes(profile, context, group))
        if not check_only:
            for n in nodes:
                spinner.add_node(n)
            LinkBus.of(context).connect()
        yield Composition(context, spinner, nodes)
    except DuplicateVesselError as err:
        quiet = quiet or not err.started  # never publish into another vessel's graph
        raise
    finally:
        if quiet:  # nothing ran: no safe state to publish, nothing to record
            for n in reversed(nodes):
                _safely(n.destroy_node, f'destroying {n.get_name()}')
        else:
            shutdown_nodes(nodes)
        spinner.shutdown()
        rclpy.try_shutdown(context=context)


# -- one vessel per set of node names on a graph ---------------------------------------------
#: How long a group watches the graph for a namesake before it starts its sources [s].
#: Discovery between two processes here takes 0.2 s or 2.5 s (bimodal); a later discovery
#: is still caught by the claims (``VesselGuard``), at the cost of a late stop.
DISCOVERY_WAIT = 3.0
#: Where every running group announces its node names and when it started (std_msgs/String,
#: JSON). Latched: a process that joins later still gets every claim.
CLAIM_TOPIC = topics.VESSEL_CLAIMS.name
CLAIM_QOS = topics.VESSEL_CLAIMS.qos
MAX_CLAIM_BYTES = 1 << 16


class DuplicateVesselError(EnbarrError):
    """Another process on this ROS graph runs nodes with the same fully qualified names.

    ``started``: False when refused before any source started (nothing may be published then,
    not even a safe state: the topics are the other vessel's too).
    """

    def __init__(self, message: str, *, started: bool) -> None:
        self.started = started
        super().__init__(message)


class VesselGuard:
    """Refuse a second process that runs a profile's nodes on the same graph.

    Two runs of one profile in one domain would drive each other's thrusters. At start
    (``check_start``, before any source starts) a group watches the graph for
    ``DISCOVERY_WAIT`` and refuses (``DuplicateVesselError``, exit code 2) if any of its nodes'
    fully qualified names is also another process's. Then it publishes a claim (its names,
    host, pid and start time) on ``CLAIM_TOPIC``; every group reads the others' claims for
    the whole run. When two runs missed each other at start (slow discovery, or both started
    at once), both get each other's claim and agree without talking further: the one whose
    claim is later in (start time, host, pid) order stops; the earlier one keeps running and
    logs a warning. The groups of one split profile have disjoint names; a restarted group is
    a new process that never discovers its killed predecessor.
    """

    def __init__(self, composition: Composition) -> None:
        self.nodes = composition.nodes
        self.names = sorted(n.get_fully_qualified_name() for n in self.nodes)
        self.host, self.pid = socket.gethostname(), os.getpid()
        self.started_ns = 0
        host = self.nodes[0]
        self._pub = host.create_publisher(String, CLAIM_TOPIC, CLAIM_QOS)
        self._sub = host.create_subscription(String, CLAIM_TOPIC, self._on_claim, CLAIM_QOS)
        self._warned: set[tuple[str, int]] = set()

    def duplicates(self) -> list[str]:
        """Our fully qualified node names that the graph lists more than once."""
        seen: dict[str, int] = {}
        for name, ns in self.nodes[0].get_node_names_and_namespaces():
            fq = f'{ns.rstrip("/")}/{name}'
            seen[fq] = seen.get(fq, 0) + 1
        return [fq for fq in self.names if seen.get(fq, 0) > 1]

    def check_start(self, wait: float = DISCOVERY_WAIT) -> None:
        """Watch the graph for ``wait`` s; refuse on a namesake, else claim the names."""
        deadline = time.monotonic() + wait
        while True:
            dup = self.duplicates()
            if dup:
                raise DuplicateVesselError(
                    f'another process on this ROS graph (ROS_DOMAIN_ID '
                    f'{os.environ.get("ROS_DOMAIN_ID", "0")}) already runs '
                    f'{_names(dup)}: refusing to start a second vessel with the same node '
                    'names; stop the other run, or use another ROS_DOMAIN_ID or namespace',
                    started=False)
            stop = _Stop.active
            if stop is not None and stop.requested:
                raise KeyboardInterrupt  # a stop before the start: nothing to start
            if time.monotonic() >= deadline:
                break
            time.sleep(STOP_POLL)
        self.started_ns = time.time_ns()
        self._pub.publish(String(data=json.dumps({
            'nodes': self.names, 'host': self.host, 'pid': self.pid,
            'started_ns': self.started_ns})))

    def _key(self) -> tuple[int, str, int]:
        return self.started_ns, self.host, self.pid

    def _on_claim(self, msg: String) -> None:
        if not self.started_ns or len(msg.data) > MAX_CLAIM_BYTES:
            return
        try:
            claim = json.loads(msg.data)
            other = (int(claim['started_ns']), str(claim['host']), int(claim['pid']))
            names = {str(n) for n in claim['nodes']}
        except (ValueError, KeyError, TypeError):
            return  # not a claim of ours: nothing to agree on
        if other[1:] == (self.host, self.pid):
            return
        shared = sorted(names.intersection(self.names))
        if not shared:
            return
        if other < self._key():
            raise DuplicateVesselError(
                f'process {other[2]} on {other[1]} runs {_names(shared)} on this ROS graph '
                f'and started first: this later run stops (its sources were running for '
                f'{(time.time_ns() - self.started_ns) / 1e9:.1f} s)', started=True)
        if other[1:] not in self._warned:
            self._warned.add(other[1:])
            log.warning('process %d on %s started later with %s on this ROS graph: it must '
                        'stop (it will, on seeing the claim of this run)', other[2], other[1],
                        _names(shared))


def _names(names: Sequence[str]) -> str:
    shown = ', '.join(names[:5])
    return f'node(s) {shown}' + (f' and {len(names) - 5} more' if len(names) > 5 else '')



def run_group(profile: Profile, group: str | None = None, duration: float | None = None,
              check_only: bool = False) -> int:
    """Run the nodes of ``group`` (all when None) in this process until stopped."""
    built: list[tuple[str, Node]] = []  # named now: a destroyed node has no name any more
    with _Stop() as stop:
        try:
            with composed(profile, group, check_only=check_only) as c:
                if check_only:
                    return 0
                built = [(n.get_name(), n) for n in c.nodes]
                VesselGuard(c).check_start()  # one vessel per set of node names on a graph
                c.start()
                orphaned = _notice_orphaning(c, group)
                names = ', '.join(n.get_name() for n in c.nodes)
                log.info('%s%s running: %s', profile.name, f' [{group}]' if group else '',
                         names)
                deadline = None if duration is None else time.monotonic() + duration
                while not stop.requested and not orphaned() and c.context.ok():
                    if deadline is not None and time.monotonic() >= deadline:
                        break
                    c.executor.spin_once(timeout_sec=0.1)
                if stop.requested:
                    log.info('%s received, stopping', signal.Signals(stop.signal).name)
                elif orphaned():
                    _outlive_the_others(c)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
    # After the shutdown (a recorder's last write fails at close): what went wrong.
    problems = [f'{name}: {p}' for name, n in built if isinstance(n, EnbarrNode)
                for p in n.problems]
    if problems:
        log.error('%s%s ended with %d problem(s): %s', profile.name,
                  f' [{group}]' if group else '', len(problems), '; '.join(problems))
        _write_problems(problems)
        return EXIT_PROBLEMS
    return 0


#: How long a recorder group whose supervisor died waits for the other groups to stop [s].
ORPHAN_GRACE_SECONDS = 5.0


def _notice_orphaning(c: Composition, group: str | None) -> Callable[[], bool]:
    """For a supervised group of recorders only: whether the supervisor has died.

    Every other group gets its parent-death signal (SIGTERM) when the supervisor is killed
    and publishes its safe state (thrusters neutral) on its way out. A group of recorders
    gets no signal (a signal landing on a middleware thread can cost the messages in
    flight) and watches its parent instead: once it is reparented, the supervisor is gone.
    """
    if group is None or not c.nodes or not all(isinstance(n, Recorder) for n in c.nodes):
        return lambda: False
    parent = os.getppid()
    _die_with_parent(0)  # no parent-death signal: polled instead
    return lambda: os.getppid() != parent


def _outlive_the_others(c: Composition) -> None:
    """Record until nothing more comes from the other groups, or the grace has passed."""
    recorders = [n for n in c.nodes if isinstance(n, Recorder)]
    log.info('supervisor gone: recording until the other groups stop (at most %.0f s)',
             ORPHAN_GRACE_SECONDS)
    start = time.monotonic()
    while c.context.ok() and time.monotonic() < start + ORPHAN_GRACE_SECONDS:
        if not any(r.still_receiving() for r in recorders):
            log.info('the other groups stopped after %.1f s', time.monotonic() - start)
            break
        c.executor.spin_once(timeout_sec=0.02)
    else:
        log.warning('the other groups still publish after %.0f s: closing the bag',
                    ORPHAN_GRACE_SECONDS)


#: Exit status of a run that went to its end but with faults it reported (``report_problem``).
EXIT_PROBLEMS = 3


def supervise(profile: Profile, child_args: Callable[[str], list[str]],
              duration: float | None = None) -> int:
    """Run each group as a child process; restart a dead group up to its limit.

    Every wait (polling, a restart delay, the grace period of stopping) serves SIGINT and
    SIGTERM within ``STOP_POLL``. Exit code: 0, 1 (a group died past its restart limit), 2 (a
    group refused its configuration) or ``EXIT_PROBLEMS`` (a group ended with faults it
    reported, named again at the end).
    """
    run_group(profile, None, check_only=True)  # validate every node before anything starts
    procs: dict[str, subprocess.Popen[bytes]] = {}
    restarts = {g: 0 for g in profile.groups}
    exit_code = 0
    # Each group writes the problems it ended with to its own file (``PROBLEMS_FILE_ENV``).
    # Not through a pipe of its output: a group must keep its own stderr, which outlives a
    # killed supervisor (the orphaned recorder's last words).
    problem_dir = Path(tempfile.mkdtemp(prefix='enbarr-problems-'))

    def spawn(group: str) -> None:
        env = {**os.environ, PROBLEMS_FILE_ENV: str(problem_dir / f'{group}.txt')}
        procs[group] = subprocess.Popen(child_args(group), preexec_fn=_die_with_parent,
                                        start_new_session=True, env=env)
        log.info('group %s started (pid %d)', group, procs[group].pid)

    codes: dict[str, int | None] = {}
    with _Stop() as stop:
        try:
            for g in profile.groups:
                spawn(g)
            deadline = None if duration is None else time.monotonic() + duration
            while not stop.requested and (deadline is None or time.monotonic() < deadline):
                for g, p in list(procs.items()):
                    rc = p.poll()
                    if rc is None:
                        continue
                    how = f'signal {signal.Signals(-rc).name}' if rc < 0 else f'exit code {rc}'
                    if rc < 0:
                        repair_recording(profile, g, how)
                    limit = profile.groups[g].restart_limit
                    if rc == 2:
                        log.error('group %s refused its configuration (%s)', g, how)
                        exit_code = 2
                        stop.requested = True
                        break
                    if restarts[g] >= limit:
                        log.error('group %s died (%s); restart limit %d reached, stopping',
                                  g, how, limit)
                        exit_code = 1
                        stop.requested = True
                        break
                    restarts[g] += 1
                    log.error('group %s died (%s); restart %d of %d', g, how, restarts[g],
                              limit)
                    if stop.sleep(profile.groups[g].restart_delay):
                        break
                    spawn(g)
                else:
                    stop.sleep(STOP_POLL)
            if stop.signal is not None:
                log.info('%s received, stopping', signal.Signals(stop.signal).name)
        finally:
            codes = _stop_children(procs, stop)
            for g, c in codes.items():
                if c is not None and c < 0:
                    repair_recording(profile, g, f'signal {signal.Signals(-c).name}')
    problems = [f'group {g}: {line}' for g in profile.groups
                for line in _read_problems(problem_dir / f'{g}.txt')]
    shutil.rmtree(problem_dir, ignore_errors=True)
    if problems or EXIT_PROBLEMS in codes.values():
        log.error('%s ended with problems: %s', profile.name, '; '.join(problems) or ', '.join(
            f'group {g} exited with code {EXIT_PROBLEMS}' for g, c in codes.items()
            if c == EXIT_PROBLEMS))
        exit_code = exit_code or EXIT_PROBLEMS
    return exit_code


def repair_recording(profile: Profile, group: str, how: str) -> None:
    """After ``group`` was killed: make its recorder's bag whole as of its last flush.

    A recorder killed while it rewrote its file's index (once per flush) leaves a torn tail
    that readers refuse; ``recording.bag.repair_bag`` cuts it and rebuilds the index. A bag
    that was intact is not written to.
    """
    from enbarr_core.recording.bag import repair_bag
    for n in profile.nodes:
        if n.name != RECORDER_NODE or n.group != group or 'path' not in n.parameters:
            continue
        path = str(n.parameters['path'])
        try:
            repaired = [r for r in repair_bag(path) if r.repaired or r.indexed]
        except EnbarrError as err:
            log.error('group %s died (%s): its bag could not be repaired: %s', group, how, err)
            continue
        for r in repaired:
            if r.repaired:
                log.warning('group %s died (%s) while writing %s: repaired, %d messages '
                            'kept, %d torn bytes cut', group, how, r.name, r.messages,
                            r.dropped_bytes)
            else:
                log.warning('group %s died (%s) while writing %s: intact, %d messages, its '
                            'index written', group, how, r.name, r.messages)


#: The environment variable that tells a supervised group where to write its problems.
PROBLEMS_FILE_ENV = 'ENBARR_PROBLEMS_FILE'
MAX_PROBLEM_BYTES = 64 << 10  # what the supervisor reads of a group's problems file
MAX_PROBLEM_LINES = 20


def _write_problems(problems: Sequence[str]) -> None:
    """In a supervised group: append the problems it ended with to its problems file."""
    path = os.environ.get(PROBLEMS_FILE_ENV)
    if not path or not problems:
        return
    try:
        with open(path, 'a', encoding='utf-8') as f:
            f.write('; '.join(p.replace('\n', ' ') for p in problems) + '\n')
    except OSError as err:  # the supervisor learns of it from the exit code alone
        log.error('cannot tell the supervisor of the problems (%s): %s', path, err.strerror)


def _read_problems(path: Path) -> list[str]:
    """Read the problem lines a group wrote (bounded: a group is not trusted to be brief)."""
    try:
        with open(path, encoding='utf-8', errors='replace') as f:
            text = f.read(MAX_PROBLEM_BYTES)
    except OSError:
        return []
    return [line[:2000] for line in text.splitlines() if line][:MAX_PROBLEM_LINES]


def _stop_children(procs: dict[str, subprocess.Popen[bytes]],
                   stop: _Stop | None = None) -> dict[str, int | None]:
    """SIGINT every group, the recorder last so that it records the others' safe state.

    A group still running ``GRACE_SECONDS`` later, or when another stop request comes in
    while waiting, is killed. Returns each group's exit code.
    """
    first = {g: p for g, p in procs.items() if g != RECORDER_GROUP}
    last = {g: p for g, p in procs.items() if g == RECORDER_GROUP}
    seen = stop.count if stop is not None else 0
    for batch in (first, last):
        for p in batch.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + GRACE_SECONDS
        while any(p.poll() is None for p in batch.values()):
            again = stop is not None and stop.count > seen
            if again or time.monotonic() >= deadline:
                for g, p in batch.items():
                    if p.poll() is None:
                        why = 'a second stop request' if again else f'{GRACE_SECONDS:.0f} s'
                        log.error('group %s did not stop (%s): killed', g, why)
                        p.kill()
                        p.wait()
                break
            time.sleep(STOP_POLL)
    return {g: p.returncode for g, p in procs.items()}


def _die_with_parent(signum: int = signal.SIGTERM) -> None:
    """In the child: get ``signum`` if the supervisor dies (Linux; 0: no signal)."""
    try:
        import ctypes
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(1, int(signum))  # PR_SET_PDEATHSIG
    except OSError:
        pass


def child_command(argv: Sequence[str]) -> Callable[[str], list[str]]:
    """Return the command that runs one group: this bringup's arguments plus ``--group``."""
    return lambda group: [sys.executable, '-m', 'enbarr_core.bringup.cli', 'bringup', *argv,
                          '--group', group]
