"""Storage under hostile conditions (issue 8), whole runs: a supervisor SIGKILLed while
recording, and a disk that fills during a run.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
import re
import signal
import subprocess
import time
from typing import Any

import pytest
from support.bags import read_bag
from support.cli import ENBARR

from e2e.test_groups import Output, SPLIT_PROFILE

MB = 1_000_000


def pgrep(pattern: str) -> list[int]:
    out = subprocess.run(['pgrep', '-f', pattern], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def wait_gone(pattern: str, timeout: float) -> list[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = pgrep(pattern)
        if not left:
            return []
        time.sleep(0.2)
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
    proc = subprocess.Popen([*ENBARR, 'bringup', '--profile', str(profile), '--record',
                             str(bag)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    out = Output(proc)
    pattern = f'--profile {profile}'
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


def test_the_bag_ends_with_neutral_thrusters(orphan_run: OrphanRun) -> None:
    # before the fix: the recorder closed at once with the others, last output 0.02
    driving = [m for t, m in orphan_run.outputs if t < orphan_run.kill_ns and any(m.effort)]
    assert driving, 'the thrusters never drove before the kill'
    after = [m for t, m in orphan_run.outputs if t > orphan_run.kill_ns]
    assert after, 'nothing recorded after the kill'
    assert not any(orphan_run.outputs[-1][1].effort), orphan_run.outputs[-1][1].effort


def test_the_recorder_says_it_waited_for_the_others(orphan_run: OrphanRun) -> None:
    assert re.search(r'supervisor gone: recording until the other groups stop',
                     orphan_run.text), orphan_run.text[-3000:]
    assert 'Traceback' not in orphan_run.text
