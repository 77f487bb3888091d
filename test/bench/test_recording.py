"""``enbarr bench --recording``: the recorder's cost per message, behind the one bench
command, and its refusals.
"""

from __future__ import annotations

import json
import math

import pytest

from support.cli import enbarr, refused

pytestmark = pytest.mark.e2e  # the command line, in processes


def test_recording_benchmark_prints_one_json_line() -> None:
    result = enbarr('bench', '--recording', '--messages', '100', '--repeat', '1', timeout=300)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, result.stdout
    figures = json.loads(lines[0])
    assert (figures['messages'], figures['repeat']) == (100, 1)
    mixes = {'mix: ROV chain sample', 'mix: Saucer chain sample'}
    assert mixes <= set(figures['us_per_message'])
    # A difference of two short runs: its sign is noise at 100 messages, its shape is not.
    assert all(isinstance(v, float) and math.isfinite(v)
               for v in figures['us_per_message'].values())
    assert set(figures['tap_us_per_message']) == set(figures['us_per_message'])


@pytest.mark.parametrize('args, says', [
    (['--recording', '--messages', '10'], '--messages must be >= 100 and --repeat >= 1'),
    (['--recording', '--rate', '50'], '--rate is not for --recording'),
    (['--recording', '--profile', 'saucer_sim'], 'not allowed with argument'),
    (['--chain', 'rov', '--messages', '200'], '--messages is for --recording'),
    (['--rate', '1e308'], '--rate must be at most 10000 Hz'),
])
def test_recording_options_are_refused_elsewhere(args: list[str], says: str) -> None:
    result = enbarr('bench', *args, timeout=120)
    if 'not allowed' in says:  # argparse's own refusal of exclusive options: usage and 2
        assert result.returncode == 2 and says in result.stderr
        return
    assert says in refused(result, 'bench')
