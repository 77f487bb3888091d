"""Node tests: sim arduino."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from support.nodes import TIMEOUT, add, probe
from support.saucer import NAMES, azimuth_msg, duty_msg, overrides

from enbarr_core.allocation.pwm_mapper_node import PwmMapperNode
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.arduino.sim import SimArduinoNode


def test_sim_arduino_round_trip_with_pwm_mapper(context, executor):
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
    assert pwm.calibration == arduino.calibration

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
    # Zero thrust is the middle of the dead band and comes back as zero.
    pub.publish(azimuth_msg([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
    assert list(applied[-1].effort) == [0.0, 0.0, 0.0] and arduino.neutral


def test_sim_arduino_refuses_out_of_range_duties_and_watchdog(context, executor, spin):
    node = add(executor, SimArduinoNode(
        node_name='arduino', context=context,
        parameter_overrides=overrides({'command_timeout': 0.1})))
    p = probe(context, executor, 'pwm')
    pub = p.create_topic_publisher(topics.PWM_DUTY)
    applied: list[JointState] = []
    p.create_topic_subscription(topics.SIM_AZIMUTH_COMMAND, applied.append)
    LinkBus.of(context).connect()
    c = node.calibration

    good = {f'{n}/{k}': d for n in NAMES for k, d in (('motor', 8.2), ('servo', 9.4))}
    pub.publish(duty_msg(good))
    assert len(applied) == 1 and not node.neutral
    assert list(applied[-1].effort) == pytest.approx([0.6] * 3, abs=1e-12)
    assert list(applied[-1].position) == pytest.approx([1.98968] * 3, abs=1e-12)

    for bad in (3.0, 12.0, 4.2, 9.5, math.nan, math.inf):
        n = node.refused
        pub.publish(duty_msg({**good, 'az_bow/motor': bad}))
        assert node.refused == n + 1, bad
        pub.publish(duty_msg({**good, 'az_stbd_aft/servo': bad}))
        assert node.refused == n + 2, bad
    pub.publish(duty_msg({'az_mid/motor': 7.0}))
    assert node.refused == 13 and len(applied) == 1
    # The limits themselves are valid duties.
    pub.publish(duty_msg({**good, 'az_bow/motor': 4.3, 'az_port_aft/motor': 9.4}))
    assert len(applied) == 2 and list(applied[-1].effort) == pytest.approx([-1.0, 1.5, 0.6])

    # Duty cycles stop: neutral by itself after command_timeout.
    assert node.timeouts == 0
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(applied) == 3 and node.neutral
    assert list(applied[-1].effort) == [c.duty_to_thrust(c.neutral_thrust_duty)] * 3 == [0.0] * 3
    assert list(applied[-1].position) == pytest.approx([0.0] * 3, abs=1e-12)
