"""What every Arduino PWM plugin does with ``pwm/duty_cycle``, simulated twin and driver alike.

``DutyInput`` is the input both ``arduino/sim.py`` and ``arduino/link.py`` own: it refuses
(and counts) a message with another label or size, or a duty outside the profile's
``pwm.duty_min_percent .. pwm.duty_max_percent`` or not finite; more than 5 % refused in a
second makes the node DEGRADED. The duty message has no stamp, so its period is measured on
arrival: a ``command_timeout`` shorter than two periods (the outputs would go neutral between
messages) is refused when set live and reported while it misfits.
"""

from __future__ import annotations

from collections.abc import Callable

from std_msgs.msg import Float64MultiArray

from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.framework.health import (
    DEGRADED, InputHealth, IntervalMeter, OK, too_short_for_rate, worst)
from enbarr_interfaces import topics

_BETWEEN = 'the outputs would go neutral between messages'
_INPUT = 'pwm/duty_cycle'


class DutyInput:
    """The checks, counts and measured period of one node's ``pwm/duty_cycle`` input."""

    def __init__(self, calibration: PwmCalibration, channels: int) -> None:
        self.calibration = calibration
        self.channels = channels
        self.refused = 0
        self.health = InputHealth()
        self.period = IntervalMeter()  # on arrival: the duty message has no stamp

    def accept(self, msg: Float64MultiArray, now_ns: int) -> bool:
        """Whether ``msg`` is a duty message for these channels within the calibrated limits.

        A refused message is counted; an accepted one is timed at ``now_ns``.
        """
        c = self.calibration
        dim = msg.layout.dim
        n = self.channels
        if (len(dim) != 1 or dim[0].label != topics.PWM_DUTY_LABEL or dim[0].size != n
                or dim[0].stride != n or len(msg.data) != n
                or not all(c.accepts(d) for d in msg.data)):
            self.refused += 1
            self.health.refused(_INPUT, 'malformed')
            return False
        self.health.accepted(_INPUT)
        self.period.add(now_ns)
        return True

    def timeout_problem(self, command_timeout: float) -> str | None:
        """Why ``command_timeout`` [s] is too short for the measured duty period, or None."""
        return too_short_for_rate('command_timeout', command_timeout, topics.PWM_DUTY.name,
                                  self.period.period, _BETWEEN)

    def status(self, command_timeout: float,
               report_problem: Callable[[str], None]) -> tuple[int, str]:
        """Level and message of the input: DEGRADED on refusals or a misfit ``command_timeout``.

        A misfit is also handed to ``report_problem`` (the node's problem report).
        """
        level, message, _ = self.health.report(1.0)
        rate = (OK, 'ok')
        problem = self.timeout_problem(command_timeout)
        if problem:
            report_problem(f'parameter {problem}')
            rate = (DEGRADED, problem)
        return worst((level, message), rate)
