"""Pose sources: an estimate's message as the dynamic frame's pose (odom -> base_link).

Numbers worked by hand: the manual's pose eta = [N 2 m, E 1 m, psi 30 deg] (NED) is x 1,
y 2, yaw 60 deg in ENU, whose quaternion is (0, 0, sin 30 deg, cos 30 deg).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frame_sources import pose_sources
from enbarr_core.framework.frames import ned_to_enu, parse_frames, Transform
from enbarr_interfaces import convert

SAUCER = parse_frames({'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'observer/odometry'},
                       'laser': {'parent': 'base_link', 'xyz': [0.0, 0.0, 0.15]}})
ROV = parse_frames({'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'imu/data'},
                    'imu_link': {'parent': 'base_link', 'xyz': [0.1, 0.0, 0.0],
                                 'rpy': [0.0, 0.0, math.pi / 2]}})


def odometry(eta_enu: np.ndarray, stamp_ns: int = 5_000_000_007) -> Odometry:
    msg = Odometry()
    convert.ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id, msg.child_frame_id = 'odom', 'base_link'
    convert.set_pose_eta(msg.pose.pose, eta_enu)
    return msg


def test_the_observer_pose_is_odom_to_base_link() -> None:
    [source] = pose_sources(SAUCER)
    assert source.spec.name == 'observer/odometry' and source.parent == 'odom'
    eta = ned_to_enu([2.0, 1.0, math.radians(30.0)])
    t = source.transform(odometry(eta))
    assert (t.stamp_ns, t.parent, t.child) == (5_000_000_007, 'odom', 'base_link')
    assert t.transform.is_close(Transform((1.0, 2.0, 0.0), (0.0, 0.0, 0.5, math.sqrt(0.75))))


def test_a_non_finite_pose_gives_no_transform() -> None:
    [source] = pose_sources(SAUCER)
    assert source.transform(odometry(np.array([math.nan, 0.0, 0.0]))) is None


def test_the_attitude_filter_gives_orientation_only() -> None:
    """imu/data is the orientation of imu_link (turned +90 deg on base_link here): base_link's
    is that times the inverse of the mount; no position estimate, so no translation."""
    [source] = pose_sources(ROV)
    msg = Imu()
    msg.header.frame_id = 'imu_link'
    yaw_imu = math.radians(100.0)
    msg.orientation.z, msg.orientation.w = math.sin(yaw_imu / 2), math.cos(yaw_imu / 2)
    t = source.transform(msg)
    assert (t.parent, t.child) == ('odom', 'base_link')
    assert t.transform.translation == (0.0, 0.0, 0.0)
    assert math.isclose(t.transform.rpy[2], math.radians(10.0))
    msg.orientation_covariance[0] = -1.0  # REP-145: no orientation
    assert source.transform(msg) is None


def test_a_pose_topic_outside_the_contract_is_refused() -> None:
    tree = parse_frames({'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'mocap/pose'}})
    with pytest.raises(ConfigurationError, match=r"frames\.base_link\.pose: 'mocap/pose' is "
                                                 r'not a pose topic of the contract; one of: '
                                                 r'imu/data, imu/data_raw, observer/odometry, '
                                                 r'sim/imu, sim/odometry') as info:
        pose_sources(tree)
    assert info.value.parameter == 'frames.base_link.pose'
