"""The ROV scenario's plot: which profiles get it, what it records, and that it draws a run."""

from __future__ import annotations

import math
from pathlib import Path

from geometry_msgs.msg import PoseWithCovarianceStamped, WrenchStamped
from nav_msgs.msg import Odometry
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from enbarr_core.bringup.profile import load_profile
from enbarr_core.tools import rov_plot
from enbarr_core.tools.scenario import record_topics
from enbarr_interfaces import convert

pytestmark = pytest.mark.unit


def test_the_rov_profiles_get_the_rov_plot_and_record_what_it_reads():
    rov, saucer = load_profile('enbarr_sim'), load_profile('saucer_sim')
    assert rov_plot.is_rov(rov) and not rov_plot.is_rov(saucer)
    topics = record_topics(rov)
    assert set(rov_plot.ROV_PLOT_TOPICS) <= set(topics) and '/azimuth_commands' not in topics
    assert '/azimuth_commands' in record_topics(saucer)
    assert not set(rov_plot.ROV_PLOT_TOPICS) & set(record_topics(rov, plot=False)) - {
        '/failsafe/action'}   # the failsafes' own metrics record that one anyway


def _stamped(msg, t: float):
    convert.ns_to_stamp(round(t * 1e9), msg.header.stamp)
    return msg


def test_a_dive_and_a_failsafe_are_drawn(tmp_path: Path):
    msgs: dict[str, list] = {'/sim/odometry': [], '/depth': [], '/force_command': [],
                             '/thruster_commands': [], '/pilot_mode': [],
                             '/failsafe/action': []}
    for k in range(200):
        t = 0.1 * k
        o = Odometry()
        o.pose.pose.position.x, o.pose.pose.position.z = 0.05 * t, -min(t, 10.0) * 0.2
        convert.yaw_to_quaternion(math.radians(10.0), o.pose.pose.orientation)
        msgs['/sim/odometry'].append((round(t * 1e9), _stamped(o, t)))
        d = PoseWithCovarianceStamped()
        d.pose.pose.position.z = o.pose.pose.position.z
        msgs['/depth'].append((round(t * 1e9), _stamped(d, t)))
        w = WrenchStamped()
        w.wrench.force.z = -5.0 if t < 10.0 else 2.0
        msgs['/force_command'].append((round(t * 1e9), _stamped(w, t)))
        msgs['/thruster_commands'].append((round(t * 1e9), _stamped(JointState(
            name=['a', 'b'], effort=[0.1, -0.2]), t)))
    msgs['/pilot_mode'] = [(0, String(data='velocity')), (round(4e9), String(data='depth_hold'))]
    msgs['/failsafe/action'] = [(0, String(data='none')), (round(12e9), String(data='surface'))]
    profile = load_profile('enbarr_sim')
    png = rov_plot.plot_rov_run(msgs, profile, tmp_path / 'run.png',
                                {'verdict': 'fail', 'failed': ['x'], 'targets': {}})
    assert png.stat().st_size > 50_000
    import matplotlib.image as mpimg
    image = mpimg.imread(png)
    assert image.shape[0] == 1500 and image.shape[1] == 1500
