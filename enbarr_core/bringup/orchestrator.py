"""The orchestrator: builds a profile's nodes, runs them, and always leaves thrusters neutral.

One process group (the default, every node in ``main``): all nodes are built in this process
on one ``SingleThreadedExecutor`` and share one link bus, so the IMU -> thruster chain runs as
direct calls (``docs/architecture.md``). Several groups: this process becomes a supervisor that
first builds every node once to validate the profile, then runs each group as a child process
(``enbarr bringup --group NAME``), reports a group that dies, restarts it up to the group's
``restart_limit``, and stops them all with SIGINT (SIGKILL after a grace period).

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
import logging
import os
import signal
import subprocess
import sys
import time
from typing import Any

from rcl_interfaces.srv import ListParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from enbarr_interfaces.links import LinkBus

from enbarr_core.framework import registry
from enbarr_core.framework.errors import EnbarrError, ProfileError
from enbarr_core.framework.node import EnbarrNode
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
                              'segment_seconds': r.segment_seconds}
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
    try:
        for spec in profile.nodes:
            if group is not None and spec.group != group:
                continue
            nodes.append(_construct(profile, spec, context))
        _check_parameters(profile, nodes, group)
    except BaseException:
        for n in reversed(nodes):
            _safely(n.destroy_node, f'destroying {n.get_name()}')
        raise
    return nodes


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
        param = getattr(err, 'parameter', None)
        if param is not None:  # point at the file that set the value, if a profile did
            if param in spec.parameters:
                key = f'nodes.{spec.name}.parameters.{param}'
                where = profile.where(key)
            elif param in profile.parameters:
                key = f'parameters.{param}'
                where = profile.where(key)
        raise ProfileError(str(err), path=where, key=key) from err
    except (ValueError, TypeError) as err:  # rclpy refusing a name, a remap, a value
        raise ProfileError(f'{spec.plugin}: {err}', path=where,
                           key=f'nodes.{spec.name}') from err


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


def shutdown_nodes(nodes: Sequence[Node]) -> None:
    """Take nodes down: stop sources, safe state, then destroy (recorders last).

    The one exit path of every run: recorders (``Recorder``) go after the other nodes so
    that the bag holds their safe state.
    """
    for n in nodes:
        if isinstance(n, EnbarrNode):
            _safely(n.stop, f'stopping {n.get_name()}')
    for n in nodes:
        if isinstance(n, EnbarrNode):
            _safely(n.safe_state, f'safe state of {n.get_name()}')
    recorders = [n for n in nodes if isinstance(n, Recorder)]
    for n in [*(n for n in nodes if n not in recorders), *recorders]:
        _safely(n.destroy_node, f'destroying {n.get_name()}')


def _safely(fn: Callable[[], Any], what: str) -> None:
    try:
        fn()
    except Exception as err:  # noqa: BLE001 - the remaining shutdown steps must still run
        log.error('%s failed: %r', what, err)


class _Stop:
    """SIGINT/SIGTERM set a flag that the spin loop checks.

    rclpy's own handlers are off so that the context still works while thrusters are put in
    their safe state.
    """

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _Stop:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        self.signal = signum

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


#: How long a Python thread may hold the GIL while another waits [s] (CPython default 5 ms).
#: The chain thread wakes 400 times a second and must not wait behind a busy recorder or
#: executor thread for a whole default interval: that alone would break the 2 ms latency goal.
GIL_SWITCH_INTERVAL = 0.0005


def configure_process() -> None:
    """Process-wide settings for running nodes (bringup and the benchmark both call it)."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)


@dataclass(frozen=True)
class Composition:
    """The nodes of one process, on one executor, their link bus connected."""

    context: Context
    executor: SingleThreadedExecutor
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
def composed(profile: Profile, group: str | None = None, *,
             check_only: bool = False) -> Iterator[Composition]:
    """Build the nodes of ``group`` (all when None) in a fresh context; always take them down.

    On leaving: ``shutdown_nodes`` (safe state first), or, when nothing was started
    (``check_only``), just destroy them. bringup, the benchmark and scenarios all use it.
    """
    configure_process()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor(context=context)
    nodes: list[Node] = []
    try:
        nodes.extend(build_nodes(profile, context, group))
        if not check_only:
            for n in nodes:
                executor.add_node(n)
            LinkBus.of(context).connect()
        yield Composition(context, executor, nodes)
    finally:
        if check_only:  # nothing ran: no safe state to publish, nothing to record
            for n in reversed(nodes):
                _safely(n.destroy_node, f'destroying {n.get_name()}')
        else:
            shutdown_nodes(nodes)
        executor.shutdown()
        rclpy.try_shutdown(context=context)


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


def node_problems(nodes: Sequence[Node]) -> list[str]:
    """Every fault the nodes reported with ``report_problem``, as 'node: message'."""
    return [f'{n.get_name()}: {p}' for n in nodes if isinstance(n, EnbarrNode)
            for p in n.problems]


def supervise(profile: Profile, child_args: Callable[[str], list[str]],
              duration: float | None = None) -> int:
    """Run each group as a child process; restart a dead group up to its limit."""
    run_group(profile, None, check_only=True)  # validate every node before anything starts
    procs: dict[str, subprocess.Popen[bytes]] = {}
    restarts = {g: 0 for g in profile.groups}
    exit_code = 0

    def spawn(group: str) -> None:
        procs[group] = subprocess.Popen(child_args(group), preexec_fn=_die_with_parent,
                                        start_new_session=True)
        log.info('group %s started (pid %d)', group, procs[group].pid)

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
                    limit = profile.groups[g].restart_limit
                    if rc == 2:
                        log.error('group %s refused its configuration (%s)', g, how)
                        return 2
                    if restarts[g] >= limit:
                        log.error('group %s died (%s); restart limit %d reached, stopping',
                                  g, how, limit)
                        exit_code = 1
                        stop.requested = True
                        break
                    restarts[g] += 1
                    log.error('group %s died (%s); restart %d of %d', g, how, restarts[g],
                              limit)
                    time.sleep(profile.groups[g].restart_delay)
                    spawn(g)
                time.sleep(0.1)
        finally:
            _stop_children(procs)
    return exit_code


def _stop_children(procs: dict[str, subprocess.Popen[bytes]]) -> None:
    """SIGINT every group, the recorder last so that it records the others' safe state."""
    first = {g: p for g, p in procs.items() if g != RECORDER_GROUP}
    last = {g: p for g, p in procs.items() if g == RECORDER_GROUP}
    for batch in (first, last):
        for p in batch.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + GRACE_SECONDS
        for g, p in batch.items():
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.error('group %s did not stop in %.0f s: killed', g, GRACE_SECONDS)
                p.kill()
                p.wait()


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
