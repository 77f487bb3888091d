"""Node tests: sim arduino (one behaviour per test)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from support.nodes import TIMEOUT, add, probe
from support.saucer import NAMES, azimuth_msg, duty_msg, overrides

from enbarr_core.allocation.pwm_mapper_node import PwmMapperNode
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.arduino.sim import SimArduinoNode

# Motor at 8.2 % (0.6 N), servo at 9.4 % (1.98968 rad) on every azimuth, in channel order.
GOOD = [8.2, 9.4] * len(NAMES)
MOTOR = {n: 2 * i for i, n in enumerate(NAMES)}
SERVO = {n: 2 * i + 1 for i, n in enumerate(NAMES)}


def with_duty(changes: dict[int, float]) -> list[float]:
    out = list(GOOD)
    for i, d in changes.items():
        out[i] = d
    return out


@dataclass
class Rig:
    node: SimArduinoNode
    pub: Any
    applied: list[JointState]


def rig(context: Any, executor: Any, timeout: float = 10.0, start: bool = True,
        **extra: Any) -> Rig:
    """The sim Arduino, a duty publisher and a listener; started (its neutral dropped)."""
    node = add(executor, SimArduinoNode(
        node_name='arduino', context=context,
        parameter_overrides=overrides({'command_timeout': timeout, **extra})))
    p = probe(context, executor, 'pwm')
    pub = p.create_topic_publisher(topics.PWM_DUTY)
    applied: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, applied.append)
    LinkBus.of(context).connect()
    if start:
        node.start()
        applied.clear()
    return Rig(node, pub, applied)


@pytest.fixture
def chain(context, executor):
    """PWM mapper -> sim Arduino, fed with azimuth commands."""
    pwm = add(executor, PwmMapperNode(node_name='pwm', context=context,
                                      parameter_overrides=overrides({'command_timeout': 10.0})))
    arduino = add(executor, SimArduinoNode(
        node_name='arduino', context=context,
        parameter_overrides=overrides({'command_timeout': 10.0})))
    p = probe(context, executor, 'allocation')
    pub = p.create_topic_publisher(topics.AZIMUTH_COMMANDS)
    applied: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, applied.append)
    LinkBus.of(context).connect()
    pwm.start()
    arduino.start()
    applied.clear()
    return pwm, arduino, pub, applied


def test_sim_arduino_shares_the_mapper_calibration(chain):
    pwm, arduino, _, _ = chain
    assert pwm.calibration == arduino.calibration


def test_sim_arduino_round_trip_with_pwm_mapper(chain):
    _, arduino, pub, applied = chain
    rng = np.random.default_rng(5)
    cases = [([0.3, -0.45, 1.5], [0.4, -1.0, 1.98968]),
             ([-1.0, 0.6, 1e-3], [-1.98968, 0.0, -0.2]),
             ([-2e-3, 1.2, -0.7], [1.0, 1.5, -1.5])]
    cases += [(list(rng.uniform(-1.0, 1.5, 3)), list(rng.uniform(-1.98968, 1.98968, 3)))
              for _ in range(20)]
    for thrust, angle in cases:
        n = len(applied)
        pub.publish(azimuth_msg(thrust, angle))
        assert len(applied) == n + 1
        out = applied[-1]
        assert list(out.name) == NAMES
        np.testing.assert_allclose(out.effort, thrust, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(out.position, angle, rtol=0.0, atol=1e-9)
    assert arduino.refused == 0 and not arduino.neutral


def test_sim_arduino_zero_thrust_is_the_dead_band_middle(chain):
    # Zero thrust is the middle of the dead band and comes back as zero.
    _, arduino, pub, applied = chain
    pub.publish(azimuth_msg([0.3, 0.3, 0.3], [0.0, 0.0, 0.0]))
    assert not arduino.neutral
    pub.publish(azimuth_msg([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
    assert list(applied[-1].effort) == [0.0, 0.0, 0.0] and arduino.neutral


def test_sim_arduino_publishes_nothing_until_started_then_neutral(context, executor):
    r = rig(context, executor, start=False)
    assert r.applied == [] and r.node.neutral
    r.node.start()
    assert len(r.applied) == 1 and list(r.applied[0].effort) == [0.0] * 3
    assert list(r.applied[0].position) == pytest.approx([0.0] * 3, abs=1e-12)


def test_sim_arduino_applies_duties_in_channel_order(context, executor):
    r = rig(context, executor)
    r.pub.publish(duty_msg(GOOD))
    assert len(r.applied) == 1 and not r.node.neutral
    assert list(r.applied[-1].effort) == pytest.approx([0.6] * 3, abs=1e-12)
    assert list(r.applied[-1].position) == pytest.approx([1.98968] * 3, abs=1e-12)
    # One channel each: az_port_aft's motor and az_stbd_aft's servo.
    r.pub.publish(duty_msg(with_duty({MOTOR['az_port_aft']: 4.3,
                                      SERVO['az_stbd_aft']: 6.85})))
    assert list(r.applied[-1].effort) == pytest.approx([0.6, -1.0, 0.6], abs=1e-12)
    assert list(r.applied[-1].position) == pytest.approx([1.98968, 1.98968, 0.0], abs=1e-12)


def test_sim_arduino_refuses_duties_outside_the_profile_limits(context, executor):
    r = rig(context, executor)
    r.pub.publish(duty_msg(GOOD))
    for bad in (3.0, 12.0, 4.2, 9.5, math.nan, math.inf):
        n = r.node.refused
        r.pub.publish(duty_msg(with_duty({MOTOR['az_bow']: bad})))
        assert r.node.refused == n + 1, bad
        r.pub.publish(duty_msg(with_duty({SERVO['az_stbd_aft']: bad})))
        assert r.node.refused == n + 2, bad
    assert r.node.refused == 12 and len(r.applied) == 1
    # The limits themselves are valid duties.
    r.pub.publish(duty_msg(with_duty({MOTOR['az_bow']: 4.3, MOTOR['az_port_aft']: 9.4})))
    assert len(r.applied) == 2 and list(r.applied[-1].effort) == pytest.approx([-1.0, 1.5, 0.6])


def test_sim_arduino_limits_come_from_the_profile(context, executor):
    # With a wider range in the profile, 3.0 % and 12.0 % are accepted (clipped by the tables).
    r = rig(context, executor, **{'pwm.duty_min_percent': 2.0, 'pwm.duty_max_percent': 12.5})
    r.pub.publish(duty_msg(with_duty({MOTOR['az_bow']: 3.0, MOTOR['az_port_aft']: 12.0})))
    assert r.node.refused == 0 and len(r.applied) == 1
    assert list(r.applied[-1].effort) == pytest.approx([-1.0, 1.5, 0.6])
    r.pub.publish(duty_msg(with_duty({MOTOR['az_bow']: 1.9})))
    assert r.node.refused == 1 and len(r.applied) == 1


def test_sim_arduino_refuses_a_wrong_label_or_size(context, executor):
    r = rig(context, executor)

    def message(label: str, size: int, stride: int, data: list[float]) -> Float64MultiArray:
        msg = Float64MultiArray(data=data)
        msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)]
        return msg

    n = len(GOOD)
    bad = [message('effort', n, n, GOOD),                    # not a duty cycle
           message('duty_cycle_percent', n - 1, n - 1, GOOD[:-1]),  # a channel missing
           message('duty_cycle_percent', n + 2, n + 2, GOOD + [7.0, 7.0]),  # one too many
           message('duty_cycle_percent', n, n, GOOD[:-1]),   # size says 6, data has 5
           message('duty_cycle_percent', n, 1, GOOD),        # stride is not the size
           Float64MultiArray(data=GOOD)]                     # no layout at all
    for i, msg in enumerate(bad):
        r.pub.publish(msg)
        assert r.node.refused == i + 1 and not r.applied, i
    r.pub.publish(message('duty_cycle_percent', n, n, GOOD))
    assert r.node.refused == len(bad) and len(r.applied) == 1


def test_sim_arduino_goes_neutral_when_duties_stop(context, executor, spin):
    r = rig(context, executor, timeout=0.1)
    c = r.node.calibration
    r.pub.publish(duty_msg(GOOD))
    assert r.node.timeouts == 0 and len(r.applied) == 1
    assert spin(executor, lambda: r.node.timeouts == 1, TIMEOUT)
    assert len(r.applied) == 2 and r.node.neutral
    assert list(r.applied[-1].effort) == [c.duty_to_thrust(c.neutral_thrust_duty)] * 3 == [0.0] * 3
    assert list(r.applied[-1].position) == pytest.approx([0.0] * 3, abs=1e-12)


def test_sim_arduino_refuses_a_command_timeout_shorter_than_two_duty_periods(
        context, executor):
    # A timeout inside its range but shorter than the input's period is harmful
    # (the outputs go neutral between every two duty messages); refuse it, saying why.
    from rclpy.parameter import Parameter
    from support.saucer import SimClock
    r = rig(context, executor)
    clock = SimClock(r.node)
    for _ in range(10):
        clock.advance(0.02)
        r.pub.publish(duty_msg(GOOD))
    result = r.node.set_parameters([Parameter('command_timeout', value=0.03)])[0]
    assert not result.successful, 'a timeout shorter than two duty periods was accepted'
    assert 'command_timeout' in result.reason and 'measured 0.02 s' in result.reason
    assert r.node.set_parameters([Parameter('command_timeout', value=0.25)])[0].successful
    assert r.node.status()[0] == 0
    r.node.set_parameters([Parameter('command_timeout', value=10.0)])
    r.pub.publish(duty_msg([float('nan')] * len(GOOD)))  # refused inputs make it DEGRADED
    r.pub.publish(duty_msg([float('nan')] * len(GOOD)))
    level, message = r.node.status()
    assert level == 1 and 'pwm/duty_cycle: refused 2 of 2' in message, message
