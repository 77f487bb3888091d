"""Node tests: dp control node."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from support.nodes import TIMEOUT, add, call, probe
from support.saucer import CROSS, SQUARE, TRIANGLE, DpHarness, joy_msg, overrides

from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_core.control.modes import Mode
from enbarr_core.guidance.guidance import HoldPose
from enbarr_interfaces import convert


def test_dp_control_modes_bumpless_refusals_and_joystick_loss(context, executor, spin):
    h = DpHarness(context, executor, spin, {'joy_timeout': 0.2})
    node = h.node
    assert spin(executor, lambda: h.joy_pub.get_subscription_count() > 0, TIMEOUT)
    h.wait_mode('manual')  # latched: a late subscriber still learns the mode
    assert h.modes == ['manual'] and node.mode is Mode.MANUAL
    manual_tau_max = np.array([1.5, 1.5, 0.2])  # the default
    assert node.settings['manual_tau_max'] == manual_tau_max.tolist()

    eta0 = np.array([0.3, -0.2, 0.4])
    h.estimate(eta0)
    assert not h.taus  # in manual the estimate does not produce force

    # Manual: the sticks are the force.
    sticks = (0.5, -0.4, 0.25)
    h.joy(joy_msg(*sticks))
    assert len(h.taus) == 1
    # Joy axes are float32: the force is tau_max times the stick as it arrived.
    tau_manual = manual_tau_max * np.array(sticks, dtype=np.float32).astype(float)
    assert h.taus[-1] == pytest.approx(tau_manual, abs=1e-12)

    # Triangle with a fresh estimate: automatic, and bumpless. The first controller output
    # equals the manual force of the moment although the vessel is now 0.2 m off the held
    # pose and moving (a plain PID would jump to about -2 N in surge).
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    assert node.mode is Mode.AUTOMATIC and node.refusals == 0
    assert len(h.taus) == 1  # the joystick no longer publishes force
    h.estimate(eta0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 2
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)
    assert h.tau_stamps[-1] == h.t_odom  # stamped with the estimate it answers
    assert len(h.refs) == 1  # holding the pose where the vessel was at the switch
    assert convert.pose_to_eta(h.refs[-1].pose.pose) == pytest.approx(eta0, abs=1e-12)
    h.estimate(eta0 + [0.2, 0.0, 0.0], nu=(0.05, 0.0, 0.0))
    assert len(h.taus) == 3 and len(h.refs) == 2  # the controller runs on every estimate

    # Cross: manual again, the sticks' force at once.
    h.joy(joy_msg(*sticks, pressed=(CROSS,)))
    h.wait_mode('manual')
    assert h.taus[-1] == pytest.approx(tau_manual, abs=1e-12)

    # Triangle while the observer dead-reckons for too long: refused, still manual.
    h.estimate(eta0, age=5.0)  # > estimate_max_age 1.5 s
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    assert node.refusals == 1 and node.mode is Mode.MANUAL
    h.joy(joy_msg(*sticks))
    assert h.modes[-1] == 'manual' and 'automatic' not in h.modes[2:]

    # Square without path.waypoints: refused, even with a fresh estimate.
    h.estimate(eta0, age=0.0)
    h.joy(joy_msg(*sticks, pressed=(SQUARE,)))
    assert node.refusals == 2 and node.mode is Mode.MANUAL
    h.joy(joy_msg(*sticks))

    # With a path: guidance, and the guidance reference follows each estimate.
    result = node.set_parameters([Parameter('path.waypoints', value=[0.3, -0.2, 2.3, -0.2])])
    assert result[0].successful, result[0].reason
    assert node.settings['waypoints'] == [(0.3, -0.2), (2.3, -0.2)]
    h.joy(joy_msg(*sticks, pressed=(SQUARE,)))
    h.wait_mode('guidance')
    assert node.mode is Mode.GUIDANCE and node.refusals == 2
    n_refs, n_taus = len(h.refs), len(h.taus)
    h.estimate(eta0)
    assert len(h.refs) == n_refs + 1 and len(h.taus) == n_taus + 1
    np.testing.assert_allclose(h.taus[-1], h.taus[-2], rtol=0.0, atol=1e-9)  # bumpless too
    ref = h.refs[-1]
    assert convert.stamp_to_ns(ref.header.stamp) == h.t_odom
    eta_d, nu_d = convert.pose_to_eta(ref.pose.pose), convert.twist_to_nu3(ref.twist.twist)
    assert eta_d == pytest.approx([0.3, -0.2, 0.4], abs=1e-9)  # on the path, heading kept
    assert math.hypot(nu_d[0], nu_d[1]) == pytest.approx(0.2)  # path.speed
    h.joy(joy_msg(*sticks, pressed=(CROSS,)))
    h.wait_mode('manual')

    # A joystick sample with a NaN axis: refused and counted, no force published.
    rejected, n_taus = node.manager.rejected_samples, len(h.taus)
    tau_before = node.tau.copy()
    h.joy(joy_msg(math.nan, 0.9, 0.9))
    assert node.manager.rejected_samples > rejected
    assert len(h.taus) == n_taus and node.mode is Mode.MANUAL
    np.testing.assert_array_equal(node.tau, tau_before)

    # Automatic, then the joystick goes silent for longer than joy_timeout (0.2 s): the
    # supervisor (10 Hz timer) returns to manual and publishes zero force.
    h.joy(joy_msg(*sticks, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')
    h.estimate(eta0 + [0.1, 0.1, 0.0])
    assert np.any(h.taus[-1])
    n_modes = len(h.modes)
    h.clock.advance(0.3)
    assert spin(executor, lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual', TIMEOUT)
    assert node.mode is Mode.MANUAL
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]
    assert h.tau_stamps[-1] == h.clock.ns


def test_dp_control_stale_estimate_in_automatic_falls_back_to_manual(context, executor, spin):
    h = DpHarness(context, executor, spin, {'estimate_max_age': 0.5})
    h.estimate([0.0, 0.0, 0.0])
    assert spin(executor, lambda: h.joy_pub.get_subscription_count() > 0, TIMEOUT)
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


def test_dp_control_live_gains(context, executor, spin):
    node = add(executor, DpControlNode(node_name='dp_control', context=context,
                                       parameter_overrides=overrides()))
    caller = probe(context, executor, 'ros2_param')
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
    assert kp0 == (10.0, 10.0, 1.5)
    assert not node.controller.ramping

    result = set_('Kp', [10.0, -1.0, 1.5])
    assert not result.successful and 'Kp' in result.reason
    result = set_('Kp', [10.0, 10.0])
    assert not result.successful and 'Kp' in result.reason
    result = set_('path.heading', 'sideways')
    assert not result.successful and 'path.heading' in result.reason
    result = set_('joy.button_guidance', 2)  # = triangle
    assert not result.successful and 'buttons' in result.reason
    result = set_('Kp', 'stiff')
    assert not result.successful and result.reason
    # Every refusal kept the old values, in the node and in its controller.
    assert get('Kp') == list(kp0) and get('path.heading') == 'fixed'
    assert get('joy.button_guidance') == 3
    assert tuple(node.controller.settings.Kp) == kp0
    assert node.manager.mapping.button_guidance == 3
    assert not node.controller.ramping

    result = set_('Kp', [20.0, 20.0, 3.0])
    assert result.successful, result.reason
    assert tuple(node.controller.settings.Kp) == (20.0, 20.0, 3.0)
    assert node.controller.ramping  # blended in over gain_ramp_time, not stepped
    assert get('Kp') == [20.0, 20.0, 3.0]
    # The ramp ends after gain_ramp_time (1 s) of control steps.
    ref = HoldPose((0.0, 0.0, 0.0)).reference((0.0, 0.0, 0.0), 0.1)
    for _ in range(11):
        node.controller.step((0.1, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), ref, 0.1)
    assert not node.controller.ramping

    result = set_('path.heading', 'course')
    assert result.successful, result.reason
    assert node.settings['path.heading'] == 'course'
    result = set_('joy_timeout', 0.3)
    assert result.successful, result.reason
    assert node.manager.joy_timeout == 0.3
