"""Simulated Arduino PWM board driving a vessel's azimuth ESCs and servos (from the profile).

Reads ``pwm/duty_cycle`` (``std_msgs/Float64MultiArray``: one duty [%] per channel,
``<azimuth>/motor, <azimuth>/servo`` for each azimuth in ``azimuth_names`` order, labelled
``duty_cycle_percent``) and sets the simulated azimuths (``sim/azimuth_command``) through the
same calibration tables the real hardware was measured with. Like firmware with a watchdog,
it drives every channel to its neutral duty when duty cycles stop for ``command_timeout``.
A message with another label or size, and duties outside the profile's
``pwm.duty_min_percent .. pwm.duty_max_percent`` or non-finite ones, are refused and counted;
more than 5 % refused in a second makes the node DEGRADED (issue 8). The duty message has no
stamp, so its period is measured on arrival: a ``command_timeout`` under two periods (the
outputs would go neutral between messages) is refused with the measured period.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.allocation.layout_params import AZIMUTHS, pwm_from_params, pwm_specs
from enbarr_core.framework.driver import ActuatorDriver
from enbarr_core.framework.health import (
    DEGRADED, InputHealth, IntervalMeter, OK, too_short_for_rate, worst)
from enbarr_core.models.vessel3dof import AzimuthSpec
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics


_BETWEEN = 'the outputs would go neutral between messages'


@dataclass(frozen=True)
class SimArduinoSettings:
    """Settings of ``SimArduinoNode``: the azimuth layout and the PWM calibration (read only)."""

    azimuths: tuple[AzimuthSpec, ...]
    calibration: PwmCalibration

    @classmethod
    def from_params(cls, names: Sequence[str], v: Mapping[str, Any]) -> SimArduinoSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        return cls(AZIMUTHS.from_params(names, v), pwm_from_params(v))


class SimArduinoNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'arduino', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='PWM input stopped: outputs neutral',
                         **kwargs)
        names = AZIMUTHS.names(self)
        self.settings: SimArduinoSettings = self.bind_settings(
            AZIMUTHS.specs(self, names) + pwm_specs(self),
            lambda v: SimArduinoSettings.from_params(names, v),
            lambda _: None).settings  # every parameter is read only
        self.names = list(names)
        self.calibration = self.settings.calibration
        self.channels = 2 * len(self.names)  # motor, servo per azimuth
        self.refused = 0
        self.health = InputHealth()
        self.duty_period = IntervalMeter()  # on arrival: the duty message has no stamp
        self.add_on_set_parameters_callback(self._check_command_timeout)
        self._pub = self.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
        self.create_topic_subscription(topics.PWM_DUTY, self._on_duty)

    def _on_duty(self, msg: Float64MultiArray) -> None:
        if not accept_duties(self, msg):
            return
        c = self.calibration
        thrust = [c.duty_to_thrust(d) for d in msg.data[0::2]]
        angle = [c.duty_to_angle(d) for d in msg.data[1::2]]
        with self.commanding():
            self.neutral = not any(thrust)
            self._send(thrust, angle)

    def _check_command_timeout(self, params: list[Parameter]) -> SetParametersResult:
        return check_command_timeout(self, params)

    def status(self) -> tuple[int, str]:
        """Return the driver's status, DEGRADED when duties are refused or settings misfit."""
        level, message, _ = self.health.report(1.0)
        return worst(super().status(), (level, message), rate_status(self))

    def _send(self, thrust: list[float], angle: list[float]) -> None:
        out = new(JointState)
        out.name, out.effort, out.position = self.names, thrust, angle
        out.header.stamp = convert.ns_to_stamp(self.now_ns())
        self._pub.publish(out)

    def is_neutral(self) -> bool:
        """Return whether every motor is at zero thrust."""
        return self.neutral

    def write_neutral(self) -> None:
        """Every motor at its neutral duty's thrust, every servo at its neutral angle."""
        self.neutral = True
        c = self.calibration
        self._send([c.duty_to_thrust(c.neutral_thrust_duty)] * len(self.names),
                   [c.duty_to_angle(c.neutral_angle_duty)] * len(self.names))


# -- the checks of pwm/duty_cycle that every Arduino plugin makes ------------------------------
# ``node`` has ``channels``, ``calibration`` (PwmCalibration), ``health`` (InputHealth),
# ``duty_period`` (IntervalMeter, on arrival: the duty message has no stamp), ``refused`` and
# the ``watchdog`` of an ActuatorDriver.

def accept_duties(node: Any, msg: Float64MultiArray) -> bool:
    """Whether ``msg`` is a duty message for ``node``'s channels within the calibrated limits.

    A message with another label or size, or a duty outside ``pwm.duty_min_percent ..
    pwm.duty_max_percent`` or not finite, is refused and counted; an accepted one is timed.
    """
    c = node.calibration
    dim = msg.layout.dim
    n = node.channels
    if (len(dim) != 1 or dim[0].label != topics.PWM_DUTY_LABEL or dim[0].size != n
            or dim[0].stride != n or len(msg.data) != n
            or not all(c.accepts(d) for d in msg.data)):
        node.refused += 1
        node.health.refused('pwm/duty_cycle', 'malformed')
        return False
    node.health.accepted('pwm/duty_cycle')
    node.duty_period.add(node.now_ns())
    return True


def check_command_timeout(node: Any, params: list[Parameter]) -> SetParametersResult:
    """Refuse a live ``command_timeout`` under two measured duty periods."""
    for p in params:
        if p.name == 'command_timeout' and isinstance(p.value, float):
            problem = too_short_for_rate('command_timeout', p.value, topics.PWM_DUTY.name,
                                         node.duty_period.period, _BETWEEN)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
    return SetParametersResult(successful=True)


def rate_status(node: Any) -> tuple[int, str]:
    """DEGRADED (and a reported problem) while ``command_timeout`` misfits the duty rate."""
    problem = too_short_for_rate('command_timeout', node.watchdog.timeout_ns * 1e-9,
                                 topics.PWM_DUTY.name, node.duty_period.period, _BETWEEN)
    if problem:
        node.report_problem(f'parameter {problem}')
        return DEGRADED, problem
    return OK, 'ok'
