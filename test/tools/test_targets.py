"""A scenario's targets (enbarr_core.tools.targets): how they are read and checked, and the
verdict on a run's figures. Pure: figures are hand-made dicts, the targets typed here."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from enbarr_core.framework.errors import ProfileError
from enbarr_core.tools.failsafe_metrics import FAILSAFE_FIGURES, FAILSAFE_FLAGS
from enbarr_core.tools.metrics import figures_of
from enbarr_core.tools.scenario import scenario_spec
from enbarr_core.tools.avoidance_metrics import AVOIDANCE_FIGURES
from enbarr_core.tools.vision_metrics import VISION_FIGURES
from enbarr_core.tools.targets import describe, EXIT_FAILED, judge, parse_targets, Target


def targets(raw, kind: str = 'station_keeping') -> tuple[Target, ...]:
    return parse_targets(raw, kind, figures_of(kind), '/here/s.yaml')


def error(raw, kind: str = 'station_keeping') -> str:
    with pytest.raises(ProfileError) as info:
        targets(raw, kind)
    return str(info.value)


# -- reading ----------------------------------------------------------------------------------
def test_bounds_are_read_as_written() -> None:
    got = targets({'position_error_rms_m': {'max': 0.01}, 'time_to_settle_s': {'min': 1},
                   'mode_changes': {'min': 1, 'max': 1}, 'settled_in_time': True,
                   'settled': False})
    assert got == (Target('position_error_rms_m', high=0.01),
                   Target('time_to_settle_s', low=1.0),
                   Target('mode_changes', low=1.0, high=1.0),
                   Target('settled_in_time', expected=True), Target('settled', expected=False))


@pytest.mark.parametrize(('raw', 'message'), [
    (None, '/here/s.yaml: scenario.targets: required: the figures this scenario must achieve'),
    ({}, 'scenario.targets: expected a mapping of figure -> bound'),
    ([0.05], 'scenario.targets: expected a mapping of figure -> bound'),
    ({'position_eror_rms_m': {'max': 0.05}},
     "scenario.targets: 'position_eror_rms_m' is not a figure of a station_keeping scenario; "
     "did you mean 'position_error_rms_m'?"),
    ({'wobble': {'max': 1}}, "'wobble' is not a figure of a station_keeping scenario; its "
     'figures: mode_changes, thrust_saturation_s, final_speed_mps, automatic_s,'),
    ({'cross_track_rms_m': {'max': 0.1}},
     "'cross_track_rms_m' is not a figure of a station_keeping scenario"),
    ({'position_error_rms_m': 0.05}, 'scenario.targets.position_error_rms_m: expected {max: N}'
     ', {min: N} or {min: N, max: N} (inclusive), got 0.05'),
    ({'position_error_rms_m': {'maximum': 0.05}}, "expected {max: N}, {min: N} or {min: N, "
     "max: N} (inclusive), got {'maximum': 0.05}"),
    ({'position_error_rms_m': {}}, 'scenario.targets.position_error_rms_m: expected {max: N}'),
    ({'position_error_rms_m': {'max': 'small'}},
     "scenario.targets.position_error_rms_m: expected {max: N}, {min: N} or {min: N, max: N} "
     "(inclusive): max must be a finite number, got 'small'"),
    ({'position_error_rms_m': {'max': float('nan')}}, 'max must be a finite number, got nan'),
    ({'position_error_rms_m': {'max': True}}, 'max must be a finite number, got True'),
    ({'mode_changes': {'min': 2, 'max': 1}},
     'scenario.targets.mode_changes: min 2.0 is above max 1.0'),
    ({'settled_in_time': 'yes'},
     "scenario.targets.settled_in_time: a yes/no figure: expected true or false, got 'yes'"),
    ({'settled_in_time': {'min': 1}}, 'a yes/no figure: expected true or false'),
])
def test_bad_targets_name_the_file_and_figure(raw, message) -> None:
    assert message in error(raw)


def test_a_figure_of_another_kind_is_refused_with_its_own_kinds_list() -> None:
    message = error({'position_error_rms_m': {'max': 0.05}}, kind='path')
    assert "'position_error_rms_m' is not a figure of a path scenario" in message
    assert 'cross_track_rms_m' in message and 'settled' not in message
    run = error({'cross_track_rms_m': {'max': 0.05}}, kind='run')
    # every kind's figures, then the collision avoidance's (a run may avoid too), then the
    # camera's, then the failsafes'
    assert run.endswith('its figures: ' + ', '.join(
        ('mode_changes', 'thrust_saturation_s', 'final_speed_mps', *AVOIDANCE_FIGURES,
         *VISION_FIGURES, *FAILSAFE_FIGURES, *FAILSAFE_FLAGS)))


def test_the_scenario_section_requires_its_targets() -> None:
    """scenario_spec reads them (and refuses a section without), naming the file."""
    section = {'duration': 60.0, 'kind': 'path'}
    with pytest.raises(ProfileError, match=r'/here/s\.yaml: scenario\.targets: required'):
        scenario_spec(SimpleNamespace(scenario=section, path='/here/s.yaml'))
    spec = scenario_spec(SimpleNamespace(scenario={**section, 'targets': {
        'all_waypoints_visited': True}}, path='/here/s.yaml'))
    assert spec.targets == (Target('all_waypoints_visited', expected=True),)


# -- the verdict ------------------------------------------------------------------------------
STATED = (Target('position_error_rms_m', high=0.01), Target('time_to_settle_s', high=10.0),
          Target('mode_changes', low=1.0, high=1.0), Target('settled_in_time', expected=True))
GOOD = {'position_error_rms_m': 0.0024, 'time_to_settle_s': 5.25, 'mode_changes': 1,
        'settled_in_time': True}


def test_every_target_met_is_a_pass() -> None:
    v = judge(GOOD, STATED)
    assert v['verdict'] == 'pass' and v['failed'] == []
    assert v['targets'] == {
        'position_error_rms_m': {'max': 0.01, 'value': 0.0024, 'pass': True},
        'time_to_settle_s': {'max': 10.0, 'value': 5.25, 'pass': True},
        'mode_changes': {'min': 1.0, 'max': 1.0, 'value': 1, 'pass': True},
        'settled_in_time': {'expected': True, 'value': True, 'pass': True}}


def test_bounds_are_inclusive() -> None:
    at = {**GOOD, 'position_error_rms_m': 0.01, 'time_to_settle_s': 10.0}
    assert judge(at, STATED)['verdict'] == 'pass'


@pytest.mark.parametrize(('change', 'failed'), [
    ({'position_error_rms_m': 0.0101}, ['position_error_rms_m']),         # above a max
    ({'mode_changes': 0}, ['mode_changes']),                               # below a min
    ({'mode_changes': 2}, ['mode_changes']),                               # fell back: 2
    ({'settled_in_time': False}, ['settled_in_time']),                     # the wrong answer
    ({'time_to_settle_s': None}, ['time_to_settle_s']),                    # never settled
    ({'time_to_settle_s': float('nan')}, ['time_to_settle_s']),
    ({'position_error_rms_m': 0.02, 'settled_in_time': False},
     ['position_error_rms_m', 'settled_in_time']),                         # in stated order
])
def test_a_target_missed_fails_and_is_named(change, failed) -> None:
    v = judge({**GOOD, **change}, STATED)
    assert v['verdict'] == 'fail' and v['failed'] == failed
    for name in failed:
        assert v['targets'][name]['pass'] is False


def test_a_figure_the_run_did_not_produce_fails() -> None:
    """A run that never reached automatic has an error and no window figures."""
    v = judge({'error': 'never in automatic mode', 'mode_changes': 1}, STATED)
    assert v['verdict'] == 'fail'
    assert v['failed'] == ['error', 'position_error_rms_m', 'time_to_settle_s',
                           'settled_in_time']
    assert v['targets']['position_error_rms_m'] == {'max': 0.01, 'value': None, 'pass': False}


def test_an_error_fails_even_with_every_stated_target_met() -> None:
    v = judge({**GOOD, 'error': 'the evaluation window is empty'}, STATED)
    assert v['verdict'] == 'fail' and v['failed'] == ['error']


def test_a_yes_no_target_takes_only_a_boolean() -> None:
    """1 == True in Python; a count of 1 is not the answer yes."""
    assert not Target('settled', expected=True).met_by(1)
    assert not Target('mode_changes', high=1.0).met_by(True)


def test_people_read_each_target_on_one_line() -> None:
    v = judge({**GOOD, 'time_to_settle_s': None}, STATED)['targets']
    assert describe('position_error_rms_m', v['position_error_rms_m']) == \
        'position_error_rms_m = 0.0024, <= 0.01: pass'
    assert describe('time_to_settle_s', v['time_to_settle_s']) == \
        'time_to_settle_s = none, <= 10: FAIL'
    assert describe('mode_changes', v['mode_changes']) == 'mode_changes = 1, in [1, 1]: pass'
    assert describe('settled_in_time', v['settled_in_time']) == \
        'settled_in_time = true, is true: pass'


def test_the_failed_exit_status_is_one() -> None:
    """1, as ``enbarr chaos`` when a fault failed; 2 stays a user's mistake (commands.main)."""
    assert EXIT_FAILED == 1
