#!/usr/bin/env python3
"""CPU share of whole vessel profiles, run as users run them: one JSON line per profile.

Each profile runs under ``enbarr bringup`` (its own process tree, LOCALHOST, a private
domain) for ``--seconds`` after a ``--settle`` that covers start-up and bringup's 3 s
discovery wait; the figure is the CPU time of the whole tree (every process and thread,
from /proc) over that window, as a share of one core here, with the Raspberry Pi 4 estimate
(x6, docs/benchmarks.md). Compare a simulated profile with its emulated twin to see what the
real drivers and their emulators cost:

    python3 tools/profile_cpu.py enbarr_sim enbarr_rov_emulated saucer_sim saucer_emulated
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

PI_FACTOR = 6.0
TICKS = os.sysconf('SC_CLK_TCK')


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (from /proc/*/stat parents)."""
    parents: dict[int, list[int]] = {}
    for d in Path('/proc').iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / 'stat').read_text().rsplit(')', 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(parents.get(p, []))
    return out


def _cpu_seconds(pids: list[int]) -> float:
    total = 0
    for p in pids:
        try:
            fields = Path(f'/proc/{p}/stat').read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / TICKS


def measure(profile: str, seconds: float, settle: float) -> dict[str, object]:
    """Run ``profile`` and return its CPU share over ``seconds`` after ``settle``."""
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': os.environ.get('ROS_DOMAIN_ID', str(50 + os.getpid() % 40))}
    proc = subprocess.Popen(
        [sys.executable, '-m', 'enbarr_core.bringup.cli', 'bringup', '--profile', profile,
         '--duration', str(settle + seconds + 5.0)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(settle)
        pids = _tree(proc.pid)
        start_cpu, start = _cpu_seconds(pids), time.monotonic()
        time.sleep(seconds)
        pids = sorted(set(pids) | set(_tree(proc.pid)))
        cpu, wall = _cpu_seconds(pids) - start_cpu, time.monotonic() - start
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    share = 100.0 * cpu / wall
    return {'profile': profile, 'seconds': round(wall, 1), 'cpu_percent': round(share, 1),
            'pi4_percent_estimate': round(share * PI_FACTOR, 0), 'exit': proc.returncode}


def main() -> int:
    """Measure each profile named on the command line in turn."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('profiles', nargs='+')
    parser.add_argument('--seconds', type=float, default=20.0)
    parser.add_argument('--settle', type=float, default=8.0)
    args = parser.parse_args()
    for p in args.profiles:
        print(json.dumps(measure(p, args.seconds, args.settle)), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
