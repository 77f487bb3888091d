"""Input health for /diagnostics (``framework/health.py``): windows, thresholds, figures."""

from __future__ import annotations

import pytest

from enbarr_core.framework.health import (
    DEGRADED, ERROR, InputHealth, IntervalMeter, OK, worst)


def test_a_quiet_window_is_ok_and_totals_carry_over() -> None:
    h = InputHealth()
    h.accepted('imu/data_raw', 400)
    level, message, values = h.report(1.0)
    assert (level, message) == (OK, 'ok')
    assert values == {'imu/data_raw.accepted': 400}


def test_losses_above_the_fraction_degrade_and_are_named_with_figures() -> None:
    h = InputHealth(degraded_fraction=0.05)
    h.accepted('imu/data_raw', 370)
    h.refused('imu/data_raw', 'future', 30)
    level, message, values = h.report(1.0)
    assert level == DEGRADED
    assert message == 'degraded: imu/data_raw: refused 30 of 400 in 1 s (future 30)'
    assert values['imu/data_raw.future'] == 30


def test_the_fraction_is_a_strict_threshold_per_window() -> None:
    h = InputHealth(degraded_fraction=0.05)
    h.accepted('pose', 95)
    h.refused('pose', 'stale', 5)  # exactly 5 %: not more than the fraction
    assert h.report(1.0)[0] == OK
    h.accepted('pose', 94)
    h.refused('pose', 'stale', 6)
    assert h.report(1.0)[0] == DEGRADED
    h.accepted('pose', 100)       # the next window is judged on its own
    level, _, values = h.report(1.0)
    assert level == OK and values['pose.stale'] == 11


def test_a_reset_always_degrades_its_window() -> None:
    h = InputHealth()
    h.accepted('imu/data_raw', 400)
    h.reset('filter')
    level, message, _ = h.report(2.0)
    assert level == DEGRADED and message == 'degraded: reset filter 1x in 2 s'
    assert h.report(2.0)[0] == OK


def test_an_input_that_is_only_refused_is_degraded() -> None:
    h = InputHealth()
    h.refused('mocap/pose', 'not_newer', 3)
    assert h.report(1.0)[1] == 'degraded: mocap/pose: refused 3 of 3 in 1 s (not_newer 3)'


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match='degraded_fraction'):
        InputHealth(degraded_fraction=1.0)
    with pytest.raises(ValueError, match='accepted'):
        InputHealth().refused('x', 'accepted')


def test_worst_keeps_the_highest_level_and_the_messages_that_matter() -> None:
    assert worst((OK, 'ok'), (OK, 'ok')) == (OK, 'ok')
    assert worst((OK, 'ok'), (DEGRADED, 'degraded: a')) == (DEGRADED, 'degraded: a')
    assert worst((ERROR, 'stale'), (DEGRADED, 'degraded: a')) == (
        ERROR, 'stale; degraded: a')


def test_interval_meter_measures_the_median_period() -> None:
    m = IntervalMeter()
    for k in range(8):
        m.add(k * 2_500_000)
    assert m.period is None  # 7 intervals: not enough to say
    m.add(8 * 2_500_000)
    assert m.period == pytest.approx(0.0025)
    m.add(8 * 2_500_000)             # a repeat adds no interval
    m.add(100 * 2_500_000)           # one long gap does not move the median
    assert m.period == pytest.approx(0.0025)
    m.reset()
    m.add(0)                          # a new stream (clock restarted): no negative interval
    assert m.period == pytest.approx(0.0025)


def test_a_tolerance_must_cover_two_measured_periods() -> None:
    from enbarr_core.framework.health import too_short_for_rate
    assert too_short_for_rate('max_gap', 0.005, 'imu/data', 0.0025, 'gaps') is None
    assert too_short_for_rate('max_gap', 0.001, 'imu/data', None, 'gaps') is None  # unmeasured
    assert too_short_for_rate('max_gap', 0.0049, 'imu/data', 0.0025, 'every sample a gap') == (
        'max_gap 0.0049 s is shorter than 2 periods of imu/data (period measured 0.0025 s): '
        'every sample a gap')


def test_max_future_must_stay_under_one_measured_period() -> None:
    from enbarr_core.framework.health import future_tolerance_problem
    assert future_tolerance_problem(0.0199, 0.02, 'mocap/pose') is None
    assert future_tolerance_problem(0.5, None, 'mocap/pose') is None
    assert future_tolerance_problem(0.02, 0.02, 'mocap/pose') == (
        'max_future 0.02 s is not under the period of mocap/pose (period measured 0.02 s): '
        'one early sample could hide the next good one')


def test_totals_include_the_open_window_and_reports_count_each_sample_once() -> None:
    """Totals are folded in when a window closes (one count per sample): none is lost or
    counted twice, whether read mid-window or in the report."""
    h = InputHealth()
    h.accepted('pose')
    h.accepted('pose', 3)
    h.refused('pose', 'stale', 2)
    assert h.totals == {('pose', 'accepted'): 4, ('pose', 'stale'): 2}
    assert h.report(1.0)[2] == {'pose.accepted': 4, 'pose.stale': 2}
    h.accepted('pose')
    h.accepted('tau')
    assert h.totals == {('pose', 'accepted'): 5, ('pose', 'stale'): 2, ('tau', 'accepted'): 1}
    assert h.report(1.0)[2] == {'pose.accepted': 5, 'pose.stale': 2, 'tau.accepted': 1}
    assert h.report(1.0)[2] == {'pose.accepted': 5, 'pose.stale': 2, 'tau.accepted': 1}
