"""Node tests: attitude filter node."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_msgs.msg import Imu, MagneticField
from support.nodes import add, get_param, param_client, probe, set_param
from support.rov import G

from enbarr_core.estimation.attitude_filter_node import AttitudeFilterNode
from enbarr_core.framework.kinematics import quat_to_euler
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus


def test_attitude_filter_live_tuning(context, executor, spin):
    node = add(executor, AttitudeFilterNode(node_name='filtering', context=context))
    client = param_client(executor, spin, context, 'filtering')
    before = node.filter.settings
    result = set_param(executor, spin, client, 'accel_noise', 0.2)
    assert result.successful, result.reason
    assert node.filter.settings is not before
    assert node.filter.settings.accel_noise == 0.2
    assert node.filter.settings.gyro_noise == before.gyro_noise
    result = set_param(executor, spin, client, 'accel_noise', -1.0)
    assert not result.successful and 'accel_noise' in result.reason
    assert node.filter.settings.accel_noise == 0.2
    assert get_param(executor, spin, client, 'accel_noise') == 0.2


@pytest.mark.parametrize('mag_body, yaw', [
    ([0.0, 1.8e-5, -4.8e-5], 0.0),            # body x east: north (+y world) is body +y
    ([1.8e-5, 0.0, -4.8e-5], math.pi / 2),    # body x north
])
def test_attitude_filter_level_at_rest(context, executor, mag_body, yaw):
    node = add(executor, AttitudeFilterNode(node_name='filtering', context=context))
    p = probe(context, executor, 'imu')
    raw_pub = p.create_topic_publisher(topics.IMU_RAW)
    mag_pub = p.create_topic_publisher(topics.IMU_MAG)
    out: list[Imu] = []
    p.create_topic_subscription(topics.IMU, out.append)
    LinkBus.of(context).connect()

    t = 5_000_000_000

    def sample(t_ns: int, gyro: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        mag = MagneticField()
        convert.ns_to_stamp(t_ns, mag.header.stamp)
        convert.set_vector3(mag.magnetic_field, mag_body)
        mag_pub.publish(mag)
        raw = Imu()
        convert.ns_to_stamp(t_ns, raw.header.stamp)
        raw.header.frame_id = topics.IMU_FRAME
        raw.orientation_covariance[0] = -1.0
        convert.set_vector3(raw.angular_velocity, gyro)
        convert.set_vector3(raw.linear_acceleration, (0.0, 0.0, G))
        raw_pub.publish(raw)

    for _ in range(300):
        t += 2_500_000
        sample(t)
    assert len(out) == 299 and node.samples == 299 and node.rejected == 0
    last = out[-1]
    assert convert.stamp_to_ns(last.header.stamp) == t
    assert last.header.frame_id == topics.IMU_FRAME
    q = convert.quaternion_to_array(last.orientation)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    roll, pitch, yaw_est = quat_to_euler(q)
    assert abs(roll) < 1e-3 and abs(pitch) < 1e-3
    assert abs(math.remainder(yaw_est - yaw, 2 * math.pi)) < 0.02
    cov = np.array(last.orientation_covariance).reshape(3, 3)
    assert np.all(np.diag(cov) > 0.0) and np.all(np.isfinite(cov))
    assert np.array(last.angular_velocity_covariance)[[0, 4, 8]].min() > 0.0
    assert convert.vector3_to_array(last.angular_velocity) == pytest.approx(np.zeros(3),
                                                                            abs=1e-3)

    # A NaN gyro sample is dropped and counted; so is a stamp that does not advance.
    sample(t + 2_500_000, gyro=(math.nan, 0.0, 0.0))
    assert node.rejected == 1 and len(out) == 299
    sample(t)
    assert node.rejected == 2 and len(out) == 299
    sample(t + 2_500_000)  # and the filter goes on
    assert len(out) == 300 and node.rejected == 2
    # A gap longer than max_gap (0.5 s): that sample is dropped and counted, the filter
    # starts over from the next one.
    t += 2_500_000 + 1_000_000_000
    sample(t)
    assert node.rejected == 3 and len(out) == 300 and not node.filter.initialized
    sample(t + 2_500_000)
    assert len(out) == 301 and node.rejected == 3 and node.filter.initialized
