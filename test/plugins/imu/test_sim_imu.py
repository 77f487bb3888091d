"""Node tests: the simulated IMU (``enbarr_plugins/imu/sim.py``) adds bias and seeded noise."""

from __future__ import annotations

import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, MagneticField
from support.nodes import add, probe

from enbarr_core.framework.kinematics import quat_to_rotmat
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.imu.sim import SimImuNode

GYRO_BIAS, ACCEL_BIAS = [0.004, -0.003, 0.002], [0.01, -0.02, 0.03]
FIELD = [0.0, 1.8e-5, -4.8e-5]


def truth(k: int) -> Imu:
    msg = Imu()
    msg.header.stamp = convert.ns_to_stamp(1_000_000_000 + k * 2_500_000)
    half = 0.01 * k
    convert.set_quaternion(msg.orientation, [0.0, 0.0, np.sin(half), np.cos(half)])
    convert.set_vector3(msg.angular_velocity, [0.01 * k, -0.2, 0.3 + 1e-9 * k])
    convert.set_vector3(msg.linear_acceleration, [0.1, 0.2 * k, -9.81])
    return msg


def test_raw_and_mag_are_truth_plus_bias_plus_the_seeded_draws_bit_for_bit(context, executor):
    """Draw order per truth: magnetometer (3), gyro (3), accelerometer (3); sums in the order
    truth + bias + noise. A seed gives the same samples, whatever the arithmetic's form."""
    imu = add(executor, SimImuNode(node_name='imu', context=context, parameter_overrides=[
        Parameter('seed', value=5), Parameter('gyro_bias', value=GYRO_BIAS),
        Parameter('accel_bias', value=ACCEL_BIAS), Parameter('magnetic_field', value=FIELD)]))
    p = probe(context, executor, 'simulator')
    pub = p.create_topic_publisher(topics.SIM_IMU)
    raws: list[Imu] = []
    mags: list[MagneticField] = []
    p.create_topic_subscription(topics.IMU_RAW, raws.append)
    p.create_topic_subscription(topics.IMU_MAG, mags.append)
    LinkBus.of(context).connect()
    truths = [truth(k) for k in range(10)]
    for t in truths:
        pub.publish(t)
    assert len(raws) == len(mags) == len(truths)
    s = imu.settings
    rng = np.random.default_rng(5)
    for t, raw, mag in zip(truths, raws, mags):
        q = convert.quaternion_to_array(t.orientation)
        m = quat_to_rotmat(q).T @ np.array(FIELD) + rng.normal(0.0, s.mag_noise, 3)
        gyro = (convert.vector3_to_array(t.angular_velocity) + np.array(GYRO_BIAS)
                + rng.normal(0.0, s.gyro_noise, 3))
        accel = (convert.vector3_to_array(t.linear_acceleration) + np.array(ACCEL_BIAS)
                 + rng.normal(0.0, s.accel_noise, 3))
        assert convert.vector3_to_array(mag.magnetic_field).tolist() == m.tolist()
        assert convert.vector3_to_array(raw.angular_velocity).tolist() == gyro.tolist()
        assert convert.vector3_to_array(raw.linear_acceleration).tolist() == accel.tolist()
        assert raw.header.stamp == t.header.stamp and raw.header.frame_id == topics.IMU_FRAME
        assert raw.angular_velocity_covariance[4] == s.gyro_noise ** 2
        assert raw.linear_acceleration_covariance[8] == s.accel_noise ** 2
