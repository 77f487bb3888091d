"""Node tests: saucer simulator node."""

from __future__ import annotations

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
