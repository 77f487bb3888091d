"""Node tests: dp control node (operator modes and the DP controller), with the guidance node
that feeds it references. One behaviour per test.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_msgs.msg import Bool
from support.nodes import TIMEOUT, add, call, probe
from support.saucer import (
    CROSS, DpHarness, SQUARE, TRIANGLE, joy_msg, node_parameters, odometry_msg, overrides)

from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_interfaces.modes import Mode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.guidance.guidance import HoldPose
from enbarr_core.guidance.guidance_node import msg_to_reference, reference_to_msg
from enbarr_interfaces import convert, topics

MANUAL_TAU_MAX = np.array(node_parameters('dp_control')['manual_tau_max'])
STICKS = (0.5, -0.4, 0.25)
ETA0 = np.array([0.3, -0.2, 0.4])


def manual_force(sticks: tuple[float, ...] = STICKS) -> np.ndarray:
    # Joy axes are float32: the force is tau_max times the stick as it arrived.
    return MANUAL_TAU_MAX * np.array(sticks, dtype=np.float32).astype(float)


def to_automatic(h: DpHarness) -> None:
    """Manual with the sticks at STICKS, an estimate at ETA0, then triangle."""
    h.estimate(ETA0)
    h.joy(joy_msg(*STICKS))
    h.joy(joy_msg(*STICKS, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')


def test_mode_is_published_latched_and_starts_manual(context, executor, spin):
    h = DpHarness(context, executor, spin)  # subscribes after the node published
    assert h.modes == ['manual'] and h.node.mode is Mode.MANUAL


def test_manual_sticks_are_the_force(context, executor, spin):
    h = DpHarness(context, executor, spin)
    assert h.node.settings.manual_tau_max == tuple(MANUAL_TAU_MAX)
    h.estimate(ETA0)
    assert not h.taus  # in manual the estimate does not produce force
    h.joy(joy_msg(*STICKS))
    assert len(h.taus) == 1
    assert h.taus[-1] == pytest.approx(manual_force(), abs=1e-12)


def test_automatic_entry_is_bumpless_and_holds_the_pose(context, executor, spin):
    h = DpHarness(context, executor, spin)
    to_automatic(h)
    # The first controller output equals the manual force of the moment although the vessel
    # is now 0.2 m off the held pose and moving (a plain PID would jump to about -2 N).
    assert h.node.mode is Mode.AUTOMATIC and h.node.refusals == 0
    assert len(h.taus) == 1  # the joystick no longer publishes force
    h.estimate(ETA0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 2
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)
    assert h.tau_stamps[-1] == h.t_odom  # stamped with the estimate it answers
    assert len(h.refs) == 1  # holding the pose where the vessel was at the switch
    assert msg_to_reference(h.refs[-1]).eta_d == pytest.approx(ETA0, abs=1e-12)
    h.estimate(ETA0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 3 and len(h.refs) == 2  # the controller runs on every estimate


def test_cross_returns_to_manual_with_the_sticks_force(context, executor, spin):
    h = DpHarness(context, executor, spin)
    to_automatic(h)
    h.estimate(ETA0 + [0.2, 0.0, 0.0])
    h.joy(joy_msg(*STICKS, pressed=(CROSS,)))
    h.wait_mode('manual')
    assert h.taus[-1] == pytest.approx(manual_force(), abs=1e-12)
    n_taus = len(h.taus)
    h.estimate(ETA0)  # no reference, no force from the controller in manual
    assert len(h.taus) == n_taus


def test_automatic_is_refused_without_a_fresh_estimate(context, executor, spin):
    h = DpHarness(context, executor, spin)
    h.estimate(ETA0, age=5.0)  # > estimate_max_age 1.5 s: dead-reckoning for too long
    h.joy(joy_msg(*STICKS))
    h.joy(joy_msg(*STICKS, pressed=(TRIANGLE,)))
    assert h.node.refusals == 1 and h.node.mode is Mode.MANUAL
    h.joy(joy_msg(*STICKS))
    assert h.modes == ['manual']


def test_guidance_is_refused_without_a_path(context, executor, spin):
    h = DpHarness(context, executor, spin)
    assert not h.guidance.settings.waypoints and not h.node.path_available
    h.estimate(ETA0, age=0.0)
    h.joy(joy_msg(*STICKS))
    h.joy(joy_msg(*STICKS, pressed=(SQUARE,)))
    assert h.node.refusals == 1 and h.node.mode is Mode.MANUAL
    h.joy(joy_msg(*STICKS))
    assert h.modes == ['manual']
    # The reason reaches /diagnostics, where an operator station reads it.
    assert h.node.diagnostic_status()[2]['last_refusal'] == 'guidance: no path configured'


def test_guidance_with_a_path_is_bumpless_and_follows_it(context, executor, spin):
    h = DpHarness(context, executor, spin)
    result = h.guidance.set_parameters(
        [Parameter('path.waypoints', value=[0.3, -0.2, 2.3, -0.2])])
    assert result[0].successful, result[0].reason
    assert h.guidance.settings.waypoints == ((0.3, -0.2), (2.3, -0.2))
    h.wait_path_available(True)  # announced (latched) by the guidance node
    h.estimate(ETA0)
    h.joy(joy_msg(*STICKS))
    h.joy(joy_msg(*STICKS, pressed=(SQUARE,)))
    h.wait_mode('guidance')
    assert h.node.mode is Mode.GUIDANCE and h.node.refusals == 0
    n_refs, n_taus = len(h.refs), len(h.taus)
    h.estimate(ETA0)
    assert len(h.refs) == n_refs + 1 and len(h.taus) == n_taus + 1
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)  # bumpless
    ref = h.refs[-1]
    assert convert.stamp_to_ns(ref.header.stamp) == h.t_odom
    eta_d, nu_d = msg_to_reference(ref).eta_d, msg_to_reference(ref).nu_d
    # On the path, heading kept: the topic carries no position reference in line of sight,
    # the law's own reference keeps the closest point on the path.
    assert np.isnan(eta_d[:2]).all() and eta_d[2] == pytest.approx(0.4, abs=1e-9)
    assert h.guidance.reference.eta_d == pytest.approx([0.3, -0.2, 0.4], abs=1e-9)
    assert math.hypot(nu_d[0], nu_d[1]) == pytest.approx(0.2)  # path.speed


def test_a_joystick_sample_with_nan_is_refused(context, executor, spin):
    h = DpHarness(context, executor, spin)
    h.joy(joy_msg(*STICKS))
    rejected, n_taus = h.node.manager.rejected_samples, len(h.taus)
    tau_before = h.node.tau.copy()
    h.joy(joy_msg(math.nan, 0.9, 0.9))
    assert h.node.manager.rejected_samples > rejected
    assert len(h.taus) == n_taus and h.node.mode is Mode.MANUAL
    np.testing.assert_array_equal(h.node.tau, tau_before)


def test_joystick_loss_returns_to_manual_with_zero_force(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    to_automatic(h)
    h.estimate(ETA0 + [0.1, 0.1, 0.0])
    h.estimate(ETA0 + [0.1, 0.1, 0.0])
    assert np.any(h.taus[-1])
    n_modes = len(h.modes)
    h.clock.advance(0.3)  # silent for longer than joy_timeout: the supervisor (10 Hz) acts
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)
    assert h.node.mode is Mode.MANUAL
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    assert h.tau_stamps[-1] == h.clock.ns


def test_stale_estimate_in_automatic_falls_back_to_manual(context, executor, spin):
    h = DpHarness(context, executor, spin, {'estimate_max_age': 0.5})
    h.estimate([0.0, 0.0, 0.0])
    h.joy(joy_msg(0.3))
    h.joy(joy_msg(0.3, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    h.estimate([0.05, 0.0, 0.0], age=0.3)
    assert np.any(h.taus[-1])
    h.estimate([0.05, 0.0, 0.0], age=0.6)  # the observer has been dead-reckoning too long
    n = len(h.modes)
    h.clock.advance(0.15)  # the next supervisor tick; the joystick (0.5 s) is not lost yet
    assert spin(executor, lambda: len(h.modes) > n and h.modes[-1] == 'manual', TIMEOUT)
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    assert h.node.manager.tau_manual.tolist() == [0.0, 0.0, 0.0]


def test_no_reference_outside_manual_falls_back_to_manual(context, executor, spin):
    """A profile without a guidance node (or one that cannot make a reference) must not
    leave the vessel in automatic with the force of the switch."""
    h = DpHarness(context, executor, spin, {'estimate_max_age': 0.5, 'joy_timeout': 5.0})
    to_automatic(h)
    h.guidance.law = None  # the guidance node makes nothing from now on
    n = len(h.modes)
    for _ in range(4):  # estimates keep coming: only the references are missing
        h.clock.advance(0.2)
        h.estimate(ETA0)
        spin(executor, lambda: len(h.modes) > n, 0.2)
    assert spin(executor, lambda: len(h.modes) > n and h.modes[-1] == 'manual', TIMEOUT)
    assert h.node.mode is Mode.MANUAL
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]


def test_a_reference_in_manual_or_malformed_is_not_applied(context, executor, spin):
    h = DpHarness(context, executor, spin)
    ref_pub = h.probe.create_topic_publisher(topics.GUIDANCE_REFERENCE)
    ref = HoldPose(ETA0 + [1.0, 0.0, 0.0]).reference(ETA0, 0.02)
    h.estimate(ETA0)
    n_taus = len(h.taus)
    ref_pub.publish(reference_to_msg(ref, odometry_msg(h.t_odom, ETA0).header))
    assert len(h.taus) == n_taus  # manual: the operator has the force
    to_automatic(h)
    h.guidance.law = None  # only this test's references from now on
    h.estimate(ETA0)
    n_taus = len(h.taus)
    bad = reference_to_msg(ref, odometry_msg(h.t_odom, ETA0).header)
    bad.joint_names = ['thruster']
    ref_pub.publish(bad)
    assert h.node.bad_references == 1 and len(h.taus) == n_taus
    ref_pub.publish(reference_to_msg(ref, odometry_msg(h.t_odom, ETA0).header))
    assert h.node.bad_references == 1 and len(h.taus) == n_taus + 1


def test_a_reference_before_its_estimate_waits_for_it(context, executor, spin):
    h = DpHarness(context, executor, spin)
    to_automatic(h)
    ref_pub = h.probe.create_topic_publisher(topics.GUIDANCE_REFERENCE)
    h.guidance.law = None  # only this test's references from now on
    t = h.clock.advance(0.02)  # the next estimate's time: its reference comes first
    assert t == h.t_odom + 20_000_000
    ref = HoldPose(ETA0).reference(ETA0, 0.02)
    n_taus = len(h.taus)
    ref_pub.publish(reference_to_msg(ref, odometry_msg(t, ETA0).header))
    assert len(h.taus) == n_taus  # its estimate has not arrived
    h.estimate(ETA0 + [0.1, 0.0, 0.0])
    assert h.t_odom == t and len(h.taus) == n_taus + 1 and h.tau_stamps[-1] == t


@pytest.mark.parametrize('missing', ['vessel.inertia', 'kp', 'tau_max'])
def test_vessel_data_and_gains_are_required(context, missing):
    given = {k: v for k, v in node_parameters('dp_control').items() if k != missing}
    with pytest.raises(ConfigurationError,
                       match=f"parameter '{missing}' is not set; the profile must give it"
                       ) as info:
        DpControlNode(node_name='dp_control', context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
    assert 'Traceback' not in str(info.value)


@pytest.mark.parametrize('change, match', [
    ({'joy.manual': ''}, 'joy.manual: required with joy.layout'),
    ({'joy.layout': 'xbox'}, "joy.layout: unknown layout 'xbox'"),
    ({'joy.automatic': 'x'}, "joy.automatic: 'x' is no button of layout enbarr_ds4"),
])
def test_joystick_names_are_checked_naming_the_parameter(context, change, match):
    given = {**node_parameters('dp_control'), **change}
    with pytest.raises(ConfigurationError, match=match) as info:
        DpControlNode(node_name='dp_control', context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
    assert info.value.parameter == next(iter(change)) and 'Traceback' not in str(info.value)


def test_dp_control_live_gains(context, executor, spin):
    node = add(executor, DpControlNode(node_name='dp_control', context=context,
                                       parameter_overrides=overrides(node='dp_control')))
    caller = probe(context, executor, 'ros2_param')
    from rclpy.parameter_client import AsyncParameterClient
    client = AsyncParameterClient(caller, 'dp_control')
    assert spin(executor, client.services_are_ready, TIMEOUT), 'parameter services not found'

    def set_(name: str, value: Any) -> Any:
        response = call(executor, client.set_parameters([Parameter(name, value=value)]))
        assert len(response.results) == 1
        return response.results[0]

    def get(name: str) -> Any:
        response = call(executor, client.get_parameters([name]))
        return convert.parameter_value_to_python(response.values[0])

    kp0 = tuple(node.controller.settings.Kp)
    assert kp0 == tuple(node_parameters('dp_control')['kp'])
    assert not node.controller.ramping

    result = set_('kp', [10.0, -1.0, 1.5])
    assert not result.successful and 'kp' in result.reason
    result = set_('kp', [10.0, 10.0])
    assert not result.successful and 'kp' in result.reason
    result = set_('joy.guidance', 'triangle')
    assert not result.successful and 'buttons' in result.reason
    result = set_('kp', 'stiff')
    assert not result.successful and result.reason
    # Every refusal kept the old values, in the node and in its controller.
    assert get('kp') == list(kp0)
    assert get('joy.guidance') == 'square'
    assert tuple(node.controller.settings.Kp) == kp0
    assert node.manager.mapping.button_guidance == SQUARE
    assert not node.controller.ramping

    result = set_('kp', [20.0, 20.0, 3.0])
    assert result.successful, result.reason
    assert tuple(node.controller.settings.Kp) == (20.0, 20.0, 3.0)
    assert node.controller.ramping  # blended in over gain_ramp_time, not stepped
    assert get('kp') == [20.0, 20.0, 3.0]
    # The ramp ends after gain_ramp_time (1 s) of control steps.
    ref = HoldPose((0.0, 0.0, 0.0)).reference((0.0, 0.0, 0.0), 0.1)
    for _ in range(11):
        node.controller.step((0.1, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), ref, 0.1)
    assert not node.controller.ramping

    result = set_('joy_timeout', 0.3)
    assert result.successful, result.reason
    assert node.manager.joy_timeout == 0.3


# -- the joystick-loss rule: connection state, not the message rate -------------------

def hold_automatic(h: DpHarness, seconds: float, heartbeat_every: int = 4) -> None:
    """Estimates every 20 ms for ``seconds`` of simulated time; a heartbeat every few, no
    joystick sample at all (a driver that publishes only on change, sticks at rest).
    """
    for k in range(round(seconds / 0.02)):
        h.estimate(ETA0)
        if k % heartbeat_every == 0:
            h.heartbeat()


def test_resting_stick_in_automatic_stays_automatic_for_many_timeouts(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    assert h.node.manager.loss_rule == 'connection'  # the Saucer's layout, enbarr_ds4
    to_automatic(h)
    n_modes = len(h.modes)
    hold_automatic(h, 3.0)  # 15 joy_timeouts without a joystick sample
    assert h.node.mode is Mode.AUTOMATIC and h.modes[n_modes - 1:] == ['automatic']


def test_held_stick_keeps_its_force_without_new_samples(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    h.joy(joy_msg(*STICKS))
    for _ in range(15):  # 1.5 s, 7 timeouts: heartbeats only
        h.clock.advance(0.1)
        h.heartbeat()
    spin(executor, lambda: False, 0.3)  # the supervisor runs
    assert h.node.mode is Mode.MANUAL
    np.testing.assert_allclose(h.node.manager.tau_manual, manual_force())
    assert not any(np.array_equal(t, np.zeros(3)) for t in h.taus[-3:])


def test_disconnect_is_manual_with_zero_force_at_once(context, executor, spin):
    h = DpHarness(context, executor, spin)
    to_automatic(h)
    n_modes = len(h.modes)
    h.heartbeat(False)  # no clock advance: at once, not joy_timeout later
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    # Samples while disconnected drive nothing.
    h.joy_pub.publish(joy_msg(*STICKS))
    spin(executor, lambda: h.node.manager.unconnected_samples > 0, TIMEOUT)
    assert h.node.manager.tau_manual.tolist() == [0.0, 0.0, 0.0]
    assert h.node.health.totals[('joy', 'not_connected')] >= 1


def test_joy_timeout_is_judged_against_the_heartbeat_not_rare_samples(context, executor, spin):
    """Samples 1 s apart (sticks moved now and then), heartbeats every 0.1 s: joy_timeout
    0.3 s covers two heartbeats and is fine; 0.15 s is refused with the heartbeat's period.
    """
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.3})
    for k in range(12):
        h.clock.advance(0.1)
        h.heartbeat()
        if k % 10 == 0:
            h.joy(joy_msg(0.1 * k / 10))
    node = h.node
    assert node.settings.rate_problem(None, node.joy_period.period) is None
    result = node.set_parameters([Parameter('joy_timeout', value=0.15)])[0]
    assert not result.successful and 'measured 0.1 s' in result.reason, result.reason


def test_heartbeat_loss_is_manual_with_zero_force(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    to_automatic(h)
    n_modes = len(h.modes)
    h.clock.advance(0.3)
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]


def test_steady_rate_driver_keeps_the_timeout_rule(context, executor, spin):
    """joy.loss timeout (a steady-rate driver): heartbeats do not keep the joystick."""
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2, 'joy.loss': 'timeout'})
    to_automatic(h)
    n_modes = len(h.modes)
    h.connected_pub.publish(Bool(data=True))
    h.clock.advance(0.3)
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)


def test_a_republished_sample_is_a_sign_of_life_not_a_stale_one(context, executor, spin):
    """ds4_driver's autorepeat republishes the last Joy with its old stamp."""
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2, 'joy.loss': 'timeout'})
    msg = joy_msg(*STICKS)
    msg.header.stamp = convert.ns_to_stamp(h.clock.advance(0.01))
    h.joy(msg)
    repeats = []
    real = h.node.manager.on_repeat
    h.node.manager.on_repeat = lambda now: (repeats.append(now), real(now))
    for k in range(10):  # 1 s, 5 timeouts
        h.clock.advance(0.1)
        h.joy_pub.publish(msg)
        assert spin(executor, lambda: len(repeats) > k, TIMEOUT)
    spin(executor, lambda: False, 0.3)
    assert h.node.mode is Mode.MANUAL and h.node.manager.tau_manual.any()
    totals = h.node.health.report(1.0)[2]
    assert not {k: n for k, n in totals.items() if k.startswith('joy.') and k != 'joy.accepted'}
