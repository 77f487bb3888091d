"""``enbarr bench --fusion``: what it measures (every obstacle ahead matched, none astern), and
its refusals. Timing itself is the benchmark's business, not a test's.
"""

from __future__ import annotations

import json
import math

import pytest

from enbarr_core.bench import fusion
from enbarr_core.commands.main import main

pytestmark = pytest.mark.unit


def test_the_scene_is_what_the_benchmark_claims_to_measure():
    figures = fusion.measure(10, 30)
    # every other obstacle ahead and in view (5), each with its box; the stray box unmatched
    assert figures['matched_last'] == 5
    for key in ('ms_per_detections_p50', 'ms_per_detections_p90', 'ms_per_detections_max',
                'ms_per_obstacles_p50'):
        assert math.isfinite(figures[key]) and figures[key] > 0.0
    assert figures['pi4_core_fraction_estimate'] == pytest.approx(
        figures['core_fraction'] * 6.0, rel=1e-2, abs=1e-4)  # printed to 0.0001


def test_the_command_prints_one_json_line(capsys):
    assert main(['bench', '--fusion', '--obstacles', '4', '--frames', '20']) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures['benchmark'] == 'fusion' and figures['obstacles'] == 4
    assert figures['matched_last'] == 2


@pytest.mark.parametrize('args, says', [
    (['--fusion', '--frames', '5'], '--frames >= 20'),
    (['--fusion', '--rate', '5'], '--rate is not for --fusion'),
    (['--fusion', '--scans', '100'], '--scans is not for --fusion'),
])
def test_fusion_options_are_refused(args, says, capsys):
    assert main(['bench', *args]) != 0
    assert says in capsys.readouterr().err
