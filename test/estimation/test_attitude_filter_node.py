"""Node tests: attitude filter node."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, MagneticField
from support.nodes import add, get_param, param_client, probe, set_param
from support.rov import G
from support.saucer import SimClock

from enbarr_core.estimation.attitude_filter_node import AttitudeFilterNode
from enbarr_core.framework.kinematics import quat_to_euler, ssa
from enbarr_core.framework.stamps import StampVerdict
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

DT_NS = 2_500_000  # 400 Hz
NORTH_BODY_Y = [0.0, 1.8e-5, -4.8e-5]  # body x east: north (+y world) is body +y


# -- live tuning -----------------------------------------------------------------------------

@pytest.fixture
def tuned(context, executor, spin):
    node = add(executor, AttitudeFilterNode(node_name='filtering', context=context))
    return node, param_client(executor, spin, context, 'filtering')


def test_a_new_value_swaps_the_settings(executor, spin, tuned):
    node, client = tuned
    before = node.filter.settings
    result = set_param(executor, spin, client, 'accel_noise', 0.2)
    assert result.successful, result.reason
    assert node.filter.settings is not before
    assert node.filter.settings.accel_noise == 0.2
    assert node.filter.settings.gyro_noise == before.gyro_noise


def test_a_refused_value_keeps_the_old_one(executor, spin, tuned):
    node, client = tuned
    assert set_param(executor, spin, client, 'accel_noise', 0.2).successful
    result = set_param(executor, spin, client, 'accel_noise', -1.0)
    assert not result.successful and 'accel_noise' in result.reason
    assert node.filter.settings.accel_noise == 0.2
    assert get_param(executor, spin, client, 'accel_noise') == 0.2


def test_innovation_gate_is_off_by_default_and_can_be_switched_on(executor, spin, tuned):
    """The gate can lock a fresh filter out of gravity (attitude_filter.py): off unless asked."""
    node, client = tuned
    assert get_param(executor, spin, client, 'use_innovation_gate') is False
    assert node.filter.settings.use_innovation_gate is False
    assert set_param(executor, spin, client, 'use_innovation_gate', True).successful
    assert node.filter.settings.use_innovation_gate is True


# -- samples ---------------------------------------------------------------------------------

class Imu400:
    """The filter node fed by hand: level, at rest, magnetometer ``mag_body``."""

    def __init__(self, context: Any, executor: Any, mag_body: list[float],
                 t0_ns: int = 5_000_000_000, **params: Any) -> None:
        self.node = add(executor, AttitudeFilterNode(
            node_name='filtering', context=context,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]))
        p = probe(context, executor, 'imu')
        self._raw_pub = p.create_topic_publisher(topics.IMU_RAW)
        self._mag_pub = p.create_topic_publisher(topics.IMU_MAG)
        self.out: list[Imu] = []
        p.create_topic_subscription(topics.IMU, self.out.append)
        LinkBus.of(context).connect()
        self.mag_body = mag_body
        self.t = t0_ns

    def sample(self, t_ns: int, gyro: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        mag = MagneticField()
        convert.ns_to_stamp(t_ns, mag.header.stamp)
        convert.set_vector3(mag.magnetic_field, self.mag_body)
        self._mag_pub.publish(mag)
        raw = Imu()
        convert.ns_to_stamp(t_ns, raw.header.stamp)
        raw.header.frame_id = topics.IMU_FRAME
        raw.orientation_covariance[0] = -1.0
        convert.set_vector3(raw.angular_velocity, gyro)
        convert.set_vector3(raw.linear_acceleration, (0.0, 0.0, G))
        self._raw_pub.publish(raw)

    def run(self, n: int = 300) -> None:
        for _ in range(n):
            self.t += DT_NS
            self.sample(self.t)


@pytest.fixture
def rig(context, executor) -> Imu400:
    rig = Imu400(context, executor, NORTH_BODY_Y)
    rig.run()
    return rig


def field_at_heading(yaw: float) -> list[float]:
    """The earth field (north = world +y, 1.8e-5 T, dipping 4.8e-5 T) in the body of a level
    vehicle at heading ``yaw`` (ENU, from east, counter-clockwise): R_z(yaw)^T m_world."""
    return [1.8e-5 * math.sin(yaw), 1.8e-5 * math.cos(yaw), -4.8e-5]


@pytest.mark.parametrize('mag_body, yaw', [
    (NORTH_BODY_Y, 0.0),
    ([1.8e-5, 0.0, -4.8e-5], math.pi / 2),    # body x north
    (field_at_heading(math.pi - 1e-3), math.pi - 1e-3),
    (field_at_heading(-math.pi + 1e-3), -math.pi + 1e-3),
    (field_at_heading(-2.0), -2.0),
    (field_at_heading(2.6), 2.6),
])
def test_level_at_rest(context, executor, mag_body, yaw):
    rig = Imu400(context, executor, mag_body)
    rig.run()
    node, out, t = rig.node, rig.out, rig.t
    assert len(out) == 299 and node.samples == 299 and node.rejected == 0
    last = out[-1]
    assert convert.stamp_to_ns(last.header.stamp) == t
    assert last.header.frame_id == topics.IMU_FRAME
    q = convert.quaternion_to_array(last.orientation)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    roll, pitch, yaw_est = quat_to_euler(q)
    assert abs(roll) < 1e-3 and abs(pitch) < 1e-3
    # Noise-free level samples: the alignment is exact and every later innovation is zero;
    # 1e-9 rad covers float64 rounding over 300 steps.
    assert abs(ssa(yaw_est - yaw)) < 1e-9, ssa(yaw_est - yaw)
    cov = np.array(last.orientation_covariance).reshape(3, 3)
    assert np.all(np.diag(cov) > 0.0) and np.all(np.isfinite(cov))
    assert np.array(last.angular_velocity_covariance)[[0, 4, 8]].min() > 0.0
    assert convert.vector3_to_array(last.angular_velocity) == pytest.approx(np.zeros(3),
                                                                            abs=1e-3)


def test_a_nan_sample_is_dropped_and_counted(rig):
    rig.sample(rig.t + DT_NS, gyro=(math.nan, 0.0, 0.0))
    assert rig.node.rejected == 1 and len(rig.out) == 299


def test_a_stamp_that_does_not_advance_is_dropped_and_counted(rig):
    rig.sample(rig.t + DT_NS, gyro=(math.nan, 0.0, 0.0))
    rig.sample(rig.t)
    assert rig.node.rejected == 2 and len(rig.out) == 299
    rig.sample(rig.t + DT_NS)  # and the filter goes on
    assert len(rig.out) == 300 and rig.node.rejected == 2


def test_a_gap_restarts_the_filter(rig):
    # A gap longer than max_gap (0.5 s): that sample is dropped and counted, the filter
    # starts over from the next one.
    t = rig.t + DT_NS + 1_000_000_000
    rig.sample(t)
    assert rig.node.rejected == 1 and len(rig.out) == 299 and not rig.node.filter.initialized
    rig.sample(t + DT_NS)
    assert len(rig.out) == 300 and rig.node.rejected == 1 and rig.node.filter.initialized


# -- the time policy on a controlled clock -------------------------------------------------

T0 = 1_000 * 1_000_000_000  # the node's clock at the start of these tests [ns]


class ClockedImu(Imu400):
    """The filter on a clock the test moves (``SimClock``): a good sample is stamped at the
    clock's present, as the in-process simulated IMU stamps it."""

    def __init__(self, context: Any, executor: Any, **params: Any) -> None:
        super().__init__(context, executor, NORTH_BODY_Y, T0, **params)
        self.clock = SimClock(self.node, t0_ns=T0)
        self.reports: list[tuple[int, str, dict[str, Any]]] = []
        self.node.publish_diagnostics = lambda *a: self.reports.append(a)

    def run(self, n: int = 300) -> None:
        for _ in range(n):
            self.t += DT_NS
            self.clock.set(self.t)
            self.sample(self.t)


@pytest.mark.parametrize('ahead_s', [20.0, 0.4, 0.06])
def test_one_future_sample_costs_only_itself(context, executor, ahead_s):
    """Before the time policy, one imu/data_raw sample stamped 20 s (or 0.4 s) ahead, from
    another process, stopped imu/data for that long. Now it is refused and counted; every good
    sample after it gives an output, and the filter is not re-initialized."""
    rig = ClockedImu(context, executor)
    rig.run()
    n = len(rig.out)
    rig.sample(rig.t + round(ahead_s * 1e9))
    rig.run(100)
    assert len(rig.out) == n + 100
    assert rig.node.filter.initialized
    assert rig.node.raw_gate.counts[StampVerdict.FUTURE] == 1
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in rig.out]
    assert max(stamps) == rig.t  # the future stamp never became the time base
    rig.node._report()
    level, message, values = rig.reports[-1]
    assert values['imu/data_raw.future'] == 1


def test_a_sample_ahead_within_max_future_costs_at_most_max_future(context, executor):
    """Accepted (clock offsets up to max_future are normal across machines): the samples
    that follow are refused as not newer until the clock passes it, max_future at most."""
    rig = ClockedImu(context, executor, max_future=0.05)
    rig.run()
    n = len(rig.out)
    rig.sample(rig.t + 30_000_000)  # 30 ms ahead, within the 50 ms tolerance
    rig.run(100)
    lost = n + 101 - len(rig.out)
    assert 0 < lost <= 30_000_000 // DT_NS, lost
    assert rig.node.raw_gate.counts[StampVerdict.NOT_NEWER] == lost
    assert rig.node.filter.initialized


def test_a_future_magnetometer_sample_is_refused(context, executor):
    rig = ClockedImu(context, executor)
    rig.run()
    mag = MagneticField()
    convert.ns_to_stamp(rig.t + 20_000_000_000, mag.header.stamp)
    convert.set_vector3(mag.magnetic_field, [1e-5, 0.0, 0.0])
    rig._mag_pub.publish(mag)
    assert rig.node.mag_gate.counts[StampVerdict.FUTURE] == 1
    rig.run(10)
    assert rig.node.mag_gate.counts[StampVerdict.ACCEPTED] == 310


# -- diagnostics and rate-aware max_gap (valid but harmful) --------------------------------

def test_a_gap_shorter_than_the_sample_period_is_reported_not_ok(context, executor):
    """max_gap = 0.001 with a 400 Hz IMU once reset the filter at every sample while
    /diagnostics said 'ok'."""
    rig = ClockedImu(context, executor, max_gap=0.001)
    rig.run(400)
    rig.node._report()
    level, message, values = rig.reports[-1]
    assert level != 0, message
    assert 'reset' in message and 'max_gap' in message and '0.0025' in message, message
    assert values['reset.filter'] >= 399


def test_a_max_gap_shorter_than_the_measured_period_is_refused_live(context, executor, spin):
    rig = ClockedImu(context, executor)
    rig.run()
    client = param_client(executor, spin, context, 'filtering')
    result = set_param(executor, spin, client, 'max_gap', 0.001)
    assert not result.successful
    assert 'max_gap' in result.reason and 'period' in result.reason, result.reason
    assert rig.node.settings.max_gap == 0.5
    assert set_param(executor, spin, client, 'max_gap', 0.1).successful


def test_a_max_future_not_under_the_measured_period_is_refused_live(context, executor, spin):
    """At 400 Hz (2.5 ms) a tolerance of 2.5 ms could let one early sample hide the next."""
    rig = ClockedImu(context, executor)
    rig.run()
    client = param_client(executor, spin, context, 'filtering')
    result = set_param(executor, spin, client, 'max_future', 0.0025)
    assert not result.successful
    assert 'max_future' in result.reason and '0.0025' in result.reason, result.reason
    assert set_param(executor, spin, client, 'max_future', 0.0024).successful


def test_refused_samples_above_5_percent_make_the_node_degraded(context, executor):
    rig = ClockedImu(context, executor)
    rig.run(100)
    rig.node._report()
    assert rig.reports[-1][0] == 0, rig.reports[-1]
    for k in range(10):
        rig.sample(rig.t + 20_000_000_000 + k)
    rig.run(100)
    rig.node._report()
    level, message, _ = rig.reports[-1]
    assert level == 1 and 'imu/data_raw' in message and 'future 10' in message, message
    rig.run(100)
    rig.node._report()
    assert rig.reports[-1][0] == 0  # one window later: ok again
