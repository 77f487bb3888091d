"""Node tests: pwm mapper node."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from support.nodes import TIMEOUT, add, probe
from support.saucer import DUTY_MAX, DUTY_MIN, NAMES, NEUTRAL_DUTY, azimuth_msg, overrides

from enbarr_core.allocation.pwm_mapper_node import PwmMapperNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_pwm_mapper_duties_watchdog_safe_state_and_refusals(context, executor, spin):
    node = add(executor, PwmMapperNode(node_name='pwm', context=context,
                                       parameter_overrides=overrides({'command_timeout': 0.1})))
    channels = [f'{n}/{k}' for n in NAMES for k in ('motor', 'servo')]
    neutral = [NEUTRAL_DUTY] * len(channels)
    assert node.channels == channels
    assert node.neutral and node.duty == pytest.approx(neutral)  # starts neutral
    p = probe(context, executor, 'allocation')
    pub = p.create_topic_publisher(topics.AZIMUTH_COMMANDS)
    duties: list[JointState] = []
    p.create_topic_subscription(topics.PWM_DUTY, duties.append)
    LinkBus.of(context).connect()
    c = node.calibration

    thrust = [0.3, -0.45, 1.5]
    angle = [0.4, -1.0, 1.98968]
    pub.publish(azimuth_msg(thrust, angle, stamp_ns=1_234_000_000))
    assert len(duties) == 1 and not node.neutral
    out = duties[-1]
    assert list(out.name) == channels
    assert convert.stamp_to_ns(out.header.stamp) == 1_234_000_000
    d = np.array(out.effort)
    assert np.all((d >= DUTY_MIN) & (d <= DUTY_MAX))
    expected = [v for f, a in zip(thrust, angle) for v in (c.thrust_to_duty(f),
                                                            c.angle_to_duty(a))]
    assert d.tolist() == pytest.approx(expected, abs=1e-12)
    # The same numbers from the profile's tables by hand: 0.3 N half-way from 7.0 % (0 N) to
    # 8.2 % (0.6 N), -0.45 N at 5.5 %, 1.5 N at 9.4 %; servo 0.4 rad on 6.85 .. 9.4 %.
    assert d[0::2].tolist() == pytest.approx([7.6, 5.5, 9.4], abs=1e-12)
    assert d[1] == pytest.approx(6.85 + 0.4 / 1.98968 * 2.55, abs=1e-12)
    assert d[5] == pytest.approx(9.4, abs=1e-12)

    # Beyond the tables: clipped to the PWM range.
    pub.publish(azimuth_msg([5.0, -5.0, 0.0], [3.0, -3.0, 0.0]))
    assert np.array(duties[-1].effort).tolist() == pytest.approx(
        [9.4, 9.4, 4.3, 4.3, NEUTRAL_DUTY, NEUTRAL_DUTY], abs=1e-12)

    # safe_state(): neutral at once.
    node.safe_state()
    assert np.array(duties[-1].effort).tolist() == pytest.approx(neutral)
    assert node.neutral

    # Refused (counted, nothing published): NaN thrust, NaN angle, unknown azimuth, lengths.
    pub.publish(azimuth_msg(thrust, angle))
    n, before = len(duties), list(node.duty)
    pub.publish(azimuth_msg([math.nan, 0.1, 0.1], angle))
    pub.publish(azimuth_msg(thrust, [0.0, math.inf, 0.0]))
    pub.publish(azimuth_msg([0.1], [0.0], names=['az_mid']))
    pub.publish(JointState(name=NAMES, effort=thrust, position=[0.0]))
    assert node.rejected == 4 and len(duties) == n and node.duty == before

    # Commands stop: neutral by itself after command_timeout, once.
    assert node.timeouts == 0 and not node.neutral
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(duties) == n + 1
    assert np.array(duties[-1].effort).tolist() == pytest.approx(neutral)
    assert node.neutral
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert node.timeouts == 1 and len(duties) == n + 1  # not repeated
