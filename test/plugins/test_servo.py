"""The camera tilt servo's arithmetic: angle to pulse, the rate limit, the refusals."""

from __future__ import annotations

from dataclasses import replace

import pytest

from enbarr_plugins.thrusters.servo import ServoSettings, ServoSlew

pytestmark = pytest.mark.unit

TILT = ServoSettings(channel=8, min_pulse=1100.0, centre_pulse=1500.0, max_pulse=1900.0,
                     min_angle=-45.0, max_angle=45.0, rate=60.0, executor='camera_tilt')


def test_the_pulse_is_linear_each_side_of_the_centre_and_clamped():
    assert TILT.pulse(0.0) == 1500.0
    assert TILT.pulse(45.0) == 1900.0 and TILT.pulse(-45.0) == 1100.0
    assert TILT.pulse(22.5) == 1700.0 and TILT.pulse(-9.0) == 1420.0
    assert TILT.pulse(80.0) == 1900.0 and TILT.pulse(-80.0) == 1100.0


def test_an_off_centre_servo_still_centres_at_zero_and_a_reversed_one_swaps_sides():
    odd = replace(TILT, centre_pulse=1400.0, min_angle=-30.0, max_angle=60.0)
    assert odd.pulse(0.0) == 1400.0
    assert odd.pulse(30.0) == pytest.approx(1650.0) and odd.pulse(-15.0) == 1250.0
    flipped = replace(TILT, min_pulse=1900.0, max_pulse=1100.0)
    flipped.validate(5000.0)
    assert flipped.pulse(45.0) == 1100.0


def test_the_angle_moves_at_most_rate_per_second_toward_the_goal():
    slew = ServoSlew(TILT)
    assert slew.request(45.0) is None
    assert slew.step(0.25) == pytest.approx(15.0)      # 60 deg/s
    assert slew.step(0.25) == pytest.approx(30.0)
    assert slew.step(1.0) == 45.0                       # arrives, no overshoot
    assert slew.request(-10) is None
    assert slew.step(0.5) == pytest.approx(15.0)
    assert slew.step(-1.0) == pytest.approx(15.0)       # time never runs backwards
    assert slew.step(10.0) == -10.0


def test_goals_outside_the_range_are_clamped_and_other_values_refused():
    slew = ServoSlew(TILT)
    assert slew.request(100.0) is None and slew.goal == 45.0
    assert slew.request(True) == 'expected an angle in degrees, got bool'
    assert slew.request('up') == 'expected an angle in degrees, got str'
    assert slew.request(float('nan')) == 'expected a finite angle'
    assert slew.goal == 45.0


@pytest.mark.parametrize('change, message', [
    ({'min_angle': 0.0}, 'servo.min_angle'),
    ({'centre_pulse': 2000.0}, 'servo.centre_pulse'),
    ({'max_pulse': 5000.0}, 'servo.max_pulse: 5000.0 us does not fit'),
    ({'executor': ''}, 'servo.executor'),
])
def test_a_calibration_that_cannot_work_is_refused_naming_the_parameter(change, message):
    with pytest.raises(ValueError, match=message):
        replace(TILT, **change).validate(5000.0)
    replace(TILT, **change, channel=-1).validate(5000.0)    # no servo: nothing to check
