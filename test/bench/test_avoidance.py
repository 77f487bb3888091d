"""``enbarr bench --avoidance``: the safety filter's cost per step, behind the bench command."""

from __future__ import annotations

import json

import pytest

from support.cli import enbarr, refused

from enbarr_core.bench import avoidance


def test_measure_reports_each_case() -> None:
    figures = avoidance.measure(obstacles=3, repeat=1)
    assert figures['obstacles'] == 3
    assert set(figures['us_per_step']) == {'far', 'engaged', 'daqp_solve', 'force_far',
                                           'force_engaged'}
    assert all(v > 0.0 for v in figures['us_per_step'].values())
    # Within the rounding of the printed figures (us to 0.1, core % to 0.001, Pi 4 % to 0.01):
    # on a fast machine 6 x 0.059 % prints as 0.35, 1.1 % off 0.354 (CI, 2026-11-27).
    worst = max(figures['us_per_step']['far'], figures['us_per_step']['engaged'])
    assert figures['core_percent_at_50hz'] == pytest.approx(worst * 50e-6 * 100, rel=0.01,
                                                            abs=1e-3)
    assert figures['pi4_estimate_core_percent_at_50hz'] == pytest.approx(
        6 * figures['core_percent_at_50hz'], rel=0.01, abs=0.01)
    force = max(figures['us_per_step']['force_far'], figures['us_per_step']['force_engaged'])
    assert figures['force_core_percent_at_50hz'] == pytest.approx(force * 50e-6 * 100, rel=0.01,
                                                                  abs=1e-3)
    assert figures['force_pi4_estimate_core_percent_at_50hz'] == pytest.approx(
        6 * figures['force_core_percent_at_50hz'], rel=0.01, abs=0.01)


@pytest.mark.e2e
def test_avoidance_benchmark_prints_one_json_line_and_refuses_chain_options() -> None:
    result = enbarr('bench', '--avoidance', '--obstacles', '2', '--repeat', '1', timeout=120)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])['bench'] == 'avoidance'
    result = enbarr('bench', '--avoidance', '--rate', '50', timeout=120)
    assert '--rate is not for --avoidance' in refused(result, 'bench')
    result = enbarr('bench', '--chain', 'rov', '--obstacles', '3', timeout=120)
    assert '--obstacles is for --avoidance' in refused(result, 'bench')
