"""Arbitration of named command sources (pure tier): priority, takeover, stop, config errors.

Times are integer nanoseconds chosen by hand; a source is live through its timeout
(inclusive) and not live from timeout + 1 ns on.
"""

from __future__ import annotations

import pytest

from enbarr_core.control.arbitration import (
    Arbiter, ArbiterSettings, CommandSource, NONE, STOPPED)

S = 1_000_000_000  # ns per second
MS = 1_000_000
T0 = 5_000 * S

STATION = CommandSource('station', 'surface_command/twist', 10, 0.5)
AUTONOMY = CommandSource('autonomy', 'autonomy/twist', 1, 1.0)


def arbiter() -> Arbiter:
    # Listed low first: the order of the list must not decide, the priority must.
    return Arbiter(ArbiterSettings((AUTONOMY, STATION)))


def test_nothing_drives_before_any_command():
    a = arbiter()
    assert a.select(T0) is None
    assert a.label(T0) == NONE


def test_a_lone_low_priority_source_drives():
    a = arbiter()
    a.offer('autonomy', T0)
    assert a.select(T0 + 10 * MS) == 'autonomy'


def test_the_higher_priority_takes_over_and_holds_while_live():
    a = arbiter()
    a.offer('autonomy', T0)
    a.offer('station', T0 + 100 * MS)
    assert a.select(T0 + 100 * MS) == 'station'
    a.offer('autonomy', T0 + 200 * MS)  # autonomy keeps sending: station still drives
    assert a.select(T0 + 200 * MS) == 'station'


def test_the_lower_takes_over_when_the_higher_falls_silent_after_its_timeout():
    a = arbiter()
    a.offer('station', T0)
    a.offer('autonomy', T0 + 400 * MS)
    assert a.select(T0 + 500 * MS) == 'station'          # exactly the station's 0.5 s
    assert a.select(T0 + 500 * MS + 1) == 'autonomy'     # 1 ns later


def test_the_higher_drives_again_as_soon_as_it_returns():
    a = arbiter()
    a.offer('station', T0)
    a.offer('autonomy', T0 + 900 * MS)
    assert a.select(T0 + 900 * MS) == 'autonomy'
    a.offer('station', T0 + 950 * MS)
    assert a.select(T0 + 950 * MS) == 'station'


def test_all_silent_means_nothing_drives():
    a = arbiter()
    a.offer('station', T0)
    a.offer('autonomy', T0)
    assert a.select(T0 + 1 * S) == 'autonomy'
    assert a.select(T0 + 1 * S + 1) is None
    assert a.label(T0 + 1 * S + 1) == NONE


def test_stop_wins_over_every_live_source_until_released():
    a = arbiter()
    a.set_stop(True)
    a.offer('station', T0)
    a.offer('autonomy', T0)
    assert a.select(T0) is None
    assert a.label(T0) == STOPPED
    assert a.select(T0 + 100 * S) is None  # the stop has no timeout
    a.set_stop(False)
    a.offer('autonomy', T0 + 100 * S)
    assert a.select(T0 + 100 * S) == 'autonomy'


def test_withdraw_hands_over_at_once():
    a = arbiter()
    a.offer('station', T0)
    a.offer('autonomy', T0)
    a.withdraw('station')
    assert a.select(T0 + 1) == 'autonomy'


def test_a_clock_that_went_back_makes_a_source_not_live():
    a = arbiter()
    a.offer('station', T0)
    assert a.select(T0 - 1) is None


def test_an_unknown_source_is_an_error():
    with pytest.raises(KeyError, match='nobody'):
        arbiter().offer('nobody', T0)


def test_from_arrays_builds_the_sources_in_order():
    s = ArbiterSettings.from_arrays(['station', 'autonomy'],
                                    ['surface_command/twist', 'autonomy/twist'], [10, 1],
                                    [0.5, 1.0])
    assert s.sources == (STATION, AUTONOMY)


@pytest.mark.parametrize('names, topics, priorities, timeouts, field', [
    (['a', 'b'], ['x'], [1, 2], [1.0, 1.0], 'sources.topics'),
    (['a', 'b'], ['x', 'y'], [1], [1.0, 1.0], 'sources.priorities'),
    (['a', 'b'], ['x', 'y'], [1, 2], [1.0], 'sources.timeouts'),
    ([], [], [], [], 'sources.names'),
    (['a', 'a'], ['x', 'y'], [1, 2], [1.0, 1.0], r'sources.names\[1\]'),
    (['a', 'b'], ['x', 'x'], [1, 2], [1.0, 1.0], r'sources.topics\[1\]'),
    (['a', 'b'], ['x', 'y'], [3, 3], [1.0, 1.0], r'sources.priorities\[1\]'),
    (['a', 'b'], ['x', 'y'], [1, 2], [1.0, 0.0], r'sources.timeouts\[1\]'),
    (['a', 'b'], ['x', 'y'], [1, 2], [-1.0, 1.0], r'sources.timeouts\[0\]'),
    (['a', 'b'], ['x', 'y'], [1, 2], [float('inf'), 1.0], r'sources.timeouts\[0\]'),
    (['a', ''], ['x', 'y'], [1, 2], [1.0, 1.0], r'sources.names\[1\]'),
    (['stop', 'b'], ['x', 'y'], [1, 2], [1.0, 1.0], r'sources.names\[0\]'),
    (['a', 'b'], ['x', ''], [1, 2], [1.0, 1.0], r'sources.topics\[1\]'),
])
def test_bad_configurations_are_refused_naming_the_field(names, topics, priorities, timeouts,
                                                         field):
    with pytest.raises(ValueError, match=field):
        ArbiterSettings.from_arrays(names, topics, priorities, timeouts)
