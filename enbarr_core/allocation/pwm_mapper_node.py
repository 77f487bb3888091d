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

Time (``framework.stamps``): a stamped command more than ``max_future`` ahead of the
clock, or not later than the last one mapped, is refused and counted (a command with a zero
stamp carries no time and is taken as it comes); more than 5 % refused in a second makes the
node DEGRADED. ``command_timeout`` must cover two measured command periods (shorter, the
outputs would go neutral between commands) and ``max_future`` stay under one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from typing import Any

from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from enbarr_interfaces import convert, topics
from enbarr_interfaces.fastmsg import new


from enbarr_core.allocation.azimuth_allocation_node import MAX_FUTURE
from enbarr_core.allocation.layout_params import declare_pwm_layout, PwmLayout
from enbarr_core.framework.driver import ActuatorDriver
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.health import (
    DEGRADED, future_tolerance_problem, InputHealth, IntervalMeter, OK, too_short_for_rate,
    worst)
from enbarr_core.framework.node import LatencyLog
from enbarr_core.framework.params import ParamSpec, refuse_live_value
from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict


def duty_message(duties: Sequence[float]) -> Float64MultiArray:
    """Build a ``PWM_DUTY`` message: one duty [%] per channel, labelled ``PWM_DUTY_LABEL``."""
    # ``fastmsg.new``: the generated constructors of these three cost more than the mapping.
    n = len(duties)
    dim = new(MultiArrayDimension)
    dim.label, dim.size, dim.stride = topics.PWM_DUTY_LABEL, n, n
    msg = new(Float64MultiArray)
    msg.layout.dim = [dim]
    msg.data = [float(d) for d in duties]
    return msg


class PwmMapperNode(ActuatorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'pwm', **kwargs: Any) -> None:
        self.neutral = True
        super().__init__(node_name, timeout_message='azimuth commands stopped: PWM neutral',
                         **kwargs)
        self.settings: PwmLayout = declare_pwm_layout(self)  # read only
        self.calibration = self.settings.calibration
        for a in self.settings.azimuths:
            try:
                self.calibration.check_covers(a.angle_min, a.angle_max)
            except ValueError as err:
                raise ConfigurationError(f'node {node_name!r}: azimuth {a.name!r}: {err}',
                                         parameter='pwm.angle_rad') from err
        self.health = InputHealth()
        self.command_period = IntervalMeter()
        self._totals: dict[str, int] = {}
        self._gate = StampGate()
        self.bind_settings([ParamSpec(
            'max_future', MAX_FUTURE.default, 'Commands stamped further ahead of the clock than '
            "this are refused (at least the observer's)", 's', 0.0, 0.5)],
            self._build_max_future, self._apply_max_future)
        self.add_on_set_parameters_callback(
            refuse_live_value('command_timeout', self._timeout_problem))
        self.azimuths = [a.name for a in self.settings.azimuths]
        self._index = {n: i for i, n in enumerate(self.azimuths)}
        self.channels = self.settings.channels
        self.duty: list[float] = []
        self.rejected = 0
        self.latency = LatencyLog()  # azimuth command stamp (the pose's) -> duties delivered
        self._pub = self.create_topic_publisher(topics.PWM_DUTY)
        self.create_topic_subscription(topics.AZIMUTH_COMMANDS, self._on_command)

    def _build_max_future(self, v: Mapping[str, Any]) -> float:
        problem = future_tolerance_problem(v['max_future'], self.command_period.period,
                                           topics.AZIMUTH_COMMANDS.name)
        if problem:
            raise ValueError(problem)
        return v['max_future']

    def _apply_max_future(self, max_future: float) -> None:
        self._gate.policy = StampPolicy(max_future=max_future)

    def _timeout_problem(self, timeout: float) -> str | None:
        return too_short_for_rate('command_timeout', timeout, topics.AZIMUTH_COMMANDS.name,
                                  self.command_period.period,
                                  'the outputs would go neutral between messages')

    def _refuse(self, reason: str) -> None:
        self.rejected += 1
        self.health.refused('azimuth_commands', reason)

    def _on_command(self, msg: JointState) -> None:
        if len(msg.name) != len(msg.effort) or len(msg.name) != len(msg.position):
            self._refuse('malformed')
            return
        t = convert.stamp_to_ns(msg.header.stamp)
        if t:  # a zero stamp carries no time: nothing to judge
            verdict = self._gate.offer(t, self.now_ns())
            if verdict is not StampVerdict.ACCEPTED:
                self._refuse(verdict.value)
                self.get_logger().warn(f'azimuth_commands refused ({verdict.value})',
                                       throttle_duration_sec=1.0)
                return
        c = self.calibration
        duty = [c.neutral_thrust_duty, c.neutral_angle_duty] * len(self.azimuths)
        for name, thrust, angle in zip(msg.name, msg.effort, msg.position):
            i = self._index.get(name)
            if i is None or not (math.isfinite(thrust) and math.isfinite(angle)):
                self._refuse('malformed')
                return
            duty[2 * i] = c.thrust_to_duty(thrust)
            duty[2 * i + 1] = c.angle_to_duty(angle)
        self.health.accepted('azimuth_commands')
        with self.commanding():
            self._publish(duty, neutral=False)
        if t:
            self.command_period.add(t)
            self.latency.add(self.now_ns() - t)

    def status(self) -> tuple[int, str]:
        """Return the driver's status, DEGRADED when commands are refused or settings misfit."""
        level, message, self._totals = self.health.report(1.0)
        period = self.command_period.period
        problem = (self._timeout_problem(self.watchdog.timeout_ns * 1e-9)
                   or future_tolerance_problem(self._gate.policy.max_future, period,
                                               topics.AZIMUTH_COMMANDS.name))
        rates = (OK, 'ok')
        if problem:
            rates = (DEGRADED, problem)
            self.report_problem(f'parameter {problem}')
        return worst(super().status(), (level, message), rates)

    def status_values(self) -> dict[str, Any]:
        """Return the driver's values and the input counts since start."""
        return {**super().status_values(), 'rejected': self.rejected, **self._totals}

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
