"""``enbarr bench --perception``: what it measures (the scene it casts gives the obstacles it
should), and its refusals. Timing itself is the benchmark's business, not a test's.
"""

from __future__ import annotations

import math

import pytest

from enbarr_core.bench import perception
from enbarr_core.commands.main import main


def test_the_scene_is_what_the_benchmark_claims_to_measure():
    figures = perception.measure(60)
    # three buoys and the two walls of the L (the first buoy hides a piece of the far wall:
    # at least two segments)
    assert figures['obstacles'] >= 5 and figures['clusters'] >= 5
    assert figures['rays'] == 360 and figures['scans'] == 60
    for key in ('ms_per_scan_p50', 'ms_per_scan_p90', 'ms_per_scan_max',
                'markers_ms_per_scan_p50'):
        assert math.isfinite(figures[key]) and figures[key] > 0.0
    assert figures['pi4_core_fraction_estimate'] == pytest.approx(
        figures['core_fraction_at_5_5_hz'] * 6.0, rel=1e-2, abs=1e-4)  # printed to 0.0001


@pytest.mark.parametrize('args, says', [
    (['--perception', '--scans', '10'], '--scans must be >= 50'),
    (['--perception', '--rate', '5'], '--rate is not for --perception'),
    (['--chain', 'rov', '--scans', '100'], '--scans is for --perception'),
    (['--recording', '--scans', '100'], '--scans'),
])
def test_perception_options_are_refused_elsewhere(args, says, capsys):
    assert main(['bench', *args]) != 0
    assert says in capsys.readouterr().err
