"""Running one process group: guard, build, start, spin until stopped, and always shut down.

Every exit path of a group (SIGINT, SIGTERM, the end of ``--duration``, an exception) leaves
through ``composed``'s one shutdown (``compose.shutdown_nodes``): sources stopped, thrusters
neutral, recorders closed last. A group that is killed outright cannot do that: then the
thruster plugin's own command timeout (a separate process) or, for a crashed thruster
process, the restart (plugins start neutral) and the device's watchdog take over.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import logging
import os
from pathlib import Path
import signal
import time

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.bringup.compose import Composition, composed
from enbarr_core.bringup.profile import Profile
from enbarr_core.bringup.stop import StopRequest, die_with_parent
from enbarr_core.recording.bag import read_counts
from enbarr_core.recording.recorder import Recorder

log = logging.getLogger('enbarr.bringup')

#: Exit status of a run that went to its end but with faults it reported (``report_problem``)
#: or a group that died on the way.
EXIT_PROBLEMS = 3


def run_group(profile: Profile, group: str | None = None,
              duration: float | None = None) -> int:
    """Run the nodes of ``group`` (all when None) in this process until stopped."""
    built: list[tuple[str, Node]] = []  # named now: a destroyed node has no name any more
    started = time.monotonic()
    with StopRequest() as stop:
        try:
            # The guard looks at the graph before any node of ours exists on it.
            with composed(profile, group, guard=True) as c:
                built = [(n.get_name(), n) for n in c.nodes]
                started = time.monotonic()
                if c.guard is not None:
                    c.guard.claim()
                c.start()
                orphaned = _notice_orphaning(c, group)
                names = ', '.join(n.get_name() for n in c.nodes)
                log.info('%s%s running: %s', profile.name, f' [{group}]' if group else '',
                         names)
                deadline = None if duration is None else started + duration
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
    ran = time.monotonic() - started if built else 0.0
    # After the shutdown (a recorder's last write fails at close): what went wrong.
    problems = [f'{name}: {p}' for name, n in built if isinstance(n, EnbarrNode)
                for p in n.problems]
    if problems:
        log.error('%s%s ended with %d problem(s): %s', profile.name,
                  f' [{group}]' if group else '', len(problems), '; '.join(problems))
        write_problems(problems)
    if group is None and built:
        log.info('%s', summary(profile, ran, problems))
    return EXIT_PROBLEMS if problems else 0


def summary(profile: Profile, ran: float, problems: Sequence[str]) -> str:
    """Return the last line of a run: how long it ran, what it recorded, what failed."""
    parts = [f'{profile.name} ran {ran:.1f} s']
    if profile.record is not None:
        count = read_counts(profile.record.path)
        parts.append(f'bag {profile.record.path}: ' + (
            'no metadata (see the errors above)' if count is None
            else f'{count.messages} messages on {count.topics} topics'))
    parts.append(f'{len(problems)} problem(s), named above' if problems else 'no problems')
    return 'summary: ' + '; '.join(parts)


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
    die_with_parent(0)  # no parent-death signal: polled instead
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


# -- how a supervised group tells the supervisor what went wrong ----------------------------
# Through a file of its own, not a pipe of its output: a group must keep its own stderr,
# which outlives a killed supervisor (the orphaned recorder's last words).

#: The environment variable that tells a supervised group where to write its problems.
PROBLEMS_FILE_ENV = 'ENBARR_PROBLEMS_FILE'
MAX_PROBLEM_BYTES = 64 << 10  # what the supervisor reads of a group's problems file
MAX_PROBLEM_LINES = 20


def write_problems(problems: Sequence[str]) -> None:
    """In a supervised group: append the problems it ended with to its problems file."""
    path = os.environ.get(PROBLEMS_FILE_ENV)
    if not path or not problems:
        return
    try:
        with open(path, 'a', encoding='utf-8') as f:
            f.write('; '.join(p.replace('\n', ' ') for p in problems) + '\n')
    except OSError as err:  # the supervisor learns of it from the exit code alone
        log.error('cannot tell the supervisor of the problems (%s): %s', path, err.strerror)


def read_problems(path: Path) -> list[str]:
    """Read the problem lines a group wrote (bounded: a group is not trusted to be brief)."""
    try:
        with open(path, encoding='utf-8', errors='replace') as f:
            text = f.read(MAX_PROBLEM_BYTES)
    except OSError:
        return []
    return [line[:2000] for line in text.splitlines() if line][:MAX_PROBLEM_LINES]
