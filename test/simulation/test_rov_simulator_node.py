"""Node tests: rov simulator node."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, MagneticField
from support.nodes import TIMEOUT, add, probe
from support.rov import G, overrides, sim_parameters

from enbarr_core.framework.kinematics import quat_to_euler
from enbarr_core.simulation.rov_simulator_node import RovSimulatorNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.imu.sim import SimImuNode


def test_simulator_truth_and_sim_imu_errors(context, executor):
    bias = [0.01, -0.02, 0.03]
    sim = add(executor, RovSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides(sim_parameters('simulator'))))
    imu = add(executor, SimImuNode(node_name='imu', context=context, parameter_overrides=[
        Parameter('gyro_bias', value=bias), Parameter('gyro_noise', value=0.002)]))
    p = probe(context, executor, 'listener')
    truth: dict[int, Imu] = {}
    raw: dict[int, Imu] = {}
    mags: dict[int, MagneticField] = {}
    p.create_topic_subscription(topics.SIM_IMU,
                               lambda m: truth.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(topics.IMU_RAW,
                               lambda m: raw.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(topics.IMU_MAG,
                               lambda m: mags.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    LinkBus.of(context).connect()
    assert not sim._loops[0].running and imu is not None  # never started: driven by hand

    deadline = time.monotonic() + TIMEOUT
    while sim.samples < 400 and time.monotonic() < deadline:
        sim.step()
        time.sleep(0.001)
    assert sim.samples >= 400
    assert len(truth) == len(raw) == len(mags) == sim.samples
    stamps = sorted(truth)
    assert stamps == sorted(raw) == sorted(mags)
    assert np.all(np.diff(stamps) > 0)

    f = np.array([convert.vector3_to_array(m.linear_acceleration) for m in truth.values()])
    assert f == pytest.approx(np.tile([0.0, 0.0, G], (len(f), 1)), abs=1e-2)
    for m in truth.values():
        roll, pitch, yaw = quat_to_euler(convert.quaternion_to_array(m.orientation))
        assert abs(roll) < 1e-3 and abs(pitch) < 1e-3 and abs(yaw) < 1e-3

    gyro_err = np.array([convert.vector3_to_array(raw[s].angular_velocity)
                         - convert.vector3_to_array(truth[s].angular_velocity) for s in stamps])
    accel_err = np.array([convert.vector3_to_array(raw[s].linear_acceleration)
                          - convert.vector3_to_array(truth[s].linear_acceleration)
                          for s in stamps])
    n = len(stamps)
    assert gyro_err.mean(axis=0) == pytest.approx(bias, abs=5 * 0.002 / math.sqrt(n))
    assert gyro_err.std(axis=0) == pytest.approx([0.002] * 3, rel=0.25)
    assert accel_err.mean(axis=0) == pytest.approx(np.zeros(3), abs=5 * 0.03 / math.sqrt(n))
    assert accel_err.std(axis=0) == pytest.approx([0.03] * 3, rel=0.25)
    assert raw[stamps[0]].orientation_covariance[0] == -1.0
    m = np.array([convert.vector3_to_array(mags[s].magnetic_field) for s in stamps])
    assert m.mean(axis=0) == pytest.approx([0.0, 1.8e-5, -4.8e-5], abs=2e-7)
