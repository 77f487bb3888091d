"""Node tests: rov simulator node (with the simulated IMU measuring it)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, MagneticField
from support.nodes import TIMEOUT, add, probe
from support.rov import G, overrides, sim_parameters

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.kinematics import quat_to_euler
from enbarr_core.simulation.rov_simulator_node import RovSimulatorNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.imu.sim import SimImuNode

BIAS = [0.01, -0.02, 0.03]


class Run:
    """The simulator stepped by hand 400 times, the simulated IMU listening; by stamp."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.sim = sim = add(executor, RovSimulatorNode(
            node_name='simulator', context=context,
            parameter_overrides=overrides(sim_parameters('simulator'))))
        self.imu = add(executor, SimImuNode(node_name='imu', context=context,
                                            parameter_overrides=[
                                                Parameter('gyro_bias', value=BIAS),
                                                Parameter('gyro_noise', value=0.002)]))
        p = probe(context, executor, 'listener')
        self.truth: dict[int, Imu] = {}
        self.raw: dict[int, Imu] = {}
        self.mags: dict[int, MagneticField] = {}
        for spec, into in ((topics.SIM_IMU, self.truth), (topics.IMU_RAW, self.raw),
                           (topics.IMU_MAG, self.mags)):
            p.create_topic_subscription(
                spec, lambda m, d=into: d.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
        LinkBus.of(context).connect()
        self.started = sim.rate_loops[0].running
        deadline = time.monotonic() + TIMEOUT
        while sim.samples < 400 and time.monotonic() < deadline:
            sim.step()
            time.sleep(0.001)
        self.stamps = sorted(self.truth)

    def errors(self, field: str) -> np.ndarray:
        return np.array([convert.vector3_to_array(getattr(self.raw[s], field))
                         - convert.vector3_to_array(getattr(self.truth[s], field))
                         for s in self.stamps])


@pytest.fixture
def run(context, executor) -> Run:
    return Run(context, executor)


def test_not_started_until_bringup_starts_it(run):
    assert not run.started  # never started: driven by hand


def test_every_step_is_one_truth_and_one_imu_sample(run):
    assert run.sim.samples >= 400
    assert len(run.truth) == len(run.raw) == len(run.mags) == run.sim.samples
    assert run.stamps == sorted(run.raw) == sorted(run.mags)
    assert np.all(np.diff(run.stamps) > 0)


def test_truth_at_rest_is_level_with_gravity_up(run):
    f = np.array([convert.vector3_to_array(m.linear_acceleration) for m in run.truth.values()])
    assert f == pytest.approx(np.tile([0.0, 0.0, G], (len(f), 1)), abs=1e-2)
    for m in run.truth.values():
        roll, pitch, yaw = quat_to_euler(convert.quaternion_to_array(m.orientation))
        assert abs(roll) < 1e-3 and abs(pitch) < 1e-3 and abs(yaw) < 1e-3


def test_gyro_has_the_bias_and_noise_asked(run):
    gyro_err = run.errors('angular_velocity')
    n = len(run.stamps)
    assert gyro_err.mean(axis=0) == pytest.approx(BIAS, abs=5 * 0.002 / math.sqrt(n))
    assert gyro_err.std(axis=0) == pytest.approx([0.002] * 3, rel=0.25)


def test_accelerometer_has_the_default_noise_and_no_bias(run):
    accel_err = run.errors('linear_acceleration')
    n = len(run.stamps)
    assert accel_err.mean(axis=0) == pytest.approx(np.zeros(3), abs=5 * 0.03 / math.sqrt(n))
    assert accel_err.std(axis=0) == pytest.approx([0.03] * 3, rel=0.25)


def test_raw_imu_carries_no_orientation(run):
    assert run.raw[run.stamps[0]].orientation_covariance[0] == -1.0


def test_magnetometer_measures_the_earth_field(run):
    m = np.array([convert.vector3_to_array(run.mags[s].magnetic_field) for s in run.stamps])
    assert m.mean(axis=0) == pytest.approx([0.0, 1.8e-5, -4.8e-5], abs=2e-7)


def test_initial_position_needs_three_values(context):
    with pytest.raises(ConfigurationError, match=r'initial.position: expected 3 values, got 2'):
        RovSimulatorNode(context=context, parameter_overrides=overrides(
            {**sim_parameters('simulator'), 'initial.position': [0.0, 1.0]}))


def test_vehicle_errors_name_the_parameter(context):
    with pytest.raises(ConfigurationError, match=r'vehicle.d_lin\b'):
        RovSimulatorNode(context=context, parameter_overrides=overrides(
            {**sim_parameters('simulator'), 'vehicle.d_lin': [1.0, 2.0]}))


def test_sim_imu_bias_needs_three_values(context):
    with pytest.raises(ConfigurationError, match=r'gyro_bias: expected 3 values, got 2'):
        SimImuNode(context=context, parameter_overrides=[
            Parameter('gyro_bias', value=[0.0, 0.1])])
