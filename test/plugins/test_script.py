"""The timed-script parser (pure) and the surface script's verbs."""

from __future__ import annotations

import pytest

from enbarr_plugins.operator.script import Step, no_arguments, numbers, parse_script
from enbarr_plugins.operator.scripted_commands import VERBS, IoRequest, ScriptedCommandsSettings

LINES = ['0.0 twist 0 0 -0.2 0 0 0', '', '4.0 io gpio_12 true', '4.0 io manipulator 50',
         '9.0 stop']


def test_lines_become_typed_steps_in_time_order():
    steps = parse_script(LINES, VERBS)
    assert steps == (
        Step(0.0, 'twist', (0.0, 0.0, -0.2, 0.0, 0.0, 0.0), 0),
        Step(4.0, 'io', IoRequest('gpio_12', True), 2),
        Step(4.0, 'io', IoRequest('manipulator', 50), 3),
        Step(9.0, 'stop', None, 4),
    )
    assert isinstance(steps, tuple)


def test_the_parser_takes_any_verbs():
    verbs = {'press': lambda args: args[0], 'sticks': lambda a: numbers(a, 3, 'S W Y', -1, 1)}
    assert parse_script(['1 press triangle', '2 sticks 0.5 0 -1'], verbs) == (
        Step(1.0, 'press', 'triangle', 0), Step(2.0, 'sticks', (0.5, 0.0, -1.0), 1))


@pytest.mark.parametrize('line, match', [
    ('soon twist 0 0 0 0 0 0', r"^script\[1\] 'soon twist 0 0 0 0 0 0': expected a time"),
    ('-1 stop', r"^script\[1\] '-1 stop': time must be finite and >= 0"),
    ('nan stop', 'time must be finite'),
    ('2.0', r'expected "twist", "io", "stop" after the time'),
    ('2.0 jump', r'expected "twist", "io", "stop" after the time'),
    ('2.0 twist 1 2 3', r'twist takes 6 finite numbers u v w p q r'),
    ('2.0 twist 1 2 3 4 5 x', r'twist takes 6 numbers u v w p q r'),
    ('2.0 twist 1 2 3 4 5 inf', r'twist takes 6 finite numbers'),
    ('2.0 io gpio_12', r'io takes an executor and one value'),
    ('2.0 io gpio_12 {a:1}', r"io value '{a:1}' is not a bool, int, float or string"),
    ('2.0 stop now', r'stop takes no arguments'),
])
def test_errors_name_the_line(line, match):
    with pytest.raises(ValueError, match=match):
        parse_script(['1.0 stop', line], VERBS)


def test_times_must_not_decrease():
    with pytest.raises(ValueError, match=r"^script\[1\] '1.0 stop': times must not decrease"):
        parse_script(['2.0 stop', '1.0 stop'], VERBS)


def test_numbers_within_bounds():
    with pytest.raises(ValueError, match='within -1..1'):
        numbers(['2'], 1, 'S', -1, 1)
    no_arguments([])


def test_settings_parse_the_script_once():
    settings = ScriptedCommandsSettings.from_params({'script': LINES, 'rate': 10.0})
    assert len(settings.script) == 4 and settings.rate == 10.0


def test_a_note_after_a_step_is_kept_and_a_comment_line_skipped():
    steps = parse_script(['# the demo', '1.0 io manipulator true  # a refusal on purpose',
                          '2.0 stop #quiet'], VERBS)
    assert steps == (Step(1.0, 'io', IoRequest('manipulator', True), 1,
                          'a refusal on purpose'),
                     Step(2.0, 'stop', None, 2, 'quiet'))


def test_a_hash_inside_a_word_is_no_note():
    assert parse_script(['1.0 io name a#b'], VERBS)[0].value == IoRequest('name', 'a#b')


@pytest.mark.parametrize('text, value', [
    ('1e3', 1000.0),   # YAML 1.1 (yaml.safe_load) read the string '1e3'
    ('off', 'off'),    # ... and False
    ('true', True),
    ('400', 400),
])
def test_io_values_are_read_as_profile_values(text, value):
    got = parse_script([f'1.0 io manipulator {text}'], VERBS)[0].value.value
    assert got == value and type(got) is type(value)
