"""The single-source rule for command topics (``framework/sources.py``), on real DDS matching.

Two publisher nodes in this process are two writers on the topic, exactly as a second
``bringup`` or a ``ros2 topic pub`` would be: the guard counts matched writers.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TwistStamped
from support.nodes import probe

from enbarr_core.framework.health import ERROR, OK
from enbarr_core.framework.sources import SourceGuard
from enbarr_interfaces import topics


def test_a_second_publisher_contests_the_topic_until_it_goes(context: Any, executor: Any,
                                                             spin: Any) -> None:
    receiver = probe(context, executor, 'receiver')
    sub = receiver.create_subscription(TwistStamped, topics.SURFACE_TWIST.name, lambda m: None,
                                       topics.SURFACE_TWIST.qos)
    guard = SourceGuard(receiver, sub)
    assert guard.topic == '/surface_command/twist'
    assert not guard.contested() and guard.status() == (OK, 'ok')

    first = probe(context, executor, 'operator')
    first.create_publisher(TwistStamped, topics.SURFACE_TWIST.name, topics.SURFACE_TWIST.qos)
    assert spin(executor, lambda: sub.get_publisher_count() == 1)
    assert not guard.contested()

    second = probe(context, executor, 'intruder')
    pub2 = second.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                   topics.SURFACE_TWIST.qos)
    assert spin(executor, lambda: sub.get_publisher_count() == 2)
    assert spin(executor, lambda: len(guard.publishers()) == 2)
    assert guard.contested() and guard.contested_count == 1
    level, message = guard.status()
    assert level == ERROR
    assert message.startswith('/surface_command/twist has 2 publishers (/intruder, /operator)')

    second.destroy_publisher(pub2)
    assert spin(executor, lambda: sub.get_publisher_count() == 1)
    assert not guard.contested() and guard.status() == (OK, 'ok')


class _OneWriter:
    """A subscription whose DDS reader matches one writer (the count lags a new one)."""

    topic_name = '/joy'

    def get_publisher_count(self) -> int:
        return 1


def test_a_sequence_number_that_does_not_go_up_is_a_second_writer(monkeypatch: Any) -> None:
    """The first message of a new writer can beat the matched count: its own numbering
    (starting at 1) gives it away while the first source is active."""
    clock = [100.0]
    monkeypatch.setattr('enbarr_core.framework.sources.time.monotonic', lambda: clock[0])
    guard = SourceGuard(None, _OneWriter())
    taken = []
    for seq in (1, 2, 3, 1, 4, 2, 5):
        clock[0] += 0.05
        taken.append(not guard.contested({'publication_sequence_number': seq}))
    assert taken == [True, True, True, False, True, False, True]
    assert guard.contested_count == 2
    clock[0] += 0.49                                     # within QUIET_S of the last: refused
    assert guard.contested({'publication_sequence_number': 1})
    clock[0] += 0.51                                     # a restarted source after silence
    assert not guard.contested({'publication_sequence_number': 1})
    assert not guard.contested({'publication_sequence_number': 2})
    assert not guard.contested(None)                     # no MessageInfo: the count alone


def test_the_command_topics_stay_on_dds_where_writers_can_be_counted() -> None:
    """The rule counts matched DDS writers: a command topic moved to the in-process link bus
    (``fast``) would leave it nothing to count."""
    for spec in (topics.SURFACE_TWIST, topics.SURFACE_IO, topics.JOY):
        assert not spec.fast, spec.name


def test_a_link_subscription_is_refused_with_the_reason(context: Any, executor: Any) -> None:
    import pytest
    node = probe(context, executor, 'receiver')
    link = node.create_topic_subscription(topics.IMU_RAW, lambda m: None)  # a fast topic
    with pytest.raises(TypeError, match='needs a DDS subscription'):
        SourceGuard(node, link)
