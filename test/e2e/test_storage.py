"""Storage under hostile conditions, whole runs: a supervisor SIGKILLed while
recording, and a disk that fills during a run.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import re
import signal
import subprocess
import time
from typing import Any

import pytest
from rosbags.rosbag2 import Reader
from support.bags import read_bag
from support.cli import ENBARR

from recording.small_disk import small_disk

from e2e.test_groups import SPLIT_PROFILE
from enbarr_interfaces.convert import stamp_to_ns
from support.processes import bringup
from support.waiting import poll_until

MB = 1_000_000


def pgrep(pattern: str) -> list[int]:
    out = subprocess.run(['pgrep', '-f', '--', pattern], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def wait_gone(pattern: str, timeout: float) -> list[int]:
    """The processes ``pattern`` matches that are left after waiting ``timeout`` [s]."""
    poll_until(lambda: not pgrep(pattern), timeout, step=0.2)
    return pgrep(pattern)


@dataclass(frozen=True)
class OrphanRun:
    """A split, recording profile whose supervisor was SIGKILLed while thrusters drove."""

    kill_ns: int                    # wall time of the kill
    leftover: list[int]             # the children still alive 60 s after it
    outputs: list[tuple[int, Any]]  # (receive time ns, thruster_output) from the bag
    text: str                       # everything the run printed


@pytest.fixture(scope='module')
def orphan_run(tmp_path_factory: pytest.TempPathFactory) -> OrphanRun:
    tmp_path = tmp_path_factory.mktemp('orphan')
    profile = tmp_path / 'split.yaml'
    profile.write_text(SPLIT_PROFILE)
    bag = tmp_path / 'bag'
    pattern = f'--profile {profile}'
    with bringup('--profile', str(profile), '--output', str(bag)) as (proc, out):
        try:
            out.wait_for(r'group recorder started', 60)
            out.wait_for(r'thrust +[1-9]\d*\.\d N', 90)  # driving across processes
            kill_ns = time.time_ns()
            proc.kill()  # the supervisor only: the groups get PDEATHSIG
            proc.wait()
            leftover = wait_gone(pattern, 60)
        finally:
            for pid in pgrep(pattern):
                os.kill(pid, signal.SIGKILL)
    time.sleep(0.5)
    return OrphanRun(kill_ns, leftover, list(read_bag(bag).get('/thruster_output', [])),
                     out.text)


def test_every_group_exits_after_the_supervisor_is_killed(orphan_run: OrphanRun) -> None:
    assert not orphan_run.leftover


def stamp_ns(msg: Any) -> int:
    return stamp_to_ns(msg.header.stamp)


def test_the_bag_ends_with_neutral_thrusters(orphan_run: OrphanRun) -> None:
    # before the fix: the recorder closed at once with the others, last output 0.02
    # By the sample's stamp, not the bag's receive time: a loaded recorder receives late.
    driving = [m for _, m in orphan_run.outputs
               if stamp_ns(m) < orphan_run.kill_ns and any(m.effort)]
    assert driving, 'the thrusters never drove before the kill'
    after = [m for t, m in orphan_run.outputs if t > orphan_run.kill_ns]
    assert after, orphan_run.text[-2500:]
    tail = [(round((t - orphan_run.kill_ns) * 1e-9, 3), max(abs(e) for e in m.effort))
            for t, m in orphan_run.outputs[-8:]]
    assert not any(orphan_run.outputs[-1][1].effort), (tail, orphan_run.text[-2000:])


def test_the_recorder_says_it_waited_for_the_others(orphan_run: OrphanRun) -> None:
    assert re.search(r'supervisor gone: recording until the other groups stop',
                     orphan_run.text), orphan_run.text[-3000:]
    assert 'Traceback' not in orphan_run.text


def rss_mb(pid: int) -> float:
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1000
    raise AssertionError(f'no VmRSS for {pid}')


@dataclass(frozen=True)
class FullDiskRun:
    """enbarr_sim recording to a 4 MB tmpfs with no margin: the disk fills mid-run."""

    exit_code: int
    text: str                  # everything the run printed
    after_failure: str         # ... from the failure on
    rss_at_failure: float      # [MB] the run's resident memory when the disk was full
    rss_later: float           # [MB] ... FULL_DISK_WATCH seconds later
    bag_count: int             # messages the rosbags reader reads from the bag
    thruster_outputs: int      # of them on /thruster_output


FULL_DISK_WATCH = 15.0  # [s] how long the run goes on after its disk filled
FULL_DISK_PROFILE = """
include: [enbarr_sim]
nodes:
  recorder:
    plugin: recorder
    parameters: {{path: {bag}, flush_seconds: 0.5, min_free_space: 0.0}}
  surface:
    parameters:
      script: ['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.0']   # drive on, all the run
"""


@pytest.fixture(scope='module')
def full_disk_run(tmp_path_factory: pytest.TempPathFactory) -> FullDiskRun:
    tmp_path = tmp_path_factory.mktemp('full')
    with small_disk(tmp_path, '4m') as disk:
        profile = tmp_path / 'full.yaml'
        profile.write_text(FULL_DISK_PROFILE.format(bag=disk / 'bag'))
        with bringup('--profile', str(profile)) as (proc, out):
            out.wait_for(r'enbarr_sim running', 60)
            t0 = time.monotonic()
            m = out.wait_for(r'No space left on device', 180)
            print(f'disk full {time.monotonic() - t0:.1f} s after the start')
            start = out.text[:m.start()].count('\n')
            rss_at_failure = rss_mb(proc.pid)
            time.sleep(FULL_DISK_WATCH)
            rss_later = rss_mb(proc.pid)
            out.wait_for(r'thrust +[1-9]\d*\.\d N', 30, start)  # still driving
            proc.send_signal(signal.SIGINT)
            exit_code = proc.wait(timeout=60)
        time.sleep(0.5)
        with Reader(disk / 'bag') as reader:
            count = sum(1 for _ in reader.messages())
        outputs = len(read_bag(disk / 'bag').get('/thruster_output', []))
        return FullDiskRun(exit_code, out.text, ''.join(out.lines[start:]), rss_at_failure,
                           rss_later, count, outputs)


def test_a_full_disk_fails_the_run_naming_it(full_disk_run: FullDiskRun) -> None:
    assert full_disk_run.exit_code == 3, full_disk_run.text[-3000:]
    assert re.search(r'ended with 1 problem\(s\): recorder: recording failed: \S+/bag: '
                     r'cannot .*No space left on device', full_disk_run.text), \
        full_disk_run.text[-3000:]


def test_a_full_disk_is_no_traceback(full_disk_run: FullDiskRun) -> None:
    assert 'Traceback' not in full_disk_run.text, full_disk_run.text[-3000:]


def test_the_vehicle_drives_on_after_the_disk_filled(full_disk_run: FullDiskRun) -> None:
    drives = re.findall(r'thrust +([\d.]+) N', full_disk_run.after_failure)
    assert len(drives) >= 3 and any(float(d) > 0.0 for d in drives), \
        full_disk_run.after_failure[-3000:]
    assert 'thruster commands stopped' not in full_disk_run.after_failure


def test_memory_stays_bounded_after_the_disk_filled(full_disk_run: FullDiskRun) -> None:
    # before the fix: +75 MB in 26 s, and growing
    growth = full_disk_run.rss_later - full_disk_run.rss_at_failure
    print(f'RSS {full_disk_run.rss_at_failure:.1f} MB at the failure, '
          f'{full_disk_run.rss_later:.1f} MB {FULL_DISK_WATCH:.0f} s later')
    assert growth < 5.0, growth


def test_the_bag_reads_up_to_its_last_flush(full_disk_run: FullDiskRun) -> None:
    assert full_disk_run.bag_count > 0
    assert full_disk_run.thruster_outputs > 0


def test_too_little_free_space_refuses_the_run(tmp_path: Path) -> None:
    with small_disk(tmp_path, '2m') as disk:
        run = subprocess.run([*ENBARR, 'bringup', '--profile', 'enbarr_sim', '--output',
                              str(disk / 'bag'), '--duration', '5'], capture_output=True,
                             text=True, timeout=120)
    assert run.returncode == 2, run.stderr[-3000:]
    assert 'Traceback' not in run.stderr
    assert re.search(r'/bag: 2\.1 MB free, less than the 64 MB margin \(min_free_space\); '
                     r'recording refused', run.stderr), run.stderr[-3000:]
