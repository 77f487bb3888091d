"""Unit tests: the checks every thruster driver makes on ``thruster_commands``
(``thrusters/common.CommandFilter``), without a node."""

from __future__ import annotations

import math

import pytest
from sensor_msgs.msg import JointState

from enbarr_core.framework.stamps import StampVerdict
from enbarr_plugins.thrusters.common import CommandFilter

NAMES = ('port', 'starboard', 'vertical')
NOW = 10_000_000_000  # node clock [ns]


class Log:
    """Records the warnings the filter logs."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def warn(self, message: str, *, throttle_duration_sec: float) -> None:
        self.lines.append(message)


def msg(names, efforts, stamp_ns: int = NOW) -> JointState:
    m = JointState(name=list(names), effort=[float(e) for e in efforts])
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return m


@pytest.fixture
def filt() -> CommandFilter:
    f = CommandFilter(NAMES, Log())
    f.set_max_future(0.002)
    return f


def test_a_command_by_name_with_the_missing_thrusters_at_zero(filt):
    taken = filt.accept(msg(['vertical', 'port'], [-0.25, 0.5]), NOW)
    assert taken.values.tolist() == [0.5, 0.0, -0.25] and taken.stamp_ns == NOW
    assert filt.refused == filt.clipped == 0


@pytest.mark.parametrize('names, efforts', [
    (['port', 'bow'], [0.1, 0.2]),                     # a thruster the profile lacks
    (['port'], [math.nan]),
    (['starboard'], [-math.inf]),
    (['port', 'starboard'], [0.1]),                     # names and values do not pair
])
def test_invalid_commands_are_refused_and_counted(filt, names, efforts):
    assert filt.accept(msg(names, efforts), NOW) is None
    assert filt.refused == 1
    assert filt.health.totals[('thruster_commands', 'invalid')] == 1


def test_values_beyond_one_are_clipped_and_counted(filt):
    assert filt.accept(msg(NAMES, [1.5, -3.0, 1.0]), NOW).values.tolist() == [1.0, -1.0, 1.0]
    assert filt.clipped == 1
    assert filt.accept(msg(NAMES, [0.0, 1.25, 0.0], NOW + 1), NOW).values.tolist() == [
        0.0, 1.0, 0.0]                                # one value, just above 1
    assert filt.clipped == 2
    assert filt.accept(msg(NAMES, [1.0, -1.0, 0.0], NOW + 2), NOW).values.tolist() == [
        1.0, -1.0, 0.0]
    assert filt.clipped == 2                          # the limits themselves are not clipped


def test_the_time_policy_refuses_future_and_old_commands(filt):
    assert filt.accept(msg(NAMES, [0.1] * 3, NOW), NOW) is not None
    assert filt.accept(msg(NAMES, [0.2] * 3, NOW - 1), NOW) is None          # older
    assert filt.accept(msg(NAMES, [0.3] * 3, NOW + 3_000_000), NOW) is None  # 3 ms ahead
    assert filt.refused == 2
    assert filt.gate.counts[StampVerdict.NOT_NEWER] == filt.gate.counts[StampVerdict.FUTURE] == 1
    filt.set_max_future(0.005)
    assert filt.accept(msg(NAMES, [0.3] * 3, NOW + 3_000_000), NOW) is not None


def test_the_refused_name_is_logged():
    log = Log()
    CommandFilter(NAMES, log).accept(msg(['bow'], [0.5]), NOW)
    assert log.lines == ['refused thruster command bow=0.5']
