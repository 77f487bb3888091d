"""The in-process link bus (``enbarr_interfaces.links``): direct calls inside a context, DDS
only for readers outside it, fallback to DDS for subscriptions without a local publisher,
isolation of faulty callbacks, and remapping.

"Another process" is played by a second rclpy ``Context`` in this process: it has its own
DDS participant and its own ``LinkBus``, so it meets the first context only through DDS.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from sensor_msgs.msg import Imu

from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.nodes import add
from support.participant import Participant

TIMEOUT = 10.0  # [s]


@pytest.fixture
def other() -> Iterator[Participant]:
    """A second context with its own executor: what another process would be."""
    o = Participant('elsewhere')
    try:
        yield o
    finally:
        o.close()


def imu(seq: int) -> Imu:
    msg = Imu()
    convert.ns_to_stamp(1_000_000_000 + seq, msg.header.stamp)
    msg.header.frame_id = topics.IMU_FRAME
    msg.orientation.w = 1.0
    return msg


class PublishSpy:
    """Counts what a link publisher hands to DDS."""

    def __init__(self, ros_publisher: Any) -> None:
        self.count = 0
        self._publish = ros_publisher.publish

    def __call__(self, msg: Any) -> None:
        self.count += 1
        self._publish(msg)


def test_local_delivery_is_the_same_object_and_skips_dds(context, executor, monkeypatch):
    a = add(executor, EnbarrNode('producer', context=context))
    b = add(executor, EnbarrNode('consumer', context=context))
    pub = a.create_topic_publisher(topics.IMU)
    got: list[Imu] = []
    sub = b.create_topic_subscription(topics.IMU, got.append)
    LinkBus.of(context).connect()
    assert sub.local and sub.ros_subscription is None
    assert pub.name == sub.name == '/imu/data'
    # Its DDS reader is the shadow the graph shows (test_link_graph): no reader outside.
    assert pub.ros_publisher.get_subscription_count() == 1
    assert pub.external_readers() == 0
    spy = PublishSpy(pub.ros_publisher)
    monkeypatch.setattr(pub.ros_publisher, 'publish', spy)

    msg = imu(1)
    pub.publish(msg)
    assert len(got) == 1 and got[0] is msg  # the object itself, no copy, no spin
    assert spy.count == 0                   # nobody outside: nothing went to DDS
    assert LinkBus.of(context).local_topics() == {'/imu/data': topics.IMU}

    # A destroyed subscription is no longer called.
    sub.destroy()
    pub.publish(imu(2))
    assert len(got) == 1


def test_publishes_to_dds_while_another_context_subscribes(context, executor, other,
                                                           monkeypatch):
    a = add(executor, EnbarrNode('producer', context=context))
    local: list[Imu] = []
    add(executor, EnbarrNode('consumer', context=context)).create_topic_subscription(
        topics.IMU, local.append)
    pub = a.create_topic_publisher(topics.IMU)
    LinkBus.of(context).connect()
    assert LinkBus.of(other.context) is not LinkBus.of(context)
    assert pub.external_readers() == 0
    spy = PublishSpy(pub.ros_publisher)
    monkeypatch.setattr(pub.ros_publisher, 'publish', spy)
    pub.publish(imu(0))
    assert spy.count == 0 and len(local) == 1

    remote: list[Imu] = []
    remote_sub = other.node.create_subscription(Imu, topics.IMU.name, remote.append,
                                                topics.IMU.qos)
    # Discovery across participants: wait for it, never a fixed sleep.
    seq = [0]

    def publish_and_check() -> bool:
        seq[0] += 1
        pub.publish(imu(seq[0]))
        # Both sides spin, as in a running graph: the publisher's node may learn of its DDS
        # readers through an event its executor dispatches.
        executor.spin_once(timeout_sec=0.01)
        other.executor.spin_once(timeout_sec=0.01)
        return bool(remote)

    assert spin_other(publish_and_check), 'the other context never received'
    assert pub.external_readers() >= 1
    assert spy.count >= 1
    assert remote[0].header.frame_id == topics.IMU_FRAME
    assert remote[0] is not local[-1]  # through DDS: a deserialized copy
    # Local delivery went on for every message, whatever DDS did.
    assert len(local) == seq[0] + 1

    # The outside reader leaves: the publisher stops serializing for DDS.
    other.node.destroy_subscription(remote_sub)

    def publish_goes_local_only() -> bool:
        before = spy.count
        pub.publish(imu(0))
        executor.spin_once(timeout_sec=0.01)
        return spy.count == before

    assert spin_other(publish_goes_local_only), 'still publishing to DDS with no reader'
    assert pub.external_readers() == 0
    before = spy.count
    for _ in range(5):
        pub.publish(imu(0))
        executor.spin_once(timeout_sec=0.01)
    assert spy.count == before


def test_has_readers_says_whether_anyone_would_receive(context, executor, other):
    """A status built only for readers: none, a subscriber in the process, one elsewhere."""
    a = add(executor, EnbarrNode('producer', context=context))
    pub = a.create_topic_publisher(topics.IMU)
    LinkBus.of(context).connect()
    assert not pub.has_readers()
    local = add(executor, EnbarrNode('consumer', context=context)).create_topic_subscription(
        topics.IMU, lambda _msg: None)
    assert pub.has_readers()
    local.destroy()
    assert not pub.has_readers()

    remote_sub = other.node.create_subscription(Imu, topics.IMU.name, lambda _msg: None,
                                                topics.IMU.qos)

    def sees_the_remote_reader() -> bool:
        executor.spin_once(timeout_sec=0.01)
        other.executor.spin_once(timeout_sec=0.01)
        return pub.has_readers()

    assert spin_other(sees_the_remote_reader), 'a reader in another context never counted'
    other.node.destroy_subscription(remote_sub)

    def forgets_it() -> bool:
        executor.spin_once(timeout_sec=0.01)
        return not pub.has_readers()

    assert spin_other(forgets_it), 'still counted a reader that left'


def spin_other(step: Any, timeout: float = TIMEOUT) -> bool:
    import time
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if step():
            return True
    return False


def test_subscription_without_local_publisher_falls_back_to_dds(context, executor, spin,
                                                                other):
    node = add(executor, EnbarrNode('consumer', context=context))
    got: list[Imu] = []
    sub = node.create_topic_subscription(topics.IMU, got.append)
    assert sub.ros_subscription is None  # undecided until the process is wired
    LinkBus.of(context).connect()
    assert not sub.local and sub.ros_subscription is not None
    assert sub.ros_subscription.topic_name == '/imu/data'

    pub = other.node.create_publisher(Imu, topics.IMU.name, topics.IMU.qos)
    assert spin(executor, lambda: pub.get_subscription_count() > 0, TIMEOUT)
    seq = [0]

    def publish_and_check() -> bool:
        seq[0] += 1
        pub.publish(imu(seq[0]))
        executor.spin_once(timeout_sec=0.02)
        return bool(got)

    assert spin_other(publish_and_check), 'the fallback subscription never received'
    assert got[0].header.frame_id == topics.IMU_FRAME

    # A subscription created after connect() decides at once.
    late: list[Imu] = []
    late_sub = node.create_topic_subscription(topics.IMU, late.append)
    assert not late_sub.local

    # A local publisher appearing later takes both subscriptions over: direct calls again.
    producer = add(executor, EnbarrNode('producer', context=context))
    link_pub = producer.create_topic_publisher(topics.IMU)
    assert sub.local and late_sub.local
    msg = imu(10_000)
    link_pub.publish(msg)
    assert got[-1] is msg and late[-1] is msg


def test_failing_callback_is_counted_and_isolated(context, executor):
    a = add(executor, EnbarrNode('producer', context=context))
    b = add(executor, EnbarrNode('consumer', context=context))
    pub = a.create_topic_publisher(topics.FORCE_COMMAND)
    first: list[Any] = []
    last: list[Any] = []

    def broken(msg: Any) -> None:
        raise RuntimeError('boom')

    b.create_topic_subscription(topics.FORCE_COMMAND, first.append)
    bad = b.create_topic_subscription(topics.FORCE_COMMAND, broken)
    b.create_topic_subscription(topics.FORCE_COMMAND, last.append)
    LinkBus.of(context).connect()
    msg = topics.FORCE_COMMAND.msg_type()
    pub.publish(msg)            # must not raise into the publisher
    pub.publish(msg)
    assert bad.errors == 2
    assert first == [msg, msg] and last == [msg, msg]


def test_remapping_applies_to_link_topics(context, executor):
    remapped = add(executor, EnbarrNode(
        'filtering', context=context, cli_args=['--ros-args', '-r', 'imu/data:=imu2/data']))
    pub = remapped.create_topic_publisher(topics.IMU)
    assert pub.name == '/imu2/data'
    assert pub.ros_publisher.topic_name == '/imu2/data'

    plain = add(executor, EnbarrNode('control_loop', context=context))
    on_imu: list[Imu] = []
    plain.create_topic_subscription(topics.IMU, on_imu.append)
    also_remapped = add(executor, EnbarrNode(
        'recorder', context=context, cli_args=['--ros-args', '-r', 'imu/data:=imu2/data']))
    on_imu2: list[Imu] = []
    also_remapped.create_topic_subscription(topics.IMU, on_imu2.append)
    LinkBus.of(context).connect()

    msg = imu(1)
    pub.publish(msg)
    assert on_imu2 == [msg] and on_imu2[0] is msg
    assert on_imu == []
    assert set(LinkBus.of(context).local_topics()) == {'/imu2/data'}
