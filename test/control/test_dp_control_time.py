"""Node tests: dp control under hostile input: one joystick at a time, the time
policy on estimates, references and the joystick, honest diagnostics, rate-aware parameters.
"""

from __future__ import annotations


import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Joy
from support.nodes import TIMEOUT, probe
from support.saucer import DpHarness, TRIANGLE, joy_msg, odometry_msg

from enbarr_interfaces import convert, topics
from enbarr_interfaces.modes import Mode

ETA0 = np.array([0.3, -0.2, 0.4])


def stamped(msg: Joy, t_ns: int) -> Joy:
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    return msg


def spin_a_little(h: DpHarness) -> None:
    h.spin(h.executor, lambda: False, 0.05)


def test_two_joysticks_are_refused_named_and_the_loss_rule_applies(context, executor, spin):
    # A second publisher on a command topic once silently took turns with the first.
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    h.estimate(ETA0)
    h.joy(joy_msg(0.5))
    assert h.taus[-1][0] > 0.0  # one joystick: its sticks are the force
    intruder = probe(context, executor, 'intruder')
    other = intruder.create_publisher(Joy, topics.JOY.name, topics.JOY.qos)
    assert spin(executor, lambda: h.node.count_publishers(topics.JOY.name) == 2, TIMEOUT)
    n = len(h.taus)
    for _ in range(10):
        h.joy_pub.publish(joy_msg(0.5))
        other.publish(joy_msg(-0.5))
        spin_a_little(h)
    # At the first contested sample, without waiting joy_timeout (the simulated clock stands
    # still): manual with zero force, as on joystick loss, and nothing taken from either.
    assert h.node.mode is Mode.MANUAL
    assert [t.tolist() for t in h.taus[n:]] == [[0.0, 0.0, 0.0]], h.taus[n:]
    assert h.node.health.totals[('joy', 'contested')] >= 10
    level, message, _ = h.node.diagnostic_status()
    assert level == 2 and '/operator' in message and '/intruder' in message, message
    # The intruder leaves: the operator's joystick is taken again.
    intruder.destroy_publisher(other)
    assert spin(executor, lambda: h.node.count_publishers(topics.JOY.name) == 1, TIMEOUT)
    h.joy(joy_msg(0.5))
    assert h.taus[-1][0] > 0.0


def test_a_future_estimate_never_becomes_the_controllers_time_base(context, executor, spin):
    h = DpHarness(context, executor, spin)
    h.estimate(ETA0)
    h.joy(joy_msg())
    h.joy(joy_msg(pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    for _ in range(5):
        h.estimate(ETA0)
    n = len(h.taus)
    h.odom_pub.publish(odometry_msg(h.clock.ns + 20_000_000_000, ETA0))
    for _ in range(20):
        h.estimate(ETA0 + [0.05, 0.0, 0.0])
    assert len(h.taus) == n + 20, 'good estimates after the future one were dropped'
    assert max(h.tau_stamps) <= h.clock.ns
    assert h.node.health.totals[('observer/odometry', 'future')] == 1
    assert h.node.mode is Mode.AUTOMATIC


def test_joystick_samples_stamped_ahead_or_behind_are_refused(context, executor, spin):
    h = DpHarness(context, executor, spin)
    t = h.clock.ns
    h.joy(stamped(joy_msg(0.2), t))
    assert h.tau_stamps[-1] == t
    n = len(h.taus)
    for msg in (stamped(joy_msg(0.9), t + 20_000_000_000), stamped(joy_msg(0.9), t - 1)):
        h.joy_pub.publish(msg)
        assert spin(executor, lambda: h.node.health.totals[('joy', 'future')]
                    + h.node.health.totals[('joy', 'not_newer')] >= 1, TIMEOUT)
    assert spin(executor, lambda: h.node.health.totals[('joy', 'not_newer')] >= 1, TIMEOUT)
    assert len(h.taus) == n and max(h.tau_stamps) <= h.clock.ns
    h.clock.advance(0.05)
    h.joy(stamped(joy_msg(0.3), h.clock.ns))  # the next good sample is taken
    assert len(h.taus) == n + 1


def test_force_stamps_never_go_back_when_the_source_changes(context, executor, spin):
    # The force is stamped with the sample it answers: the estimate's in automatic, the
    # joystick's in manual (another computer's clock), the clock's on a fall-back. Downstream
    # refuses a force not newer than the last, so the stream must stay ordered.
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    h.estimate(ETA0)
    h.joy(stamped(joy_msg(0.2), h.clock.ns))
    h.clock.advance(0.3)  # joystick lost: zero force stamped now
    assert spin(executor, lambda: h.taus[-1].tolist() == [0.0, 0.0, 0.0], TIMEOUT)
    h.joy(stamped(joy_msg(0.4), h.clock.ns - 100_000_000))  # a joystick clock 0.1 s behind
    assert np.all(np.diff(h.tau_stamps) > 0), h.tau_stamps


def test_force_stamps_start_over_when_the_clock_goes_back(context, executor, spin):
    # A restarted simulation: forces are stamped on the new clock, not 1 ns after the old
    # run's last force, which every node downstream would refuse as from the future.
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    h.estimate(ETA0)
    h.joy(stamped(joy_msg(0.2), h.clock.ns))
    h.clock.advance(60.0)
    h.joy(stamped(joy_msg(0.3), h.clock.ns))
    h.clock.set(h.clock.ns - 30_000_000_000)
    h.joy(stamped(joy_msg(0.2), h.clock.ns))
    assert h.tau_stamps[-1] == h.clock.ns, (h.tau_stamps[-3:], h.clock.ns)


def test_rate_dependent_parameters_are_refused_with_the_measured_period(
        context, executor, spin):
    h = DpHarness(context, executor, spin)
    node = h.node
    assert node.set_parameters([Parameter('joy_timeout', value=0.06)])[0].successful
    assert node.set_parameters([Parameter('joy_timeout', value=0.5)])[0].successful
    for _ in range(12):
        h.estimate(ETA0)
        h.clock.advance(0.05)
        h.joy(stamped(joy_msg(), h.clock.ns))
    result = node.set_parameters([Parameter('joy_timeout', value=0.06)])[0]
    assert not result.successful
    assert 'joy_timeout' in result.reason and 'measured 0.05 s' in result.reason, result.reason
    result = node.set_parameters([Parameter('estimate_max_age', value=0.03)])[0]
    assert not result.successful
    assert 'estimate_max_age' in result.reason and 'measured 0.02 s' in result.reason
    result = node.set_parameters([Parameter('max_future', value=0.03)])[0]
    assert not result.successful and 'max_future' in result.reason
    assert node.settings.joy_timeout == 0.5 and node.settings.estimate_max_age == 1.5
    assert node.set_parameters([Parameter('joy_timeout', value=0.2)])[0].successful


@pytest.mark.parametrize('name', ['observer/odometry', 'observer/bias'])
def test_refused_estimates_make_the_node_degraded(context, executor, spin, name: str):
    h = DpHarness(context, executor, spin)
    from geometry_msgs.msg import WrenchStamped
    for _ in range(10):
        h.estimate(ETA0)
    h.node.diagnostic_status()  # close the window
    for _ in range(5):
        if name == 'observer/odometry':
            h.odom_pub.publish(odometry_msg(h.clock.ns + 5_000_000_000, ETA0))
        else:
            w = WrenchStamped()
            convert.ns_to_stamp(h.clock.ns + 5_000_000_000, w.header.stamp)
            h.bias_pub.publish(w)
    level, message, values = h.node.diagnostic_status()
    assert level == 1 and f'{name}: refused 5 of 5' in message, message
    assert values[f'{name}.future'] == 5


