"""``enbarr chaos`` as a user runs it: a short run of the ROV profile split into process groups,
with the faults that today's tree survives (the control group SIGKILLed, then SIGSTOPped):
one JSON line, every fault judged safe with its measured time, no traceback, the bag readable.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from support.cli import enbarr

pytestmark = pytest.mark.e2e


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict, str, Path]:
    out = tmp_path_factory.mktemp('chaos') / 'run'
    result = enbarr('chaos', 'enbarr_sim', '--faults', 'sigkill,sigstop', '--json',
                    '--out', str(out), timeout=240)
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, (result.stdout, result.stderr[-3000:])
    return result.returncode, json.loads(lines[0]), result.stderr, out


def test_run_passes_with_one_json_line(run: tuple[int, dict, str, Path]) -> None:
    code, summary, stderr, out = run
    assert code == 0, (summary, stderr[-3000:], (out / 'bringup.log').read_text()[-3000:])
    assert summary['faults_injected'] == 2 == summary['safe_within_0_5s']
    assert summary['tracebacks'] == 0
    assert summary['bags_readable'] == '1/1'


def test_each_removal_fault_reaches_neutral_within_half_a_second(
        run: tuple[int, dict, str, Path]) -> None:
    faults = {f['fault']: f for f in run[1]['per_fault']}
    assert set(faults) == {'sigkill:control', 'sigstop:control'}
    for f in faults.values():
        assert f['expected'] == 'actuators neutral within 0.5 s'
        assert f['passed'] and 0.0 <= f['time_to_safe_s'] <= 0.5, f


def test_run_keeps_its_profile_and_logs(run: tuple[int, dict, str, Path]) -> None:
    out = run[3]
    assert 'group control died (signal SIGKILL)' in (out / 'bringup.log').read_text()
    assert 'group: control' in (out / 'chaos.yaml').read_text()
