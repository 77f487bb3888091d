"""PWM mapping: ``azimuth_commands`` (thrust N, angle rad) -> ``pwm/duty_cycle`` (%).

Goes through the profile's calibration tables (``pwm.*``) and publishes one duty per channel,
``<azimuth>/motor, <azimuth>/servo`` for each azimuth in ``azimuth_names`` order, as a
``std_msgs/Float64MultiArray`` labelled ``duty_cycle_percent`` (``topics.PWM_DUTY``). Every
duty lies within the profile's ``pwm.duty_min_percent .. pwm.duty_max_percent``.

Neutral (zero-thrust duty, servo at 0 rad) when commands stop for ``command_timeout``, on
start and on ``safe_state`` (every bringup exit path). The serial link to the Arduino is a
hardware plugin's job; this node computes what it sends. The duty message has no header, so
this node keeps the ``LatencyLog`` of the chain (command stamp -> duties delivered: with the
in-process link bus the delivery includes the Arduino plugin's callback).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Any

from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

from enbarr_interfaces import convert, topics

from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.allocation.layout_params import AZIMUTHS, pwm_from_params, pwm_specs
from enbarr_core.framework.driver import ActuatorDriver
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.node import LatencyLog
from enbarr_core.models.vessel3dof import AzimuthSpec


@dataclass(frozen=True)
class PwmMapperSettings:
    """Settings of ``PwmMapperNode``: the azimuth layout and the PWM calibration (read only)."""

    azimuths: tuple[AzimuthSpec, ...]
    calibration: PwmCalibration

    @classmethod
    def from_params(cls, names: Sequence[str], v: Mapping[str, Any]) -> PwmMapperSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        return cls(AZIMUTHS.from_params(names, v), pwm_from_params(v))

    @property
    def channels(self) -> list[str]:
        """Channel names in the order of the duties: ``<azimuth>/motor, <azimuth>/servo``."""
        return [f'{a.name}/{k}' for a in self.azimuths for k in ('motor', 'servo')]


def duty_message(duties: Sequence[float]) -> Float64MultiArray:
    """Build a ``PWM_DUTY`` message: one duty [%] per channel, labelled ``PWM_DUTY_LABEL``."""
    n = len(duties)
    return Float64MultiArray(
        layout=MultiArrayLayout(dim=[
            MultiArrayDimension(label=topics.PWM_DUTY_LABEL, size=n, stride=n)]),
        data=[float(d) for d in duties])


class PwmMapperNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'pwm', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='azimuth commands stopped: PWM neutral',
                         **kwargs)
        names = AZIMUTHS.names(self)
        self.settings: PwmMapperSettings = self.bind_settings(
            AZIMUTHS.specs(self, names) + pwm_specs(self),
            lambda v: PwmMapperSettings.from_params(names, v),
            lambda _: None).settings  # every parameter is read only
        self.calibration = self.settings.calibration
        for a in self.settings.azimuths:
            try:
                self.calibration.check_covers(a.angle_min, a.angle_max)
            except ValueError as err:
                raise ConfigurationError(f'node {node_name!r}: azimuth {a.name!r}: {err}',
                                         parameter='pwm.angle_rad') from err
        self.azimuths = list(names)
        self._index = {n: i for i, n in enumerate(self.azimuths)}
        self.channels = self.settings.channels
        self.duty: list[float] = []
        self.rejected = 0
        self.latency = LatencyLog()  # azimuth command stamp (the pose's) -> duties delivered
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
            self._publish(duty, neutral=False)
        if msg.header.stamp.sec:
            self.latency.add(self.get_clock().now().nanoseconds
                             - convert.stamp_to_ns(msg.header.stamp))

    def _publish(self, duty: list[float], neutral: bool) -> None:
        self.duty, self.neutral = duty, neutral
        self._pub.publish(duty_message(duty))

    def is_neutral(self) -> bool:
        """Return whether every channel is at its neutral duty."""
        return self.neutral

    def write_neutral(self) -> None:
        """Every motor at its zero-thrust duty, every servo at 0 rad."""
        c = self.calibration
        self._publish([c.neutral_thrust_duty, c.neutral_angle_duty] * len(self.azimuths),
                      neutral=True)
