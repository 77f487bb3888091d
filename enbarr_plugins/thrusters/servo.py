"""A hobby servo on a spare PWM channel: angle to pulse width, and a rate-limited angle. Pure.

A hobby servo (the ROV's camera tilt) takes the same 50-400 Hz pulse train as an ESC and
holds the angle the pulse width names: ``centre`` [us] is 0 deg, ``min_pulse`` the lowest
angle ``min_angle`` and ``max_pulse`` the highest ``max_angle`` (each side linear, so a servo
whose centre is not midway still centres; a servo mounted the other way swaps min and max
pulse). The angle goal comes from an io request; the angle moves to it at most ``rate``
[deg/s] so that the camera does not jerk (and its cable does not snap) on a big step.
"""

from __future__ import annotations

from dataclasses import dataclass
import math


@dataclass(frozen=True)
class ServoSettings:
    """Pulse calibration and limits of one servo; ``validate`` says what does not fit."""

    channel: int          # PWM channel; -1: no servo
    min_pulse: float      # [us] at min_angle
    centre_pulse: float   # [us] at 0 deg
    max_pulse: float      # [us] at max_angle
    min_angle: float      # [deg] (< 0)
    max_angle: float      # [deg] (> 0)
    rate: float           # [deg/s], largest angular speed
    executor: str         # io_request executor name

    def validate(self, period_us: float) -> None:
        """ValueError naming the parameter (``servo.*``) when the calibration cannot work."""
        if self.channel < 0:
            return
        if not self.min_angle < 0.0 < self.max_angle:
            raise ValueError(f'servo.min_angle, servo.max_angle: {self.min_angle}, '
                             f'{self.max_angle} deg must hold 0 (the centre) strictly inside')
        pulses = (self.min_pulse, self.centre_pulse, self.max_pulse)
        if not (min(pulses[0], pulses[2]) < pulses[1] < max(pulses[0], pulses[2])):
            raise ValueError(f'servo.centre_pulse: {self.centre_pulse} us must lie between '
                             f'servo.min_pulse {self.min_pulse} and servo.max_pulse '
                             f'{self.max_pulse} us')
        if max(pulses) >= period_us:
            raise ValueError(f'servo.max_pulse: {max(pulses)} us does not fit in the PWM '
                             f'period of {period_us:.0f} us (lower frequency)')
        if not self.executor:
            raise ValueError('servo.executor: the io_request name of the servo is empty')

    def pulse(self, angle: float) -> float:
        """Return the pulse width [us] for ``angle`` [deg], clamped to the angle range."""
        a = max(self.min_angle, min(self.max_angle, angle))
        if a >= 0.0:
            return self.centre_pulse + a / self.max_angle * (self.max_pulse - self.centre_pulse)
        return self.centre_pulse + a / self.min_angle * (self.min_pulse - self.centre_pulse)


class ServoSlew:
    """The angle on its way to the goal at most ``rate`` deg/s; starts (and resets) centred."""

    def __init__(self, settings: ServoSettings) -> None:
        self.settings = settings
        self.angle = 0.0   # [deg]
        self.goal = 0.0    # [deg]

    def request(self, value: object) -> str | None:
        """Take an angle goal [deg] from an io request; return a refusal, or None."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f'expected an angle in degrees, got {type(value).__name__}'
        if not math.isfinite(value):
            return 'expected a finite angle'
        s = self.settings
        self.goal = max(s.min_angle, min(s.max_angle, float(value)))
        return None

    def step(self, dt: float) -> float:
        """Move the angle toward the goal over ``dt`` [s]; return the angle [deg]."""
        room = self.settings.rate * max(dt, 0.0)
        self.angle += max(-room, min(room, self.goal - self.angle))
        return self.angle
