"""``guidance/avoidance``: the labelled Float64MultiArray of enbarr_interfaces.avoidance."""

from __future__ import annotations

import math

import pytest
from std_msgs.msg import Float64MultiArray

from enbarr_interfaces import avoidance

VALUES = {'solve_time': 8e-5, 'active': 2, 'infeasible': 0.0, 'min_barrier': math.inf,
          'engaged': 1.0, 'blind': 0.0, 'obstacles': 3}


def test_round_trip_keeps_the_stamps_exact_and_labels_every_value():
    estimate_ns, obstacles_ns = 1_764_000_000_123_456_789, 1_764_000_000_023_456_001
    msg = avoidance.to_msg(VALUES, estimate_ns, obstacles_ns)
    assert msg.layout.dim[0].label.split(',') == [
        'estimate_stamp_sec', 'estimate_stamp_nanosec', 'obstacles_stamp_sec',
        'obstacles_stamp_nanosec', 'solve_time', 'active', 'infeasible', 'min_barrier',
        'engaged', 'blind', 'obstacles']
    assert msg.layout.dim[0].size == msg.layout.dim[0].stride == 11
    got = avoidance.from_msg(msg)
    assert got['estimate_stamp_ns'] == estimate_ns and got['obstacles_stamp_ns'] == obstacles_ns
    assert {k: got[k] for k in VALUES} == pytest.approx(VALUES)
    assert avoidance.from_msg(avoidance.to_msg(VALUES, estimate_ns, None))[
        'obstacles_stamp_ns'] == 0


def test_a_message_without_the_layout_is_refused():
    with pytest.raises(ValueError, match='one dimension'):
        avoidance.from_msg(Float64MultiArray(data=[1.0, 2.0]))
    msg = avoidance.to_msg(VALUES, 1, 2)
    msg.data = list(msg.data)[:-1]
    with pytest.raises(ValueError, match='labels for'):
        avoidance.from_msg(msg)
