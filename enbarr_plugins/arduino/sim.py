"""Simulated Arduino PWM board with the Saucer's ESCs and servos: reads ``pwm/duty_cycle``
(percent per channel) and sets the simulated azimuths (``sim/azimuth_command``) through the
same calibration tables the real hardware was measured with. Like firmware with a watchdog,
it drives every channel to its neutral duty when duty cycles stop for ``command_timeout``.
Duties outside the manual's 4.3 .. 9.4 % or non-finite ones are refused and counted.
"""

from __future__ import annotations

import math
from typing import Any

from sensor_msgs.msg import JointState

from enbarr_core.allocation.azimuth_params import declare_azimuths, declare_pwm
from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.framework.driver import ActuatorDriver
from enbarr_core.framework.node import LatencyLog
from enbarr_interfaces import convert, topics

class SimArduinoNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'arduino', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='PWM input stopped: outputs neutral',
                         **kwargs)
        self.names = [a.name for a in declare_azimuths(self)]
        self.calibration = declare_pwm(self)
        self._channels = {f'{n}/{k}': (i, k) for i, n in enumerate(self.names)
                          for k in ('motor', 'servo')}
        self.refused = 0
        self.latency = LatencyLog()  # pose stamp -> duty cycles applied
        self._pub = self.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
        self.create_topic_subscription(topics.PWM_DUTY, self._on_duty)
        self.connect()

    def _on_duty(self, msg: JointState) -> None:
        c = self.calibration
        thrust = [0.0] * len(self.names)
        angle = [0.0] * len(self.names)
        for name, duty in zip(msg.name, msg.effort):
            channel = self._channels.get(name)
            if channel is None or not math.isfinite(duty) or not (
                    PwmCalibration.DUTY_MIN <= duty <= PwmCalibration.DUTY_MAX):
                self.refused += 1
                return
            i, kind = channel
            if kind == 'motor':
                thrust[i] = c.duty_to_thrust(duty)
            else:
                angle[i] = c.duty_to_angle(duty)
        with self.commanding():
            self.neutral = not any(thrust)
            self._send(thrust, angle)
        if msg.header.stamp.sec:
            self.latency.add(self.get_clock().now().nanoseconds
                             - convert.stamp_to_ns(msg.header.stamp))

    def _send(self, thrust: list[float], angle: list[float]) -> None:
        out = JointState(name=self.names, effort=thrust, position=angle)
        out.header.stamp = self.get_clock().now().to_msg()
        self._pub.publish(out)

    def is_neutral(self) -> bool:
        return self.neutral

    def write_neutral(self) -> None:
        """Every motor at its neutral duty's thrust, every servo at its neutral angle."""
        self.neutral = True
        c = self.calibration
        self._send([c.duty_to_thrust(c.neutral_thrust_duty)] * len(self.names),
                   [c.duty_to_angle(c.neutral_angle_duty)] * len(self.names))
