"""Unit tests of the failsafe figures (tools.failsafe_metrics) on hand-made bags."""

from __future__ import annotations

from types import SimpleNamespace as NS

import pytest

from enbarr_core.tools.failsafe_metrics import failsafe_figures

pytestmark = pytest.mark.unit

S = 1_000_000_000
T0 = 1 * S   # world time 0


def profile(*nodes: tuple[str, dict]) -> NS:
    return NS(parameters={}, nodes=[NS(plugin=p, parameters=params) for p, params in nodes])


def odometry(z_of_t) -> list:
    """100 Hz from world time 0 to 30 s; ``z_of_t``: the height [m] at world time t [s]."""
    return [(T0 + k * S // 100, NS(pose=NS(pose=NS(position=NS(z=z_of_t(k / 100))))))
            for k in range(3000)]


def climb_from(t_start: float, z0: float, rate: float):
    return lambda t: min(0.0, z0 + max(0.0, t - t_start) * rate)


def test_a_leak_is_timed_from_the_leak_to_the_action_and_to_the_climb():
    msgs = {
        '/leak': [(T0, NS(data=False)), (T0 + 12 * S, NS(data=True))],
        '/failsafe/action': [(T0, NS(data='none')), (T0 + 12 * S + S // 10, NS(data='surface'))],
        '/failsafe/active': [(T0 + 12 * S + S // 10,
                              NS(data='leak: surface since 12.1 s (leak detected)'))],
        '/sim/odometry': odometry(climb_from(13.0, -2.0, 0.25)),
    }
    f = failsafe_figures(msgs, profile(('failsafe', {})), T0)
    assert f['failsafe'] == 'leak'
    assert f['failsafe_event_s'] == 12.0
    assert f['failsafe_action_s'] == 0.1
    # climbing at 0.25 m/s from 13 s: the rise over the last 0.5 s reaches 0.2 m/s at 13.4 s
    assert f['failsafe_safe_s'] == pytest.approx(1.4, abs=0.011)
    assert f['failsafe_surfaced'] is True


def test_the_battery_event_is_the_crossing_of_the_failsafe_that_acted_not_the_warning():
    volts = [(T0 + k * S // 5, NS(voltage=14.5 - 0.1 * k / 5)) for k in range(100)]
    msgs = {
        '/battery': volts,   # below 14.0 V at 5 s, below 13.2 V at 13 s
        '/failsafe/action': [(T0 + 7 * S, NS(data='warn')), (T0 + 15 * S, NS(data='surface'))],
        '/failsafe/active': [
            (T0 + 7 * S, NS(data='battery_low: warn since 7.00 s (x)')),
            (T0 + 15 * S, NS(data='battery_low: warn since 7.00 s (x); battery_critical: '
                                  'surface since 15.00 s (y)'))],
        '/sim/odometry': odometry(lambda t: -1.0),   # never climbs
    }
    f = failsafe_figures(msgs, profile(('failsafe', {})), T0)
    assert f['failsafe'] == 'battery_critical'
    assert f['failsafe_event_s'] == pytest.approx(13.2, abs=0.01)   # first sample below 13.2 V
    assert f['failsafe_action_s'] == pytest.approx(1.8, abs=0.01)
    assert f['failsafe_safe_s'] is None        # never safe: fails any target
    assert f['failsafe_surfaced'] is False


def test_neutral_is_safe_at_the_first_zero_force_and_pilot_loss_counts_from_the_last_twist():
    wrench = lambda fx: NS(wrench=NS(force=NS(x=fx, y=0.0, z=0.0),  # noqa: E731
                                     torque=NS(x=0.0, y=0.0, z=0.0)))
    msgs = {
        '/surface_command/twist': [(T0 + k * S // 10, NS()) for k in range(101)],  # to 10 s
        '/failsafe/action': [(T0 + 13 * S + S // 10, NS(data='neutral'))],
        '/failsafe/active': [(T0 + 13 * S + S // 10,
                              NS(data='pilot_input: neutral since 13.1 s (z)'))],
        '/force_command': [(T0 + 13 * S, wrench(5.0)), (T0 + 13 * S + S // 10, wrench(2.0)),
                           (T0 + 13 * S + S // 5, wrench(0.0))],
        '/sim/odometry': odometry(lambda t: -1.0),
    }
    f = failsafe_figures(msgs, profile(('failsafe', {})), T0)
    assert (f['failsafe'], f['failsafe_event_s']) == ('pilot_input', 10.0)
    assert f['failsafe_action_s'] == 3.1
    assert f['failsafe_safe_s'] == 3.2
    assert 'failsafe_surfaced' not in f


def test_no_figures_when_only_warnings_acted():
    msgs = {'/failsafe/action': [(T0, NS(data='none')), (T0 + S, NS(data='warn'))]}
    assert failsafe_figures(msgs, profile(('failsafe', {})), T0) == {}
