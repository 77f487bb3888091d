"""Simulated Arduino PWM board driving a vessel's azimuth ESCs and servos (from the profile).

Reads ``pwm/duty_cycle`` (``std_msgs/Float64MultiArray``: one duty [%] per channel,
``<azimuth>/motor, <azimuth>/servo`` for each azimuth in ``azimuth_names`` order, labelled
``duty_cycle_percent``) and sets the simulated azimuths (``sim/azimuth_command``) through the
same calibration tables the real hardware was measured with. Like firmware with a watchdog,
it drives every channel to its neutral duty when duty cycles stop for ``command_timeout``.
A message with another label or size, and duties outside the profile's
``pwm.duty_min_percent .. pwm.duty_max_percent`` or non-finite ones, are refused and counted
exactly as the real driver does (``arduino/common.py``, ``DutyInput``); more than 5 % refused
in a second makes the node DEGRADED. The duty message has no stamp, so its period is measured
on arrival: a ``command_timeout`` under two periods (the outputs would go neutral between
messages) is refused with the measured period.
"""

from __future__ import annotations

from typing import Any

from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from enbarr_core.allocation.layout_params import declare_pwm_layout, PwmLayout
from enbarr_core.framework.driver import ActuatorDriver
from enbarr_core.framework.health import worst
from enbarr_core.framework.params import refuse_live_value
from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics
from enbarr_plugins.arduino.common import DutyInput


class SimArduinoNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'arduino', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='PWM input stopped: outputs neutral',
                         **kwargs)
        self.settings: PwmLayout = declare_pwm_layout(self)  # read only
        self.names = [a.name for a in self.settings.azimuths]
        self.calibration = self.settings.calibration
        self.channels = 2 * len(self.names)  # motor, servo per azimuth
        self.duties = DutyInput(self.calibration, self.channels)
        self.add_on_set_parameters_callback(
            refuse_live_value('command_timeout', self.duties.timeout_problem))
        self._pub = self.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
        self.create_topic_subscription(topics.PWM_DUTY, self._on_duty)

    @property
    def refused(self) -> int:
        """Duty messages refused since start."""
        return self.duties.refused

    def _on_duty(self, msg: Float64MultiArray) -> None:
        if not self.duties.accept(msg, self.now_ns()):
            return
        c = self.calibration
        thrust = [c.duty_to_thrust(d) for d in msg.data[0::2]]
        angle = [c.duty_to_angle(d) for d in msg.data[1::2]]
        with self.commanding():
            self.neutral = not any(thrust)
            self._send(thrust, angle)

    def status(self) -> tuple[int, str]:
        """Return the driver's status, DEGRADED when duties are refused or settings misfit."""
        return worst(super().status(), self.duties.status(self.watchdog.timeout_ns * 1e-9,
                                                          self.report_problem))

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
