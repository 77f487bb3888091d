"""``enbarr chaos`` as a user runs it: a short run of the ROV profile split into process groups,
with two faults that remove control (the control group SIGKILLed, then SIGSTOPped): one JSON
line, every fault judged on its measured time to neutral, no traceback, the bag readable.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from support.cli import enbarr

# alone: each fault is timed in real time, and a removal fault is watched for 5 s at most. In
# CI beside a second worker (2026-11-27) the sigkill fault saw no neutral output in its 2 s
# window (the window was then the whole watch): the thruster driver's process, starved, went
# neutral late. It runs with the machine to itself.
pytestmark = [pytest.mark.e2e, pytest.mark.alone]


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict, str, Path]:
    out = tmp_path_factory.mktemp('chaos') / 'run'
    result = enbarr('chaos', '--profile', 'enbarr_sim', '--faults', 'sigkill,sigstop', '--json',
                    '--output', str(out), timeout=240)
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, (result.stdout, result.stderr[-3000:])
    return result.returncode, json.loads(lines[0]), result.stderr, out


def test_run_ends_with_one_json_line_and_no_traceback(run: tuple[int, dict, str, Path]) -> None:
    code, summary, stderr, out = run
    assert summary['faults_injected'] == 2
    assert summary['tracebacks'] == 0
    assert summary['bags_readable'] == '1/1'
    # The exit code follows the verdicts: 0 when both were safe within 0.5 s, 1 otherwise.
    assert code == (0 if summary['safe_within_0_5s'] == 2 else 1), (
        summary, stderr[-3000:], (out / 'bringup.log').read_text()[-3000:])


def test_each_removal_fault_reaches_neutral_and_is_timed(
        run: tuple[int, dict, str, Path]) -> None:
    """The instrument, not the figure: each fault is judged on a measured time to neutral.

    Whether that time is within 0.5 s is the benchmark's verdict (``docs/benchmarks.md``:
    0.25-0.35 s on a quiet machine, the 0.25 s command watchdog plus its 0.1 s period); on a
    loaded 2-core machine the watchdog's process may be scheduled late, so a test bounds it
    only by what no scheduling delay explains (5 s: twenty watchdog timeouts, and how long
    ``enbarr chaos`` watches a removal fault for its neutral output).
    """
    faults = {f['fault']: f for f in run[1]['per_fault']}
    assert set(faults) == {'sigkill:control', 'sigstop:control'}
    for f in faults.values():
        assert f['expected'] == 'actuators neutral within 0.5 s'
        t = f['time_to_safe_s']
        assert t is not None and 0.0 <= t <= 5.0, f
        assert f['passed'] == (t <= 0.5), f


def test_run_keeps_its_profile_and_logs(run: tuple[int, dict, str, Path]) -> None:
    out = run[3]
    assert 'group control died (signal SIGKILL)' in (out / 'bringup.log').read_text()
    assert 'group: control' in (out / 'chaos.yaml').read_text()
