"""Node tests: saucer simulator node."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from support.nodes import add, probe
from support.saucer import SimClock, azimuth_msg, overrides

from enbarr_core.simulation.vessel3dof_simulator_node import Vessel3DofSimulatorNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.mocap.sim import SimMocapNode


def test_vessel3dof_simulator_and_sim_mocap(context, executor):
    sim = add(executor, Vessel3DofSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides({'rate': 100.0})))
    mocap = add(executor, SimMocapNode(
        node_name='mocap', context=context, parameter_overrides=[
            Parameter('rate', value=50.0), Parameter('dropout_windows', value=[0.5, 1.0]),
            Parameter('position_noise', value=0.002), Parameter('heading_noise', value=0.005)]))
    clock = SimClock(sim, mocap)
    p = probe(context, executor, 'arduino')
    cmd_pub = p.create_topic_publisher(topics.SIM_AZIMUTH_COMMAND)
    truth: dict[int, Odometry] = {}
    poses: dict[int, PoseStamped] = {}
    p.create_topic_subscription(
        topics.SIM_ODOMETRY, lambda m: truth.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(
        topics.MOCAP_POSE, lambda m: poses.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    LinkBus.of(context).connect()
    assert not sim.rate_loops[0].running  # never started: stepped by hand

    forward = azimuth_msg([1.0, 1.0, 1.0], [0.0, 0.0, 0.0])
    steps = 150  # 1.5 s
    for k in range(steps):
        if k % 5 == 0:
            cmd_pub.publish(forward)  # well within command_timeout (0.25 s)
        clock.advance(0.01)
        sim.step()
    assert sim.steps == steps and len(truth) == steps
    stamps = sorted(truth)
    assert np.diff(stamps).tolist() == [10_000_000] * (steps - 1)
    assert stamps[-1] == clock.ns

    # Three azimuths pushing ahead at 0 rad: the vessel accelerates east, straight.
    x = np.array([truth[s].pose.pose.position.x for s in stamps])
    u = np.array([truth[s].twist.twist.linear.x for s in stamps])
    assert x[-1] > 0.1 and np.all(np.diff(x[5:]) > 0.0)
    assert u[-1] > 0.1 and np.all(np.diff(u[5:]) > 0.0)
    for s in stamps:
        eta = convert.pose_to_eta(truth[s].pose.pose)
        assert abs(eta[1]) < 1e-9 and abs(eta[2]) < 1e-9
    assert sim.actuators.tau() == pytest.approx([3.0, 0.0, 0.0], abs=1e-3)  # 3 x 1 N

    # Motion capture: every 20 ms from the first sample, none inside [0.5, 1.0) s.
    start = stamps[0]
    slots = [s for s in stamps if (s - start) % 20_000_000 == 0]
    in_window = [s for s in slots if 0.5 <= (s - start) * 1e-9 < 1.0]
    assert len(slots) == 75 and 24 <= len(in_window) <= 26
    assert sorted(poses) == [s for s in slots if s not in in_window]
    assert mocap.published == len(poses) and mocap.dropped == len(in_window)
    assert mocap.published + mocap.dropped == len(slots)
    # Measured with noise around the truth.
    err = np.array([convert.pose_to_eta(poses[s].pose) - convert.pose_to_eta(truth[s].pose.pose)
                    for s in sorted(poses)])
    assert np.all(err[:, :2] != 0.0) and np.all(err[:, 2] != 0.0)
    assert np.abs(err[:, :2]).max() < 5 * 0.002 and np.abs(err[:, 2]).max() < 5 * 0.005
    assert err[:, :2].std() == pytest.approx(0.002, rel=0.3)
    assert err[:, 2].std() == pytest.approx(0.005, rel=0.3)
    assert all(poses[s].header.frame_id == topics.WORLD_FRAME for s in poses)


def test_simulator_needs_the_vessel_from_the_profile(context):
    from support.saucer import COMMON

    from enbarr_core.framework.errors import ConfigurationError
    given = {k: v for k, v in COMMON.items() if k != 'vessel.inertia'}
    with pytest.raises(ConfigurationError,
                       match="parameter 'vessel.inertia' is not set; the profile must give it"):
        Vessel3DofSimulatorNode(node_name='simulator', context=context,
                            parameter_overrides=[Parameter(k, value=v)
                                                 for k, v in given.items()])


def test_simulator_runs_the_profile_vessel(context, executor):
    sim = add(executor, Vessel3DofSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides({'vessel.inertia': [20.0, 21.0, 0.5]})))
    assert sim.settings.vessel.M == (20.0, 21.0, 0.5)
    np.testing.assert_array_equal(np.diag(sim.model.M), [20.0, 21.0, 0.5])


# -- away from rest: sim/odometry against closed forms ---------------------------------------
#
# No commands (the azimuths stay at zero thrust), no current, no bias; the vessel starts at a
# pose and velocity and coasts. Budget: RK4 at dt = 10 ms on motions no faster than 1 rad/s
# and time constants above 0.6 s: global error of order (1 rad/s dt)^4 t ~ 1e-8 over 3 s,
# so 1e-7 [m, m/s, rad].

TOL = 1e-7
M_MANUAL = (9.51, 9.51, 0.116)        # CS Saucer manual eq. 1.2 (profile vessel.inertia)
D_MANUAL = (1.96, 1.96, 0.168)        # manual eq. 1.4 (profile vessel.linear_damping)
DN_MANUAL = 7.095                     # manual eq. 1.5 (profile vessel.nonlinear_damping)


def coast(context, executor, initial, nu0, extra=None, seconds=3.0):
    """(t [s], eta, nu) of every sim/odometry while coasting from ``initial``, ``nu0``."""
    sim = add(executor, Vessel3DofSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides({'rate': 100.0, 'initial': list(initial),
                                       **(extra or {})})))
    sim.nu = np.array(nu0, dtype=float)
    clock = SimClock(sim)
    t0 = clock.ns
    p = probe(context, executor, 'listener')
    out: list[Odometry] = []
    p.create_topic_subscription(topics.SIM_ODOMETRY, out.append)
    LinkBus.of(context).connect()
    for _ in range(round(seconds * 100)):
        clock.advance(0.01)
        sim.step()
    assert len(out) == round(seconds * 100)
    for m in out:
        assert m.header.frame_id == topics.WORLD_FRAME and m.child_frame_id == topics.BODY_FRAME
        yield ((convert.stamp_to_ns(m.header.stamp) - t0) * 1e-9,
               convert.pose_to_eta(m.pose.pose),
               np.array([m.twist.twist.linear.x, m.twist.twist.linear.y,
                         m.twist.twist.angular.z]))


def wrapped(a: float) -> float:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def test_spinning_vessel_coasts_in_a_straight_line(context, executor):
    """The manual's M and D are equal in surge and sway, so with the quadratic term off the
    world-frame velocity obeys M w_dot = -D w whatever the yaw rate (the Coriolis term only
    rotates the body-frame velocity): a straight line, w(t) = R(psi0) [u0, v0] exp(-t d / m).
    Yaw: psi(t) = psi0 + r0 (m33 / d33) (1 - exp(-t d33 / m33)), through +-pi. The published
    twist is the body-frame velocity R(psi(t))^T w(t)."""
    m, d, m3, d3 = M_MANUAL[0], D_MANUAL[0], M_MANUAL[2], D_MANUAL[2]
    x0, y0, psi0 = 1.5, -0.5, 2.9
    u0, v0, r0 = 0.3, -0.15, 0.8
    w0 = np.array([math.cos(psi0) * u0 - math.sin(psi0) * v0,
                   math.sin(psi0) * u0 + math.cos(psi0) * v0])
    crossed = False
    for t, eta, nu in coast(context, executor, (x0, y0, psi0), (u0, v0, r0),
                            {'vessel.nonlinear_damping': [0.0, 0.0, 0.0]}):
        e, tau_r = math.exp(-t * d / m), m3 / d3
        w = w0 * e
        psi = psi0 + r0 * tau_r * (1.0 - math.exp(-t / tau_r))
        np.testing.assert_allclose(eta[:2], [x0, y0] + w0 * (m / d) * (1.0 - e),
                                   rtol=0.0, atol=TOL)
        assert abs(wrapped(eta[2] - psi)) < TOL
        assert -np.pi <= eta[2] <= np.pi
        c, s = math.cos(psi), math.sin(psi)
        np.testing.assert_allclose(nu, [c * w[0] + s * w[1], -s * w[0] + c * w[1],
                                        r0 * math.exp(-t / tau_r)], rtol=0.0, atol=TOL)
        crossed = crossed or psi > np.pi
    assert crossed


@pytest.mark.parametrize('r0', [0.3, -0.25])
def test_pure_turn_follows_the_quadratic_damping_solution(context, executor, r0):
    """The manual's model with D_n: a pure yaw spin m33 r_dot = -d33 r - dn r |r| has
    |r(t)| = a |r0| e / (a + b |r0| (1 - e)), e = exp(-a t), a = d33 / m33, b = dn / m33, and
    the heading turns by ln(1 + b |r0| (1 - e) / a) / b; the position does not move.

    Yaw is stiff (b = 61 1/rad: the quadratic term dominates), so the budget is RK4's own:
    per step (lambda dt)^5 / 120 of r with lambda = a + 2 b |r0| the fastest linearised rate,
    summed over the decay, |r0| (lambda dt)^4 / 120; ten times that for r, and times the
    3 s run for the heading it integrates.
    """
    a, b = D_MANUAL[2] / M_MANUAL[2], DN_MANUAL / M_MANUAL[2]
    sign, spin = math.copysign(1.0, r0), abs(r0)
    tol_r = spin * ((a + 2.0 * b * spin) * 0.01) ** 4 / 12.0
    psi0 = sign * (math.pi - 0.02)        # turning through +-pi
    for t, eta, nu in coast(context, executor, (0.2, 0.3, psi0), (0.0, 0.0, r0)):
        e = math.exp(-a * t)
        r = sign * a * spin * e / (a + b * spin * (1.0 - e))
        turned = sign * math.log(1.0 + b * spin * (1.0 - e) / a) / b
        np.testing.assert_allclose(nu[:2], 0.0, rtol=0.0, atol=TOL)
        assert abs(nu[2] - r) < tol_r, (t, nu[2] - r, tol_r)
        np.testing.assert_allclose(eta[:2], [0.2, 0.3], rtol=0.0, atol=TOL)
        assert abs(wrapped(eta[2] - (psi0 + turned))) < 3.0 * tol_r
    # It turned through +-pi (the published heading wrapped); the linear damping alone would
    # have turned it |r0| m33 / d33 (1 - exp(-3 a)) = 0.69 |r0|, the quadratic term much less.
    assert 0.03 < abs(turned) < 0.3 * spin and abs(eta[2]) < math.pi - 0.01


def test_surge_coast_with_the_manual_damping_moves_along_the_heading(context, executor):
    """Pure surge at heading 2.0 rad with D and D_n of the manual: the quadratic-damping
    solution of the previous test in surge, along (cos psi, sin psi) in the world (ENU)."""
    a, b = D_MANUAL[0] / M_MANUAL[0], DN_MANUAL / M_MANUAL[0]
    psi0, u0 = 2.0, 0.5
    for t, eta, nu in coast(context, executor, (1.0, 2.0, psi0), (u0, 0.0, 0.0)):
        e = math.exp(-a * t)
        u = a * u0 * e / (a + b * u0 * (1.0 - e))
        s = math.log(1.0 + b * u0 * (1.0 - e) / a) / b
        np.testing.assert_allclose(nu, [u, 0.0, 0.0], rtol=0.0, atol=TOL)
        np.testing.assert_allclose(eta, [1.0 + s * math.cos(psi0), 2.0 + s * math.sin(psi0),
                                         psi0], rtol=0.0, atol=TOL)


def test_the_current_is_its_mean_plus_the_sine_of_its_period(context, executor):
    """current_at: mean + sin(2 pi t / period) * amplitude, per axis (east, north)."""
    sim = add(executor, Vessel3DofSimulatorNode(
        node_name='simulator', context=context, parameter_overrides=overrides({
            'current': [0.05, -0.01], 'current_amplitude': [0.02, 0.03],
            'current_period': 8.0})))
    for t in (0.0, 2.0, 3.3, 6.0, 100.1):
        phase = math.sin(2.0 * math.pi * t / 8.0)
        assert sim.current_at(t) == (0.05 + phase * 0.02, -0.01 + phase * 0.03)
    assert sim.current_at(2.0) == pytest.approx((0.07, 0.02))
    assert sim.current_at(6.0) == pytest.approx((0.03, -0.04))
