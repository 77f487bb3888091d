"""Link subscriptions in the ROS graph (``enbarr_interfaces.links``, shadow readers).

What ``ros2 topic info -v`` and rqt_graph see is played by a second rclpy ``Context`` (its own
DDS participant) asking the graph API they use: ``get_subscriptions_info_by_topic``,
``get_subscriber_names_and_types_by_node`` and ``count_subscribers``. Every test that spins
runs under both executors bringup may use: the ``SingleThreadedExecutor`` and the
``EventsExecutor`` of ``compose.make_executor``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import time
from types import SimpleNamespace
from typing import Any

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from sensor_msgs.msg import Imu

from enbarr_core.bringup.compose import make_executor
from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import convert, links, topics
from enbarr_interfaces.links import LinkBus, LinkPublisher, READER_CHECK_PERIOD
from support.participant import Participant

TIMEOUT = 15.0  # [s] discovery between participants on a loaded machine
IMU_TYPE = 'sensor_msgs/msg/Imu'
EXECUTORS: dict[str, Callable[[Any], Any]] = {
    'single_threaded': lambda context: SingleThreadedExecutor(context=context),
    'events': make_executor,
}


class Spinner:
    """The executor of the process under test, with the nodes it spins."""

    def __init__(self, context: Any, kind: str) -> None:
        self.context = context
        self.executor = EXECUTORS[kind](context)
        self.nodes: list[Node] = []

    def add(self, node: Node) -> Any:
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def node(self, name: str) -> EnbarrNode:
        return self.add(EnbarrNode(name, context=self.context))

    def spin(self, seconds: float = 0.01) -> None:
        self.executor.spin_once(timeout_sec=seconds)

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()


@pytest.fixture(params=sorted(EXECUTORS))
def spinner(request: pytest.FixtureRequest, context: Any) -> Iterator[Spinner]:
    s = Spinner(context, request.param)
    try:
        yield s
    finally:
        s.close()


class Graph(Participant):
    """What ``ros2 topic info`` sees: another participant asking the graph API."""

    def __init__(self) -> None:
        super().__init__('ros2cli')

    def subscribers(self, topic: str) -> list[str]:
        """Return the names of the nodes subscribing to ``topic``, sorted."""
        return sorted(i.node_name for i in self.node.get_subscriptions_info_by_topic(topic))

    def topics_of(self, node: str) -> dict[str, list[str]]:
        """Return ``{topic: types}`` that ``node`` subscribes to (``{}`` when it is unknown)."""
        try:
            found = self.node.get_subscriber_names_and_types_by_node(node, '/')
        except rclpy.exceptions.NodeNameNonExistentError:
            return {}
        return dict(found)


@pytest.fixture
def graph() -> Iterator[Graph]:
    g = Graph()
    try:
        yield g
    finally:
        g.close()


def until(condition: Callable[[], bool], step: Callable[[], None] = lambda: time.sleep(0.02),
          timeout: float = TIMEOUT) -> bool:
    """Call ``step`` until ``condition()`` holds or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        step()
    return condition()


class PublishSpy:
    """Counts what a link publisher hands to DDS."""

    def __init__(self, pub: LinkPublisher, monkeypatch: pytest.MonkeyPatch) -> None:
        self.count = 0
        self._publish = pub.ros_publisher.publish
        monkeypatch.setattr(pub.ros_publisher, 'publish', self)

    def __call__(self, msg: Any) -> None:
        self.count += 1
        self._publish(msg)


def imu(seq: int) -> Imu:
    msg = Imu()
    convert.ns_to_stamp(1_000_000_000 + seq, msg.header.stamp)
    msg.header.frame_id = topics.IMU_FRAME
    return msg


def publish_for(pub: LinkPublisher, spinner: Spinner, seconds: float) -> list[Imu]:
    """Publish at about 100 Hz for ``seconds`` while spinning; return what was published."""
    sent = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        msg = imu(len(sent))
        pub.publish(msg)
        sent.append(msg)
        spinner.spin(0.01)
    return sent


def linked_only(spinner: Spinner, monkeypatch: pytest.MonkeyPatch
                ) -> tuple[LinkPublisher, list[Imu], PublishSpy, list[Imu]]:
    """``imu/data`` from attitude_filter to velocity_control in one process, published for two
    reader checks: nothing went to DDS. The publisher, what the subscription got, the spy on
    what goes to DDS and what was sent."""
    producer = spinner.node('attitude_filter')
    linked: list[Imu] = []
    spinner.node('velocity_control').create_topic_subscription(topics.IMU, linked.append)
    pub = producer.create_topic_publisher(topics.IMU)
    LinkBus.of(spinner.context).connect()
    spy = PublishSpy(pub, monkeypatch)
    sent = publish_for(pub, spinner, 2 * READER_CHECK_PERIOD)
    assert spy.count == 0
    return pub, linked, spy, sent


@pytest.mark.parametrize('order', ['publisher_first', 'subscriptions_first'])
def test_link_subscriptions_show_in_the_graph_and_cost_no_dds(spinner, graph, monkeypatch,
                                                            order):
    producer = spinner.node('attitude_filter')
    control, logger = spinner.node('velocity_control'), spinner.node('logger')
    got: dict[str, list[Imu]] = {'velocity_control': [], 'logger': []}

    def subscribe() -> list[Any]:
        return [n.create_topic_subscription(topics.IMU, got[n.get_name()].append)
                for n in (control, logger)]

    if order == 'publisher_first':
        pub = producer.create_topic_publisher(topics.IMU)
        subs = subscribe()
    else:
        subs = subscribe()
        pub = producer.create_topic_publisher(topics.IMU)
    LinkBus.of(spinner.context).connect()
    assert all(s.local for s in subs)

    # ros2 topic info -v /imu/data: both subscribing nodes, with the topic's QoS.
    assert until(lambda: graph.subscribers('/imu/data') == ['logger', 'velocity_control']), \
        graph.subscribers('/imu/data')
    infos = graph.node.get_subscriptions_info_by_topic('/imu/data')
    assert {i.topic_type for i in infos} == {IMU_TYPE}
    assert {i.qos_profile.reliability for i in infos} == {ReliabilityPolicy.BEST_EFFORT}
    assert graph.node.count_subscribers('/imu/data') == 2
    # The publisher's node name arrives with its participant's discovery data, which may
    # come after the endpoint itself (_NODE_NAME_UNKNOWN_ until then, seen under load).
    assert until(lambda: [i.node_name for i in graph.node.get_publishers_info_by_topic(
        '/imu/data')] == ['attitude_filter']), graph.node.get_publishers_info_by_topic('/imu/data')
    # rqt_graph asks per node.
    assert until(lambda: graph.topics_of('velocity_control').get('/imu/data') == [IMU_TYPE])

    # The writer has matched the two shadows, yet nobody outside the fast path listens.
    assert pub.ros_publisher.get_subscription_count() == 2
    assert pub.external_readers() == 0
    spy = PublishSpy(pub, monkeypatch)
    sent = publish_for(pub, spinner, 4 * READER_CHECK_PERIOD)
    assert spy.count == 0
    # Each message once, the object itself (a shadow never feeds a callback).
    assert all(got[n] == sent and all(a is b for a, b in zip(got[n], sent)) for n in got)

    # A destroyed subscription leaves the graph; the other stays.
    subs[1].destroy()
    assert until(lambda: graph.subscribers('/imu/data') == ['velocity_control'])
    assert pub.ros_publisher.get_subscription_count() == 1 and pub.external_readers() == 0


def test_a_plain_ros_reader_in_the_same_process_counts_as_outside(spinner, monkeypatch):
    pub, linked, spy, sent = linked_only(spinner, monkeypatch)

    # A raw DDS reader in this very participant: not a shadow, so it is a reader outside.
    plain: list[Imu] = []
    raw_sub = spinner.node('third_party').create_subscription(
        Imu, topics.IMU.name, plain.append, topics.IMU.qos)
    assert pub.external_readers() == 1

    def step() -> None:
        sent.append(imu(len(sent)))
        pub.publish(sent[-1])
        spinner.spin(0.01)

    assert until(lambda: bool(plain), step), 'the plain subscription never received'
    assert spy.count >= 1
    assert plain[0] is not sent[-1]  # through DDS
    assert linked == sent and all(a is b for a, b in zip(linked, sent))

    spinner.nodes[-1].destroy_subscription(raw_sub)
    # Unmatching is asynchronous (and the EventsExecutor holds a subscription until it spins).
    assert until(lambda: pub.external_readers() == 0, spinner.spin)
    publish_for(pub, spinner, 1.5 * READER_CHECK_PERIOD)  # the last decision holds till then
    before = spy.count
    publish_for(pub, spinner, 2 * READER_CHECK_PERIOD)
    assert spy.count == before


def test_outside_subscriber_gets_messages_and_nothing_is_delivered_twice(spinner, graph,
                                                                        monkeypatch):
    pub, linked, spy, sent = linked_only(spinner, monkeypatch)

    # ros2 topic echo /imu/data from another process.
    echoed: list[Imu] = []
    graph.node.create_subscription(Imu, topics.IMU.name, echoed.append, topics.IMU.qos)
    first_outside = len(sent)

    def step() -> None:
        sent.append(imu(len(sent)))
        pub.publish(sent[-1])
        spinner.spin(0.01)
        graph.executor.spin_once(timeout_sec=0.01)

    assert until(lambda: len(echoed) >= 5, step), 'the outside subscriber never received'
    assert pub.external_readers() == 1
    # It saw only what was published once it existed: nothing went to DDS before.
    seqs = [convert.stamp_to_ns(m.header.stamp) - 1_000_000_000 for m in echoed]
    assert min(seqs) >= first_outside and seqs == sorted(seqs)
    # While DDS carried every message, the shadows received them too: still each message
    # exactly once in process, the published object itself, under either executor.
    for _ in range(20):
        spinner.spin(0.01)
    assert len(linked) == len(sent) and all(a is b for a, b in zip(linked, sent))


def test_fallback_subscription_is_the_only_reader_of_its_node(spinner, graph):
    consumer = spinner.node('velocity_control')
    got: list[Imu] = []
    sub = consumer.create_topic_subscription(topics.IMU, got.append)
    assert sub.shadow_reader is not None  # undecided until connect(): the node subscribes
    LinkBus.of(spinner.context).connect()
    assert not sub.local and sub.shadow_reader is None
    assert until(lambda: graph.subscribers('/imu/data') == ['velocity_control'])

    # A publisher in another process feeds it through DDS.
    outside = graph.node.create_publisher(Imu, topics.IMU.name, topics.IMU.qos)

    def step() -> None:
        outside.publish(imu(1))
        spinner.spin(0.02)

    assert until(lambda: bool(got), step), 'the fallback subscription never received'
    assert until(lambda: graph.node.count_subscribers('/imu/data') == 1)

    # A local publisher appears: the shadow replaces the ROS subscription, still one reader.
    pub = spinner.node('attitude_filter').create_topic_publisher(topics.IMU)
    assert sub.local and sub.shadow_reader is not None
    # The ROS subscription goes once the executor lets go of it and DDS unmatches it.
    assert until(lambda: pub.ros_publisher.get_subscription_count() == 1, spinner.spin)
    assert pub.external_readers() == 0
    time.sleep(0.5)  # give a second reader time to show up, were there one
    assert graph.subscribers('/imu/data') == ['velocity_control']
    msg = imu(2)
    pub.publish(msg)
    assert got[-1] is msg

    # destroy_node drops the links: the node leaves the topic.
    spinner.nodes.remove(consumer)
    spinner.executor.remove_node(consumer)
    consumer.destroy_node()
    assert until(lambda: graph.subscribers('/imu/data') == [])
    assert pub.ros_publisher.get_subscription_count() == 0


class FakeReader:
    """A shadow reader whose matches the test sets; ``destroyed`` as after destroy."""

    def __init__(self, publishers: int) -> None:
        self.publishers = publishers
        self.destroyed = False

    def __enter__(self) -> FakeReader:
        if self.destroyed:
            raise InvalidHandle('cannot use Destroyable because destruction was requested')
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def get_publisher_count(self) -> int:
        return self.publishers


class FakeWriter:
    def __init__(self) -> None:
        self.matched = 0
        self.published = 0

    def get_subscription_count(self) -> int:
        return self.matched

    def publish(self, msg: Any) -> None:
        self.published += 1


def test_readers_outside_follow_asynchronous_matching(context, monkeypatch):
    """Where the middleware matches endpoints asynchronously, the two sides of a shadow
    match may disagree for a while: the count follows the middleware at every check, so a
    late match costs DDS traffic only until both sides agree and never hides a real reader.
    """
    node = Node('attitude_filter', context=context)
    try:
        pub = LinkBus.of(context).create_publisher(node, topics.IMU)
        writer, shadow = FakeWriter(), FakeReader(publishers=0)
        monkeypatch.setattr(pub, 'ros_publisher', writer)
        pub._shadows = (shadow,)
        clock = [100.0]
        monkeypatch.setattr(links, 'time', SimpleNamespace(monotonic=lambda: clock[0]))

        def publish(seconds: float) -> int:
            clock[0] += seconds
            before = writer.published
            pub.publish(imu(0))
            return writer.published - before

        assert publish(0.0) == 0                    # nothing matched
        writer.matched = 1                          # the writer saw the shadow first
        assert publish(1.01 * READER_CHECK_PERIOD) == 1    # taken for a reader outside, for now
        shadow.publishers = 1                       # the shadow caught up
        assert publish(0.001) == 1                  # the last decision holds until the check
        assert publish(1.01 * READER_CHECK_PERIOD) == 0    # then: nobody outside, not forever
        writer.matched = 2                          # a real reader outside appears
        assert publish(1.01 * READER_CHECK_PERIOD) == 1
        shadow.destroyed, writer.matched = True, 1  # the shadow's subscription is destroyed
        assert pub.external_readers() == 1          # the real one is still there
    finally:
        node.destroy_node()
