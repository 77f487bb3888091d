"""The full-disk fault of a chaos run: a second run recording to a tmpfs that fills up.

The tmpfs lives in a private mount namespace (root only; else the fault is skipped). Safe:
control not disrupted while the disk is full, the recorder's memory bounded, the bag readable
(as of its last flush), and ``bringup`` exiting non-zero.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import time

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools.chaos import judge
from enbarr_core.tools.chaos.judge import KEEPS_CONTROL, Verdict
from enbarr_core.tools.chaos.observer import Observer
from enbarr_core.tools.chaos.plan import Plan
from enbarr_core.tools.chaos.tree import enbarr_command, rss_mb, Tree

DISK_BYTES = 160 << 20          # the tmpfs of the disk fault (over the recorder's 64 MB margin)
RSS_GROWTH_LIMIT_MB = 3.0       # recorder memory growth allowed while the disk stays full
RSS_SETTLE_S = 2.0              # ... counted from this long after the disk filled


@dataclass(frozen=True)
class DiskRun:
    """The disk fault's verdict, the bag it kept and everything its processes printed."""

    verdict: Verdict
    bag: Path | None   # None: skipped, no bag
    output: str


def disk_run(plan: Plan, out: Path, window: float, startup_timeout: float) -> DiskRun:
    """Run with a recording disk that fills: control kept, memory bounded, exit != 0."""
    name = 'disk_full:recorder'
    kept = out / 'disk_bag'
    if os.geteuid() != 0 or shutil.which('unshare') is None:
        return DiskRun(judge.skipped(name, KEEPS_CONTROL, 'needs root (a tmpfs in a private '
                                     'mount namespace)'), None, '')
    mnt = out / 'tmpfs'
    mnt.mkdir()
    # In the namespace: mount, run bringup (its pid printed for the final SIGINT), keep a copy
    # of the bag once it ended (the tmpfs goes with the namespace).
    script = ('mount -t tmpfs -o size=%d enbarr_chaos "$0" || exit 97; '
              '"$@" & pid=$!; echo "chaos: bringup pid $pid"; wait $pid; rc=$?; '
              'cp -a "$0/bag" %s 2>/dev/null; exit $rc' % (DISK_BYTES, _quote(str(kept))))
    cmd = ['unshare', '--mount', '--propagation', 'private', 'sh', '-c', script, str(mnt),
           *enbarr_command('bringup', '--profile', str(plan.path), '--output',
                           str(mnt / 'bag'))]
    obs = Observer()
    tree = Tree(cmd, out / 'disk.log')
    rss: list[float] = []
    rc: int | None = None
    try:
        try:
            tree.wait_group('recorder', startup_timeout)
            if not obs.wait_busy(startup_timeout):
                raise EnbarrError('control never drove the actuators')
        except EnbarrError as err:
            return DiskRun(Verdict(name, KEEPS_CONTROL, False, None, str(err)), kept,
                           tree.text)
        rec = tree.group_pid('recorder')
        filled = fill(Path(f'/proc/{tree.proc.pid}/root') / mnt.relative_to('/'))
        start = time.time_ns()
        while time.time_ns() - start < max(10.0, 3 * window) * 1e9:
            mb = rss_mb(rec) if rec is not None else None
            if mb is not None and time.time_ns() - start >= RSS_SETTLE_S * 1e9:
                rss.append(mb)
            time.sleep(0.5)
        end = time.time_ns()
        found = re.search(r'chaos: bringup pid (\d+)', tree.text)
        if found:
            os.kill(int(found.group(1)), signal.SIGINT)
        try:
            rc = tree.proc.wait(60.0)
        except subprocess.TimeoutExpired:
            rc = None
        tree.reap_children()
    finally:
        if tree.proc.poll() is None:
            tree.stop(signal.SIGKILL)
        obs.close()
    growth = (max(rss) - min(rss)) if rss else 0.0
    v = judge.judge_kept(name, list(obs.control), list(obs.actuators), start, end,
                         figures={'filled_bytes': filled, 'exit_code': rc,
                                  'recorder_rss_growth_mb': round(growth, 1)})
    problems = [] if v.passed else [v.detail]
    if rc is None or rc == 0:
        problems.append(f'bringup exited {rc} after the disk filled (want non-zero)')
    if growth > RSS_GROWTH_LIMIT_MB:
        problems.append(f'recorder memory grew {growth:.0f} MB in '
                        f'{(end - start) * 1e-9:.0f} s (> {RSS_GROWTH_LIMIT_MB:.0f})')
    if not bag_readable(kept):
        problems.append('bag unreadable')
    detail = '; '.join(problems) or f'{v.detail}; exit {rc}'
    return DiskRun(Verdict(name, KEEPS_CONTROL, not problems, None, detail, v.figures), kept,
                   tree.text)


def fill(directory: Path) -> int:
    """Fill the file system of ``directory`` (one file, until ENOSPC); bytes written."""
    written = 0
    chunk = b'\0' * (1 << 20)
    with open(directory / 'chaos_filler', 'wb', buffering=0) as f:
        while True:
            try:
                written += f.write(chunk)
            except OSError:
                break
    return written


def bag_readable(path: Path) -> bool:
    """Whether the bag at ``path`` reads back."""
    from enbarr_core.recording.bag import read_bag
    try:
        return bool(read_bag(path))
    except Exception:  # noqa: BLE001 - any reader failure means unreadable
        return False


def _quote(s: str) -> str:
    return "'" + s.replace("'", "'\\''") + "'"
