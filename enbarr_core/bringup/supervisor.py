"""The supervisor of a profile split into process groups.

It validates the whole profile once (``compose.validate``: no device opened, nothing visible
on the graph), then runs each group as a child process (``enbarr bringup --group NAME``),
reports a group that dies, repairs its recorder's bag (``repair``), restarts it up to the
group's ``restart_limit``, and stops them all with SIGINT (SIGKILL after a grace period), the
recorder last so that it records the others' safe state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import logging
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from enbarr_core.bringup.compose import RECORDER_GROUP, validate
from enbarr_core.bringup.profile import Profile
from enbarr_core.bringup.repair import repair_recording
from enbarr_core.bringup.run import EXIT_PROBLEMS, PROBLEMS_FILE_ENV, read_problems, summary
from enbarr_core.bringup.stop import STOP_POLL, StopRequest, die_with_parent

log = logging.getLogger('enbarr.bringup')

#: How long a group may take to stop after SIGINT before it is killed [s].
GRACE_SECONDS = 10.0


def supervise(profile: Profile, child_args: Callable[[str], list[str]],
              duration: float | None = None) -> int:
    """Run each group as a child process; restart a dead group up to its limit.

    Every wait (polling, a restart delay, the grace period of stopping) serves SIGINT and
    SIGTERM within ``STOP_POLL``. Exit code: 0, 1 (a group died past its restart limit), 2 (a
    group refused its configuration) or ``EXIT_PROBLEMS`` (a group died on the way, even if
    its restart kept the vessel going, or ended with faults it reported: each named again at
    the end).
    """
    validate(profile)  # every node of every group, before anything starts
    procs: dict[str, subprocess.Popen[bytes]] = {}
    restarts = {g: 0 for g in profile.groups}
    exit_code = 0
    deaths: list[str] = []  # every group that died on the way, restarted or not
    # Each group writes the problems it ended with to its own file (``PROBLEMS_FILE_ENV``).
    problem_dir = Path(tempfile.mkdtemp(prefix='enbarr-problems-'))

    def spawn(group: str) -> None:
        env = {**os.environ, PROBLEMS_FILE_ENV: str(problem_dir / f'{group}.txt')}
        procs[group] = subprocess.Popen(child_args(group), preexec_fn=die_with_parent,
                                        start_new_session=True, env=env)
        log.info('group %s started (pid %d)', group, procs[group].pid)

    codes: dict[str, int | None] = {}
    started = time.monotonic()
    with StopRequest() as stop:
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
                    deaths.append(f'group {g} died ({how})')
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
    problems = [*deaths, *(f'group {g}: {line}' for g in profile.groups
                           for line in read_problems(problem_dir / f'{g}.txt'))]
    problems += [f'group {g} exited with code {EXIT_PROBLEMS}' for g, c in codes.items()
                 if c == EXIT_PROBLEMS and not any(p.startswith(f'group {g}: ')
                                                   for p in problems)]
    shutil.rmtree(problem_dir, ignore_errors=True)
    if problems:
        # A group that died and was restarted kept the vessel going, but the run was not
        # what was asked for: the user hears of it in the exit code, not only in the log.
        log.error('%s ended with problems: %s', profile.name, '; '.join(problems))
        exit_code = exit_code or EXIT_PROBLEMS
    log.info('%s', summary(profile, time.monotonic() - started, problems))
    return exit_code


def _stop_children(procs: dict[str, subprocess.Popen[bytes]],
                   stop: StopRequest | None = None) -> dict[str, int | None]:
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


def child_command(argv: Sequence[str]) -> Callable[[str], list[str]]:
    """Return the command that runs one group: this bringup's arguments plus ``--group``."""
    return lambda group: [sys.executable, '-m', 'enbarr_core.commands.main', 'bringup', *argv,
                          '--group', group]

