"""Node tests: pwm mapper node (one behaviour per test)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from support.nodes import TIMEOUT, add, probe
from support.saucer import (
    COMMON, DUTY_MAX, DUTY_MIN, NAMES, NEUTRAL_DUTY, azimuth_msg, overrides)

from enbarr_core.allocation.pwm_mapper_node import PwmMapperNode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus

CHANNELS = [f'{n}/{k}' for n in NAMES for k in ('motor', 'servo')]
NEUTRAL = [NEUTRAL_DUTY] * len(CHANNELS)
THRUST = [0.3, -0.45, 1.5]
ANGLE = [0.4, -1.0, 1.98968]


@dataclass
class Rig:
    node: PwmMapperNode
    pub: Any
    duties: list[Float64MultiArray]


def rig(context: Any, executor: Any, timeout: float = 10.0, start: bool = True) -> Rig:
    """The mapper, a command publisher and a duty listener; started (its neutral dropped)."""
    node = add(executor, PwmMapperNode(
        node_name='pwm', context=context,
        parameter_overrides=overrides({'command_timeout': timeout})))
    p = probe(context, executor, 'allocation')
    pub = p.create_topic_publisher(topics.AZIMUTH_COMMANDS)
    duties: list[Float64MultiArray] = []
    p.create_topic_subscription(topics.PWM_DUTY, duties.append)
    LinkBus.of(context).connect()
    assert not duties  # constructing publishes nothing
    if start:
        node.start()  # neutral duties before the first command, as bringup starts it
        assert len(duties) == 1 and list(duties[0].data) == pytest.approx(NEUTRAL)
        duties.clear()
    return Rig(node, pub, duties)


def test_pwm_mapper_channels_in_profile_order_and_starts_neutral(context, executor):
    r = rig(context, executor, start=False)
    assert r.node.channels == CHANNELS
    assert r.duties == [] and r.node.duty == []  # constructing it published nothing
    r.node.start()
    assert len(r.duties) == 1 and list(r.duties[0].data) == pytest.approx(NEUTRAL)
    assert r.node.neutral and r.node.duty == pytest.approx(NEUTRAL)


def test_pwm_mapper_message_is_labelled_duty_cycle_percent(context, executor):
    r = rig(context, executor)
    r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=1_234_000_000))
    assert len(r.duties) == 1 and not r.node.neutral
    out = r.duties[-1]
    assert isinstance(out, Float64MultiArray)
    assert len(out.layout.dim) == 1
    dim = out.layout.dim[0]
    assert dim.label == 'duty_cycle_percent' == topics.PWM_DUTY_LABEL
    assert dim.size == dim.stride == len(CHANNELS) == len(out.data)
    assert out.layout.data_offset == 0


def test_pwm_mapper_latency_from_the_command_stamp(context, executor):
    # The duty message has no header: the mapper logs command stamp -> duties delivered.
    r = rig(context, executor)
    stamp = 1_234_000_000
    before = r.node.get_clock().now().nanoseconds
    r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=stamp))
    after = r.node.get_clock().now().nanoseconds
    assert r.node.latency.count == 1
    assert before - stamp <= r.node.latency.last(1)[0] <= after - stamp
    r.pub.publish(azimuth_msg(THRUST, ANGLE))  # no stamp: nothing to measure
    assert r.node.latency.count == 1


def test_pwm_mapper_duties_follow_the_profile_tables(context, executor):
    r = rig(context, executor)
    c = r.node.calibration
    r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=1_234_000_000))
    d = np.array(r.duties[-1].data)
    assert np.all((d >= DUTY_MIN) & (d <= DUTY_MAX))
    expected = [v for f, a in zip(THRUST, ANGLE) for v in (c.thrust_to_duty(f),
                                                            c.angle_to_duty(a))]
    assert d.tolist() == pytest.approx(expected, abs=1e-12)
    # The same numbers from the profile's tables by hand: 0.3 N half-way from 7.0 % (0 N) to
    # 8.2 % (0.6 N), -0.45 N at 5.5 %, 1.5 N at 9.4 %; servo 0.4 rad on 6.85 .. 9.4 %.
    assert d[0::2].tolist() == pytest.approx([7.6, 5.5, 9.4], abs=1e-12)
    assert d[1] == pytest.approx(6.85 + 0.4 / 1.98968 * 2.55, abs=1e-12)
    assert d[5] == pytest.approx(9.4, abs=1e-12)


def test_pwm_mapper_clips_beyond_the_tables(context, executor):
    r = rig(context, executor)
    r.pub.publish(azimuth_msg([5.0, -5.0, 0.0], [3.0, -3.0, 0.0]))
    assert np.array(r.duties[-1].data).tolist() == pytest.approx(
        [9.4, 9.4, 4.3, 4.3, NEUTRAL_DUTY, NEUTRAL_DUTY], abs=1e-12)


def test_pwm_mapper_safe_state_is_neutral_at_once(context, executor):
    r = rig(context, executor)
    r.pub.publish(azimuth_msg(THRUST, ANGLE))
    assert not r.node.neutral
    r.node.safe_state()
    assert np.array(r.duties[-1].data).tolist() == pytest.approx(NEUTRAL)
    assert r.node.neutral


def test_pwm_mapper_refuses_bad_commands(context, executor):
    # Refused (counted, nothing published): NaN thrust, Inf angle, unknown azimuth, lengths.
    r = rig(context, executor)
    r.pub.publish(azimuth_msg(THRUST, ANGLE))
    n, before = len(r.duties), list(r.node.duty)
    r.pub.publish(azimuth_msg([math.nan, 0.1, 0.1], ANGLE))
    r.pub.publish(azimuth_msg(THRUST, [0.0, math.inf, 0.0]))
    r.pub.publish(azimuth_msg([0.1], [0.0], names=['az_mid']))
    r.pub.publish(JointState(name=NAMES, effort=THRUST, position=[0.0]))
    assert r.node.rejected == 4 and len(r.duties) == n and r.node.duty == before


def test_pwm_mapper_goes_neutral_once_when_commands_stop(context, executor, spin):
    r = rig(context, executor, timeout=0.1)
    r.pub.publish(azimuth_msg(THRUST, ANGLE))
    n = len(r.duties)
    assert r.node.timeouts == 0 and not r.node.neutral
    assert spin(executor, lambda: r.node.timeouts == 1, TIMEOUT)
    assert len(r.duties) == n + 1
    assert np.array(r.duties[-1].data).tolist() == pytest.approx(NEUTRAL)
    assert r.node.neutral
    ticks = [0]
    r.node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert r.node.timeouts == 1 and len(r.duties) == n + 1  # not repeated


@pytest.mark.parametrize('missing', [
    'pwm.duty_min_percent', 'pwm.duty_max_percent', 'pwm.angle_rad',
    'azimuths.az_port_aft.angle_max', 'azimuths.az_bow.max_angle_rate'])
def test_pwm_mapper_needs_every_profile_value(context, missing):
    values = {k: v for k, v in COMMON.items() if k != missing}
    with pytest.raises(ConfigurationError, match=f"parameter '{missing}' is not set") as info:
        PwmMapperNode(node_name='pwm', context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
    assert info.value.parameter == missing


def test_pwm_mapper_duty_limits_come_from_the_profile(context, executor):
    # A table duty outside the profile's limits is refused at start, naming the table.
    with pytest.raises(ConfigurationError, match=r'thrust_duty_percent\[5\]: 9.4 % is outside'):
        PwmMapperNode(node_name='pwm', context=context,
                      parameter_overrides=overrides({'pwm.duty_max_percent': 9.0}))
    # A wider range accepts the same tables.
    r = add(executor, PwmMapperNode(
        node_name='pwm_wide', context=context,
        parameter_overrides=overrides({'pwm.duty_min_percent': 2.0,
                                       'pwm.duty_max_percent': 12.0})))
    assert (r.calibration.duty_min_percent, r.calibration.duty_max_percent) == (2.0, 12.0)


def test_pwm_mapper_refuses_commands_stamped_ahead_or_out_of_order(context, executor):
    # Before the time policy, a command stamped 20 s ahead was mapped to duties (and logged as
    # a latency of -20 s). Unstamped commands (stamp 0) carry no time and are taken as they come.
    from support.saucer import SimClock
    r = rig(context, executor)
    clock = SimClock(r.node)
    for _ in range(10):
        r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=clock.advance(0.02)))
    n = len(r.duties)
    r.pub.publish(azimuth_msg([0.0] * 3, ANGLE, stamp_ns=clock.ns + 20_000_000_000))
    r.pub.publish(azimuth_msg([0.0] * 3, ANGLE, stamp_ns=clock.ns - 1))
    assert len(r.duties) == n, 'a command from the future or the past was mapped'
    assert r.node.latency.last(r.node.latency.count).min() >= 0
    r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=clock.advance(0.02)))
    assert len(r.duties) == n + 1
    level, message = r.node.status()
    assert level == 1 and 'azimuth_commands: refused 2 of 13' in message, message
    assert r.node.status_values()['azimuth_commands.future'] == 1


def test_pwm_mapper_refuses_a_command_timeout_shorter_than_two_command_periods(
        context, executor):
    from support.saucer import SimClock
    r = rig(context, executor)
    clock = SimClock(r.node)
    for _ in range(10):
        r.pub.publish(azimuth_msg(THRUST, ANGLE, stamp_ns=clock.advance(0.02)))
    result = r.node.set_parameters([Parameter('command_timeout', value=0.03)])[0]
    assert not result.successful and 'command_timeout' in result.reason, result.reason
    assert 'measured 0.02 s' in result.reason
    assert r.node.watchdog.timeout_ns != 30_000_000
    assert r.node.set_parameters([Parameter('command_timeout', value=0.25)])[0].successful


def test_duty_message_is_byte_for_byte_the_one_the_generated_constructors_build() -> None:
    """``duty_message`` builds with ``fastmsg.new``: the same message as the classes'."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

    from enbarr_core.allocation.pwm_mapper_node import duty_message
    from enbarr_interfaces import topics
    from support.cdr_bytes import same_cdr
    duties = [7.5, 6.1, 8.25, 7.0]
    expected = Float64MultiArray(layout=MultiArrayLayout(dim=[MultiArrayDimension(
        label=topics.PWM_DUTY_LABEL, size=4, stride=4)]), data=duties)
    # Every byte CDR defines (rmw_fastrtps leaves padding as its buffer held it).
    assert same_cdr(serialize_message(duty_message(duties)), serialize_message(expected),
                    expected)
    assert duty_message(duties).layout.dim[0] is not duty_message(duties).layout.dim[0]
