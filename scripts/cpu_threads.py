"""CPU of every thread of a running profile, by thread name (docs/hardware.md's figures).

    python3 scripts/cpu_threads.py PROFILE [--warmup W] [--seconds S] [-- BRINGUP_ARGS...]

Runs ``enbarr bringup --profile PROFILE BRINGUP_ARGS`` (this interpreter, LOCALHOST, the
caller's ROS_DOMAIN_ID), waits ``--warmup`` seconds (start-up and bringup's discovery wait),
reads the CPU time of every thread of its process tree from /proc at the start and the end
of a ``--seconds`` window, stops bringup with SIGINT and prints one JSON line: every thread's
share of one core, summed per thread name (the kernel keeps 15 characters of a name: the
node's ``<node>_loop``, a driver's reader or writer thread, ``dds.*``; a process's main
thread, which spins the executor, is ``executor``).
``enbarr bench --profile`` measures the same tree but reports its busiest threads only.
Figures depend on the machine and its load: run it alone.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

TICKS = os.sysconf('SC_CLK_TCK')


def tree(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in Path(f'/proc/{p}/task').glob('*'):
            children = task / 'children'
            if children.exists():
                todo += [int(c) for c in children.read_text().split()]
    return out


def thread_ticks(pid: int) -> dict[tuple[int, int], tuple[str, int]]:
    """(process, thread) -> (thread name, utime + stime [ticks]) over the tree of ``pid``."""
    out = {}
    for p in tree(pid):
        for task in Path(f'/proc/{p}/task').glob('*'):
            try:
                stat = (task / 'stat').read_text()
            except OSError:
                continue  # the thread ended
            name = stat[stat.index('(') + 1:stat.rindex(')')]
            if int(task.name) == p:
                name = 'executor'  # the main thread: it spins the executor
            fields = stat[stat.rindex(')') + 2:].split()
            out[(p, int(task.name))] = (name, int(fields[11]) + int(fields[12]))
    return out


def main() -> int:
    """Measure and print the JSON line."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('profile')
    p.add_argument('--warmup', type=float, default=8.0, metavar='W')
    p.add_argument('--seconds', type=float, default=10.0, metavar='S')
    p.add_argument('bringup_args', nargs=argparse.REMAINDER)
    args = p.parse_args()
    extra = [a for a in args.bringup_args if a != '--']
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    proc = subprocess.Popen([sys.executable, '-m', 'enbarr_core.commands.main', 'bringup',
                             '--profile', args.profile, *extra], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(args.warmup)
        if proc.poll() is not None:
            print(f'bringup ended during the warm-up (exit {proc.returncode})', file=sys.stderr)
            return 1
        start, t0 = thread_ticks(proc.pid), time.monotonic()
        time.sleep(args.seconds)
        end, wall = thread_ticks(proc.pid), time.monotonic() - t0
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    shares: dict[str, float] = defaultdict(float)
    for key, (name, ticks) in end.items():
        shares[name] += (ticks - start.get(key, (name, 0))[1]) / TICKS / wall
    ordered = sorted(shares.items(), key=lambda kv: -kv[1])
    print(json.dumps({'profile': args.profile, 'bringup_args': extra,
                      'seconds': round(wall, 2),
                      'cpu_core_fraction': round(sum(shares.values()), 4),
                      'threads': {name: round(share, 4) for name, share in ordered}}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
