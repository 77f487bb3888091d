"""Unit tests of the failsafe logic (control.failsafes): each trigger, each action, the
priorities, latching and clearing, and the refusal of bad settings."""

from __future__ import annotations

import math

import pytest

from enbarr_core.control.failsafes import (
    ACTIONS, describe, FailsafeSetting, FailsafeSettings, KINDS, most_severe, NONE,
    Observation, Supervisor)

pytestmark = pytest.mark.unit

# ArduSub's numbers, typed from its source (ArduSub/Parameters.cpp and config.h):
# FS_PILOT_TIMEOUT 3 s, FS_PRESS_MAX 105000 Pa, FS_TEMP_MAX 62 degC; GCS timeout 5 s.
SETTINGS = {
    'pilot_input': FailsafeSetting('neutral', 3.0),
    'surface_link': FailsafeSetting('neutral', 5.0),
    'leak': FailsafeSetting('surface'),
    'battery_low': FailsafeSetting('warn', 14.0, 10.0),
    'battery_critical': FailsafeSetting('surface', 13.2, 10.0),
    'depth': FailsafeSetting('stabilize', 0.5),
    'attitude': FailsafeSetting('neutral', 2.0),
    'pressure': FailsafeSetting('warn', 105000.0),
    'temperature': FailsafeSetting('warn', 62.0),
}
QUIET = Observation(pilot_input_age=0.1, surface_link_age=0.1, leak=False,
                    battery_voltage=16.0, depth_age=0.1, pressure=101000.0, temperature=30.0)


def supervisor(**changes: FailsafeSetting) -> Supervisor:
    return Supervisor(FailsafeSettings({**SETTINGS, **changes}))


def obs(**changes: object) -> Observation:
    return Observation(**{**QUIET.__dict__, **changes})


def test_the_actions_are_ordered_from_the_least_to_the_most_severe():
    assert ACTIONS == ('disabled', 'warn', 'stabilize', 'manual', 'surface', 'neutral')
    assert most_severe(['warn', 'neutral', 'surface']) == 'neutral'
    assert most_severe(['warn', 'surface', 'stabilize']) == 'surface'
    assert most_severe(['disabled']) == NONE
    assert most_severe([]) == NONE


def test_nothing_trips_on_a_quiet_vehicle():
    v = supervisor().evaluate(QUIET, 10.0)
    assert (v.action, v.active, v.tripped) == (NONE, (), ())


@pytest.mark.parametrize('name, o, reason', [
    ('pilot_input', dict(pilot_input_age=3.1), 'no pilot input for 3.1 s (limit 3 s)'),
    ('surface_link', dict(surface_link_age=5.1, pilot_input_age=0.0),
     'no message from the surface for 5.1 s (limit 5 s)'),
    ('leak', dict(leak=True), 'leak detected'),
    ('depth', dict(depth_hold=True, depth_age=0.6), 'depth 0.6 s old (limit 0.5 s)'),
    ('attitude', dict(attitude_problem='no IMU samples', attitude_age=2.5),
     'no IMU samples for 2.5 s (limit 2 s)'),
    ('pressure', dict(pressure=106000.0), 'inside pressure 106000 Pa above 105000 Pa'),
    ('temperature', dict(temperature=63.0), 'inside temperature 63 degC above 62 degC'),
])
def test_each_trigger_trips_its_failsafe_with_its_action_and_reason(name, o, reason):
    s = supervisor()
    v = s.evaluate(obs(**o), 20.0)
    assert [t.name for t in v.tripped] == [name]
    trip = v.tripped[0]
    assert (trip.action, trip.reason, trip.since) == (SETTINGS[name].action, reason, 20.0)
    assert v.action == SETTINGS[name].action


@pytest.mark.parametrize('name, o', [
    ('pilot_input', dict(pilot_input_age=3.0)),    # at the limit: not yet
    ('surface_link', dict(surface_link_age=5.0)),
    ('depth', dict(depth_hold=False, depth_age=9.0)),  # only depth hold needs the depth
    ('attitude', dict(attitude_problem='x', attitude_age=2.0)),
    ('attitude', dict(attitude_problem=None, attitude_age=9.0)),
    ('pressure', dict(pressure=105000.0)),
    ('temperature', dict(temperature=62.0)),
])
def test_just_inside_the_limits_nothing_trips(name, o):
    assert supervisor().evaluate(obs(**o), 1.0).active == ()


def test_an_input_never_heard_does_not_trip():
    never = Observation(pilot_input_age=0.0, surface_link_age=0.0)
    assert supervisor().evaluate(never, 100.0).active == ()


def test_a_depth_never_heard_in_depth_hold_trips():
    v = supervisor().evaluate(obs(depth_hold=True, depth_age=None), 1.0)
    assert v.active[0].reason == 'no depth sensor heard'


def test_the_depth_trip_outlives_the_mode_it_forced_and_clears_on_a_fresh_depth():
    s = supervisor()
    s.evaluate(obs(depth_hold=True, depth_age=1.0), 1.0)
    v = s.evaluate(obs(depth_hold=False, depth_age=2.0), 2.0)   # now in stabilize
    assert [t.name for t in v.active] == ['depth']
    v = s.evaluate(obs(depth_hold=False, depth_age=0.1), 3.0)
    assert (v.active, v.cleared) == ((), ('depth',))


def test_battery_must_stay_low_for_its_time_and_a_sag_does_not_trip():
    s = supervisor()
    assert s.evaluate(obs(battery_voltage=13.9), 0.0).active == ()
    assert s.evaluate(obs(battery_voltage=13.9), 9.9).active == ()
    assert s.evaluate(obs(battery_voltage=14.5), 10.0).active == ()   # recovered: starts over
    assert s.evaluate(obs(battery_voltage=13.9), 11.0).active == ()
    v = s.evaluate(obs(battery_voltage=13.9), 21.0)
    assert [t.name for t in v.tripped] == ['battery_low']
    assert v.tripped[0].reason == 'battery 13.90 V below 14 V for 10.0 s'
    assert v.action == 'warn'


def test_low_then_critical_battery_warns_then_surfaces():
    s = supervisor()
    s.evaluate(obs(battery_voltage=13.8), 0.0)
    assert s.evaluate(obs(battery_voltage=13.8), 10.0).action == 'warn'
    s.evaluate(obs(battery_voltage=13.0), 11.0)
    v = s.evaluate(obs(battery_voltage=13.0), 21.0)
    assert [t.name for t in v.active] == ['battery_low', 'battery_critical']
    assert v.action == 'surface'


def test_the_most_severe_action_wins_and_the_next_takes_over_when_it_clears():
    s = supervisor()
    v = s.evaluate(obs(leak=True, pilot_input_age=4.0, temperature=70.0), 5.0)
    assert {t.name for t in v.active} == {'pilot_input', 'leak', 'temperature'}
    assert v.action == 'neutral'
    v = s.evaluate(obs(leak=True, pilot_input_age=0.0, temperature=70.0), 6.0)
    assert v.cleared == ('pilot_input',)
    assert v.action == 'surface'


def test_link_loss_clears_when_the_link_returns_and_keeps_its_trip_time():
    s = supervisor()
    s.evaluate(obs(surface_link_age=6.0, pilot_input_age=6.0), 30.0)
    v = s.evaluate(obs(surface_link_age=7.0, pilot_input_age=7.0), 31.0)
    assert [t.since for t in v.active] == [30.0, 30.0]   # when it tripped, not now
    assert v.tripped == ()
    v = s.evaluate(obs(surface_link_age=0.0, pilot_input_age=0.0), 32.0)
    assert (v.action, set(v.cleared)) == (NONE, {'pilot_input', 'surface_link'})


def test_a_leak_latches_until_the_operator_clears_it_dry():
    s = supervisor()
    s.evaluate(obs(leak=True), 1.0)
    v = s.evaluate(obs(leak=False), 2.0)    # the sensor dries: the leak stays
    assert (v.action, v.cleared) == ('surface', ())
    v, said = s.clear(obs(leak=True), 3.0)   # still wet: refused
    assert v.action == 'surface'
    assert said == 'nothing to clear; still holding: leak (leak detected)'
    v, said = s.clear(obs(leak=False), 4.0)
    assert (v.action, v.cleared, said) == (NONE, ('leak',), 'cleared leak')


def test_battery_critical_latches_and_clears_only_above_its_voltage():
    s = supervisor()
    s.evaluate(obs(battery_voltage=12.0), 0.0)
    s.evaluate(obs(battery_voltage=12.0), 10.0)
    v = s.evaluate(obs(battery_voltage=16.0), 11.0)   # rested pack: still latched
    assert v.action == 'surface'
    v, said = s.clear(obs(battery_voltage=13.5), 12.0)
    assert said == ('cleared battery_critical; still holding: battery_low '
                    '(battery 13.50 V below 14 V for 0.0 s)')
    assert v.action == 'warn'
    v, said = s.clear(obs(battery_voltage=16.0), 13.0)
    assert (v.action, said) == (NONE, 'cleared battery_low')


def test_a_clear_leaves_the_non_latching_failsafes_to_their_inputs():
    s = supervisor()
    s.evaluate(obs(pilot_input_age=9.0), 1.0)
    v, said = s.clear(obs(pilot_input_age=9.0), 2.0)
    assert (v.action, said) == ('neutral', 'nothing to clear')


def test_a_disabled_failsafe_never_trips_and_disabling_drops_an_active_one():
    s = supervisor(leak=FailsafeSetting('disabled'))
    assert s.evaluate(obs(leak=True), 1.0).active == ()
    s = supervisor()
    s.evaluate(obs(leak=True), 1.0)
    s.settings = FailsafeSettings({**SETTINGS, 'leak': FailsafeSetting('disabled')})
    assert s.evaluate(obs(leak=True), 2.0).action == NONE


def test_describe_names_each_trip_its_action_time_and_reason():
    s = supervisor()
    v = s.evaluate(obs(leak=True, temperature=70.0), 12.345)
    assert describe(v.active) == ('leak: surface since 12.35 s (leak detected); temperature: '
                                  'warn since 12.35 s (inside temperature 70 degC above 62 '
                                  'degC)')
    assert describe(()) == 'none'


@pytest.mark.parametrize('changes, message', [
    (dict(leak=FailsafeSetting('neutral')),
     "leak.action: 'neutral' is not one of disabled, warn, surface"),
    (dict(pressure=FailsafeSetting('surface', 105000.0)),
     "pressure.action: 'surface' is not one of disabled, warn"),
    (dict(pilot_input=FailsafeSetting('neutral', 0.0)),
     'pilot_input.timeout: 0.0 s must be > 0'),
    (dict(attitude=FailsafeSetting('neutral', math.nan)),
     'attitude.timeout: nan must be finite'),
    (dict(battery_low=FailsafeSetting('warn', 14.0, -1.0)),
     'battery_low.time: -1.0 s must be finite and >= 0'),
    (dict(battery_critical=FailsafeSetting('surface', 14.5, 10.0)),
     'battery_critical.voltage: 14.5 V must be below battery_low.voltage (14.0 V)'),
    (dict(warp_core=FailsafeSetting('warn')), "unknown failsafe 'warp_core'"),
])
def test_bad_settings_are_refused_naming_the_failsafe(changes, message):
    with pytest.raises(ValueError, match='^' + message.replace('(', r'\(').replace(')', r'\)')):
        supervisor(**changes)


def test_every_failsafe_mirrors_an_ardusub_parameter_and_allows_disabled_and_warn():
    assert set(KINDS) == set(SETTINGS)
    for kind in KINDS.values():
        assert kind.actions[:2] == ('disabled', 'warn'), kind.name
    assert {k.ardusub for k in KINDS.values()} >= {
        'FS_PILOT_INPUT', 'FS_GCS_ENABLE', 'FS_LEAK_ENABLE', 'FS_BATT_ENABLE', 'FS_EKF_ACTION',
        'FS_PRESS_ENABLE', 'FS_TEMP_ENABLE'}
