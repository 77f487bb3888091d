"""The CS Saucer's Arduino PWM mapping: ``azimuth_commands`` (thrust N, angle rad) ->
``pwm/duty_cycle`` (percent, 4.3 .. 9.4, manual Table 1.1) through the calibration tables of
the profile (``pwm.*``). Channels are ``<azimuth>/motor`` and ``<azimuth>/servo``.

Neutral (zero-thrust duty, servo at 0 rad) when commands stop for ``command_timeout``, on
start and on ``safe_state`` (every bringup exit path). The serial link to the Arduino is a
hardware plugin's job; this node computes what it sends.
"""

from __future__ import annotations

import math
from typing import Any

from sensor_msgs.msg import JointState

from enbarr_interfaces import topics

from enbarr_core.allocation.azimuth_params import declare_azimuths, declare_pwm
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.driver import ActuatorDriver


class PwmMapperNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'pwm', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='azimuth commands stopped: PWM neutral',
                         **kwargs)
        specs = declare_azimuths(self)
        self.calibration = declare_pwm(self)
        for a in specs:
            try:
                self.calibration.check_covers(a.angle_min, a.angle_max)
            except ValueError as err:
                raise ConfigurationError(f'node {node_name!r}: azimuth {a.name!r}: {err}',
                                         parameter='pwm.angle_rad') from err
        self.azimuths = [a.name for a in specs]
        self._index = {n: i for i, n in enumerate(self.azimuths)}
        self.channels = [f'{n}/{k}' for n in self.azimuths for k in ('motor', 'servo')]
        self.duty: list[float] = []
        self.rejected = 0
        self._pub = self.create_topic_publisher(topics.PWM_DUTY)
        self.create_topic_subscription(topics.AZIMUTH_COMMANDS, self._on_command)
        self.safe_state()
        self.connect()

    def _on_command(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.effort) or len(msg.name) != len(msg.position):
            self.rejected += 1
            return
        c = self.calibration
        duty = [c.neutral_thrust_duty, c.neutral_angle_duty] * len(self.azimuths)
        for name, thrust, angle in zip(msg.name, msg.effort, msg.position):
            i = self._index.get(name)
            if i is None or not (math.isfinite(thrust) and math.isfinite(angle)):
                self.rejected += 1
                return
            duty[2 * i] = c.thrust_to_duty(thrust)
            duty[2 * i + 1] = c.angle_to_duty(angle)
        with self.commanding():
            self._publish(duty, msg.header.stamp, neutral=False)

    def _publish(self, duty: list[float], stamp: Any, neutral: bool) -> None:
        self.duty, self.neutral = duty, neutral
        out = JointState(name=self.channels, effort=duty)
        out.header.stamp = stamp
        self._pub.publish(out)

    def is_neutral(self) -> bool:
        return self.neutral

    def write_neutral(self) -> None:
        """Every motor at its zero-thrust duty, every servo at 0 rad."""
        c = self.calibration
        self._publish([c.neutral_thrust_duty, c.neutral_angle_duty] * len(self.azimuths),
                      self.get_clock().now().to_msg(), neutral=True)

