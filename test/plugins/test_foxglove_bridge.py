"""Node tests: the Foxglove bridge, through a WebSocket client that speaks the protocol.

The client here is written from the protocol's specification (github foxglove/ws-protocol,
docs/spec.md), not from the SDK that serves it: the opcodes and byte layouts below are typed
from the spec's tables, so a server that framed them otherwise fails these tests.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass
import json
import struct
import time
from typing import Any

from geometry_msgs.msg import Twist, TwistStamped, Vector3
from nav_msgs.msg import Odometry
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import Bool
from support.nodes import add, probe, TIMEOUT
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from enbarr_core.bringup.compose import make_executor
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import parse_frames
from enbarr_core.framework.node import EnbarrNode, install_frame_tree
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.foxglove.bridge import FoxgloveBridgeNode

pytestmark = pytest.mark.node

#: The WebSocket subprotocol the SDK's server requires.
SUBPROTOCOL = 'foxglove.sdk.v1'
#: Server -> client binary "Message Data": opcode 0x01, uint32 subscription id, uint64 receive
#: timestamp [ns], then the payload; all little-endian (spec, "Binary messages").
MESSAGE_DATA = 0x01
MESSAGE_DATA_HEAD = struct.Struct('<BIQ')
#: Client -> server binary "Client Message Data": opcode 0x01, uint32 channel id, payload.
CLIENT_MESSAGE_DATA = 0x01
CLIENT_MESSAGE_HEAD = struct.Struct('<BI')
#: Status levels (spec, "Status"): 0 info, 1 warning, 2 error.
STATUS_ERROR = 2


class FoxgloveClient:
    """A protocol client over ``websockets``' synchronous connection.

    Every wait spins the test's executor between reads, so that the node answers while the
    client waits (bounded by ``TIMEOUT``, never a fixed sleep).
    """

    def __init__(self, ws: ClientConnection, executor: Any) -> None:
        self.executor = executor
        self.ws = ws
        self.texts: list[dict[str, Any]] = []
        self.frames: list[bytes] = []

    def send(self, op: str, **fields: Any) -> None:
        self.ws.send(json.dumps({'op': op, **fields}))

    def send_binary(self, data: bytes) -> None:
        self.ws.send(data)

    def _pump(self) -> None:
        self.executor.spin_once(timeout_sec=0.02)
        while True:
            try:
                got = self.ws.recv(timeout=0.02)
            except TimeoutError:
                return
            if isinstance(got, bytes):
                self.frames.append(got)
            else:
                self.texts.append(json.loads(got))

    def wait(self, condition: Callable[[], Any], what: str) -> Any:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            found = condition()
            if found:
                return found
            self._pump()
        found = condition()
        assert found, f'no {what} within {TIMEOUT} s; got {self.texts}'
        return found

    def text(self, op: str, **match: Any) -> dict[str, Any]:
        """Wait for the first JSON message ``op`` whose fields include ``match``."""
        def find() -> dict[str, Any] | None:
            return next((m for m in self.texts if m.get('op') == op
                         and all(m.get(k) == v for k, v in match.items())), None)
        return self.wait(find, f'{op} {match}')

    def channel(self, topic: str) -> dict[str, Any]:
        """Wait for the advertisement of ``topic``."""
        def find() -> dict[str, Any] | None:
            return next((c for m in self.texts if m.get('op') == 'advertise'
                         for c in m['channels'] if c['topic'] == topic), None)
        return self.wait(find, f'advertisement of {topic}')

    def statuses(self, level: int) -> list[str]:
        return [m['message'] for m in self.texts if m.get('op') == 'status'
                and m.get('level') == level]


@pytest.fixture(params=['single_threaded', 'events'])
def executor(request, context):
    """Both executors: the tests' ``SingleThreadedExecutor`` and bringup's
    ``EventsExecutor`` (which takes no guard condition and passes no message info)."""
    ex = (SingleThreadedExecutor(context=context) if request.param == 'single_threaded'
          else make_executor(context))
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


@pytest.fixture
def bridge(context, executor):
    """Build a started bridge on a free port with ``overrides``; the node and a connected
    client, closed after the test."""
    with ExitStack() as connections:
        def make(**overrides: Any) -> tuple[FoxgloveBridgeNode, FoxgloveClient]:
            params = [Parameter('port', value=0)] + [Parameter(k, value=v)
                                                      for k, v in overrides.items()]
            node = add(executor, FoxgloveBridgeNode(context=context,
                                                    parameter_overrides=params))
            node.start()
            assert node.port, node.failure
            ws = connections.enter_context(connect(
                f'ws://127.0.0.1:{node.port}', subprotocols=[SUBPROTOCOL],
                open_timeout=TIMEOUT))
            return node, FoxgloveClient(ws, executor)
        yield make


# -- a node with validated parameters, as every Enbarr node has -----------------------------
SPECS = [ParamSpec('gain', 1.0, 'A gain', '', 0.0, 10.0),
         ParamSpec('label', 'a', 'A label')]


@dataclass(frozen=True)
class TunedSettings:
    gain: float
    label: str

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> TunedSettings:
        if v['gain'] == 7.0:
            raise ValueError('gain 7 is unlucky')
        return cls(gain=v['gain'], label=v['label'])


class TunedNode(EnbarrNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('tuned', **kwargs)
        self.settings: TunedSettings
        self.bind_settings(SPECS, TunedSettings.from_params, self._apply)

    def _apply(self, settings: TunedSettings) -> None:
        self.settings = settings


# -- topics ---------------------------------------------------------------------------------
def _odometry(x: float) -> Odometry:
    msg = Odometry()
    msg.header.frame_id = 'odom'
    msg.child_frame_id = 'base_link'
    msg.pose.pose.position.x = x
    msg.pose.pose.orientation.w = 1.0
    msg.twist.twist.angular.z = -0.25
    return msg


def test_a_topic_is_advertised_with_its_ros2_schema_and_forwarded_as_cdr(
        context, executor, bridge):
    p = probe(context, executor, 'publisher')
    pub = p.create_publisher(Odometry, topics.OBSERVER_ODOMETRY.name, 10)
    p.create_timer(0.05, lambda: pub.publish(_odometry(3.5)))
    node, client = bridge()
    info = client.text('serverInfo')
    assert 'parameters' in info['capabilities']
    assert 'clientPublish' not in info['capabilities']
    ch = client.channel('/observer/odometry')
    assert (ch['encoding'], ch['schemaName'], ch['schemaEncoding']) == (
        'cdr', 'nav_msgs/msg/Odometry', 'ros2msg')
    # The full definition: the type's own fields, then each nested type after a separator.
    schema = ch['schema']
    assert schema.startswith('std_msgs/Header header\nstring child_frame_id\n')
    assert '\ngeometry_msgs/PoseWithCovariance pose\n' in schema
    assert '\nMSG: geometry_msgs/PoseWithCovariance\n' in schema
    assert '\nMSG: std_msgs/Header\n' in schema
    assert node.subscribed_topics == ()  # nothing is taken from ROS before a client asks
    before = time.time_ns()
    client.send('subscribe', subscriptions=[{'id': 42, 'channelId': ch['id']}])
    frame = client.wait(lambda: next((f for f in client.frames if f[0] == MESSAGE_DATA), None),
                        'message data')
    opcode, sub_id, stamp = MESSAGE_DATA_HEAD.unpack_from(frame)
    assert (opcode, sub_id) == (MESSAGE_DATA, 42)
    assert before <= stamp <= time.time_ns()
    msg = deserialize_message(frame[MESSAGE_DATA_HEAD.size:], Odometry)
    assert msg.pose.pose.position.x == 3.5
    assert msg.twist.twist.angular.z == -0.25
    assert (msg.header.frame_id, msg.child_frame_id) == ('odom', 'base_link')
    assert node.subscribed_topics == ('/observer/odometry',)
    client.send('unsubscribe', subscriptionIds=[42])
    client.wait(lambda: node.subscribed_topics == (), 'the ROS subscription dropped')


def test_a_fast_topic_of_the_process_is_taken_from_the_bus_not_dds(context, executor, bridge):
    p = probe(context, executor, 'observer')
    pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)  # a link publisher
    node, client = bridge()
    ch = client.channel('/observer/odometry')
    client.send('subscribe', subscriptions=[{'id': 3, 'channelId': ch['id']}])
    client.wait(lambda: node.subscribed_topics == ('/observer/odometry',), 'the bus followed')
    frame = client.wait(lambda: pub.publish(_odometry(-2.0)) or next(iter(client.frames),
                                                                      None), 'message data')
    assert MESSAGE_DATA_HEAD.unpack_from(frame)[:2] == (MESSAGE_DATA, 3)
    msg = deserialize_message(frame[MESSAGE_DATA_HEAD.size:], Odometry)
    assert (msg.pose.pose.position.x, msg.child_frame_id) == (-2.0, 'base_link')
    assert pub.external_readers() == 0  # the bridge is no DDS reader: nothing serialized
    client.send('unsubscribe', subscriptionIds=[3])
    client.wait(lambda: node.subscribed_topics == (), 'the topic dropped')
    sent = node.forwarded
    pub.publish(_odometry(-3.0))  # delivered on the bus at once, in this thread
    assert node.forwarded == sent  # nothing encoded for nobody


def test_a_latched_topic_reaches_a_late_client_and_a_gone_topic_is_withdrawn(
        context, executor, bridge):
    p = probe(context, executor, 'controller')
    pub = p.create_publisher(Bool, 'station/latched', topics.LATCHED_QOS)
    pub.publish(Bool(data=True))
    node, client = bridge()
    ch = client.channel('/station/latched')
    client.send('subscribe', subscriptions=[{'id': 1, 'channelId': ch['id']}])
    frame = client.wait(lambda: next(iter(client.frames), None), 'the latched message')
    assert deserialize_message(frame[MESSAGE_DATA_HEAD.size:], Bool).data is True
    client.send('unsubscribe', subscriptionIds=[1])  # the bridge's reader leaves the graph
    client.wait(lambda: node.subscribed_topics == (), 'the ROS subscription dropped')
    p.destroy_publisher(pub)
    client.text('unadvertise', channelIds=[ch['id']])
    assert '/station/latched' not in node.advertised_topics


TREE = {'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'observer/odometry'},
        'laser': {'parent': 'base_link', 'xyz': [0.0, 0.0, 0.15]}}


def _transforms(frame: bytes) -> list[tuple[str, str, float, float]]:
    """(parent, child, x, z) of a TFMessage, decoded by rosbags (not the bridge's packer)."""
    msg = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(frame[MESSAGE_DATA_HEAD.size:],
                                                          'tf2_msgs/msg/TFMessage')
    return [(t.header.frame_id, t.child_frame_id, t.transform.translation.x,
             t.transform.translation.z) for t in msg.transforms]


def test_without_a_tf_publisher_the_frame_tree_is_served_by_the_bridge(
        context, executor, bridge):
    install_frame_tree(context, parse_frames(TREE))
    p = probe(context, executor, 'observer')
    pub = p.create_topic_publisher(topics.OBSERVER_ODOMETRY)
    node, client = bridge()
    static = client.channel('/tf_static')
    tf = client.channel('/tf')
    assert static['schemaName'] == tf['schemaName'] == 'tf2_msgs/msg/TFMessage'
    assert static['schema'].startswith('geometry_msgs/TransformStamped[] transforms\n')
    client.send('subscribe', subscriptions=[{'id': 5, 'channelId': static['id']},
                                            {'id': 6, 'channelId': tf['id']}])

    def on(sub_id: int) -> list[bytes]:
        return [f for f in client.frames if MESSAGE_DATA_HEAD.unpack_from(f)[1] == sub_id]
    frame = client.wait(lambda: next(iter(on(5)), None), 'the static frames')
    assert _transforms(frame) == [('base_link', 'laser', 0.0, 0.15)]
    odometry = _odometry(1.5)
    odometry.header.stamp.sec = 12
    client.wait(lambda: pub.publish(odometry) or on(6), 'a pose on /tf')
    assert _transforms(on(6)[0]) == [('odom', 'base_link', 1.5, 0.0)]


# -- parameters -----------------------------------------------------------------------------
def _values(client: FoxgloveClient, request_id: str) -> dict[str, Any]:
    reply = client.text('parameterValues', id=request_id)
    return {p['name']: p for p in reply['parameters']}


def test_parameters_of_every_node_of_the_process_are_listed_with_their_types(
        context, executor, bridge):
    add(executor, TunedNode(context=context))
    _, client = bridge()
    client.send('getParameters', parameterNames=[], id='all')
    values = _values(client, 'all')
    assert values['/tuned.gain'] == {'name': '/tuned.gain', 'value': 1.0, 'type': 'float64'}
    assert values['/tuned.label']['value'] == 'a'
    assert values['/foxglove_bridge.allow_parameter_writes']['value'] is False
    assert values['/foxglove_bridge.client_publish_topics']['value'] == [
        'surface_command/twist', 'joy']
    client.send('getParameters', parameterNames=['/tuned.gain', '/nobody.x'], id='two')
    assert list(_values(client, 'two')) == ['/tuned.gain']


def test_a_set_goes_through_the_nodes_own_validation(context, executor, bridge):
    tuned = add(executor, TunedNode(context=context))
    _, client = bridge(allow_parameter_writes=True)
    client.send('setParameters', parameters=[{'name': '/tuned.gain', 'value': 2.5}], id='ok')
    assert _values(client, 'ok')['/tuned.gain']['value'] == 2.5
    assert tuned.settings.gain == 2.5
    # A whole number for a double is the double (the wire cannot tell them apart).
    client.send('setParameters', parameters=[{'name': '/tuned.gain', 'value': 3}], id='int')
    assert _values(client, 'int')['/tuned.gain']['value'] == 3.0
    assert tuned.get_parameter('gain').value == 3.0
    # Out of the declared range: refused by rclpy, reason to the client, value kept.
    client.send('setParameters', parameters=[{'name': '/tuned.gain', 'value': 20.0}], id='hi')
    assert _values(client, 'hi')['/tuned.gain']['value'] == 3.0
    assert tuned.settings.gain == 3.0
    # Refused by the node's settings build: its reason reaches the client.
    client.send('setParameters', parameters=[{'name': '/tuned.gain', 'value': 7.0}], id='7')
    assert _values(client, '7')['/tuned.gain']['value'] == 3.0
    client.wait(lambda: any('/tuned.gain' in s and 'gain 7 is unlucky' in s
                            for s in client.statuses(STATUS_ERROR)), 'the refusal reason')
    assert any('/tuned.gain' in s and 'range' in s for s in client.statuses(STATUS_ERROR))
    assert tuned.settings.gain == 3.0
    # The wrong type: refused, value kept.
    client.send('setParameters', parameters=[{'name': '/tuned.label', 'value': 5}], id='t')
    assert _values(client, 't')['/tuned.label']['value'] == 'a'
    # A read-only parameter stays what the profile said.
    client.send('setParameters', parameters=[
        {'name': '/foxglove_bridge.allow_client_publish', 'value': True}], id='ro')
    assert _values(client, 'ro')['/foxglove_bridge.allow_client_publish']['value'] is False


def test_with_writes_off_a_set_is_refused_and_changes_nothing(context, executor, bridge):
    tuned = add(executor, TunedNode(context=context))
    _, client = bridge()
    client.send('setParameters', parameters=[{'name': '/tuned.gain', 'value': 2.5}], id='s')
    assert _values(client, 's')['/tuned.gain']['value'] == 1.0
    client.wait(lambda: any('allow_parameter_writes' in s
                            for s in client.statuses(STATUS_ERROR)), 'the refusal')
    assert tuned.get_parameter('gain').value == 1.0
    assert tuned.settings.gain == 1.0


# -- client publish -------------------------------------------------------------------------
def _twist(u: float) -> TwistStamped:
    msg = TwistStamped()
    msg.header.frame_id = 'base_link'
    msg.twist.linear.x = u
    return msg


def _listen(context: Any, executor: Any) -> tuple[list[Any], list[Any]]:
    p = probe(context, executor, 'command_receiver')
    twists: list[Any] = []
    stops: list[Any] = []
    p.create_subscription(TwistStamped, topics.SURFACE_TWIST.name, twists.append,
                          topics.SURFACE_TWIST.qos)
    p.create_subscription(Bool, topics.SURFACE_STOP.name, stops.append,
                          topics.SURFACE_STOP.qos)
    return twists, stops


def _client_message(channel_id: int, msg: Any) -> bytes:
    return CLIENT_MESSAGE_HEAD.pack(CLIENT_MESSAGE_DATA, channel_id) + serialize_message(msg)


def test_a_client_publishes_to_an_allowed_topic_only(context, executor, bridge):
    twists, stops = _listen(context, executor)
    node, client = bridge(allow_client_publish=True)
    assert 'clientPublish' in client.text('serverInfo')['capabilities']
    client.channel('/surface_command/twist')  # the receiver is in the graph
    client.send('advertise', channels=[
        {'id': 4, 'topic': '/surface_command/stop', 'encoding': 'cdr',
         'schemaName': 'std_msgs/msg/Bool'},
        {'id': 3, 'topic': '/surface_command/twist', 'encoding': 'cdr',
         'schemaName': 'geometry_msgs/msg/TwistStamped'}])
    client.send_binary(_client_message(4, Bool(data=True)))
    client.send_binary(_client_message(3, _twist(0.4)))
    client.wait(lambda: twists, 'the twist in ROS')
    assert twists[0].twist.linear.x == 0.4
    assert twists[0].header.frame_id == 'base_link'
    # Sent before the twist and handled in order: the stop was refused, not merely late.
    assert stops == []
    assert node.refused_messages == 1
    assert any('/surface_command/stop' in s and 'client_publish_topics' in s
               for s in client.statuses(STATUS_ERROR))
    # Bytes that are not a TwistStamped never reach DDS.
    client.send_binary(CLIENT_MESSAGE_HEAD.pack(CLIENT_MESSAGE_DATA, 3) + b'\x00\x01')
    client.send_binary(_client_message(3, _twist(0.1)))
    client.wait(lambda: len(twists) == 2, 'the second twist')
    assert [t.twist.linear.x for t in twists] == [0.4, 0.1]
    assert node.refused_messages == 2


def test_the_teleop_panels_twist_is_stamped_on_arrival(context, executor, bridge):
    # Foxglove's Teleop panel publishes an unstamped geometry_msgs/Twist; the receiver takes a
    # TwistStamped and refuses a stale one, so the bridge stamps it as it arrives
    twists, _ = _listen(context, executor)
    node, client = bridge(allow_client_publish=True)
    client.channel('/surface_command/twist')
    client.send('advertise', channels=[
        {'id': 5, 'topic': '/surface_command/twist', 'encoding': 'cdr',
         'schemaName': 'geometry_msgs/msg/Twist'}])
    before = node.get_clock().now().nanoseconds
    client.send_binary(_client_message(5, Twist(linear=Vector3(x=0.3))))
    client.wait(lambda: twists, 'the stamped twist in ROS')
    after = node.get_clock().now().nanoseconds
    assert twists[0].twist.linear.x == 0.3 and twists[0].header.frame_id == 'base_link'
    stamp = twists[0].header.stamp.sec * 1_000_000_000 + twists[0].header.stamp.nanosec
    assert before <= stamp <= after
    # only onto a TwistStamped topic: a Twist offered for the joystick's topic is refused
    client.send('advertise', channels=[
        {'id': 6, 'topic': '/joy', 'encoding': 'cdr', 'schemaName': 'geometry_msgs/msg/Twist'}])
    client.send_binary(_client_message(6, Twist()))
    client.send('getParameters', parameterNames=['/foxglove_bridge.port'], id='after')
    _values(client, 'after')
    assert len(twists) == 1 and node.refused_messages == 1


def test_with_client_publish_off_nothing_reaches_ros(context, executor, bridge):
    twists, _ = _listen(context, executor)
    node, client = bridge()
    assert 'clientPublish' not in client.text('serverInfo')['capabilities']
    client.channel('/surface_command/twist')
    client.send('advertise', channels=[
        {'id': 3, 'topic': '/surface_command/twist', 'encoding': 'cdr',
         'schemaName': 'geometry_msgs/msg/TwistStamped'}])
    client.send_binary(_client_message(3, _twist(0.4)))
    # A request behind them on the same connection: once answered, they were handled.
    client.send('getParameters', parameterNames=['/foxglove_bridge.port'], id='after')
    _values(client, 'after')
    assert twists == []
    assert node.client_messages == 0
    assert node.count_publishers(topics.SURFACE_TWIST.name) == 0
    # The node refuses too, should a client's advertisement get past the server.
    node._client_advertise((0, 9), '/surface_command/twist', 'cdr',
                           'geometry_msgs/msg/TwistStamped')
    node._client_message((0, 9), serialize_message(_twist(0.4)))
    assert node.refused_messages == 1
    assert node.count_publishers(topics.SURFACE_TWIST.name) == 0


# -- configuration --------------------------------------------------------------------------
def test_it_binds_to_loopback_by_default_and_refuses_an_empty_host(context):
    node = FoxgloveBridgeNode(context=context)
    try:
        assert (node.settings.host, node.settings.port) == ('127.0.0.1', 8765)
        assert node.server is None  # constructing opens nothing
    finally:
        node.destroy_node()
    with pytest.raises(ConfigurationError, match='host'):
        FoxgloveBridgeNode(context=context, parameter_overrides=[Parameter('host', value=' ')])


def test_a_port_in_use_is_a_problem_not_a_crash(context, executor, bridge):
    first, client = bridge()
    second = add(executor, FoxgloveBridgeNode(
        'foxglove_bridge_2', context=context,
        parameter_overrides=[Parameter('port', value=first.port)]))
    second.start()
    assert second.server is None and second.port is None
    assert any(str(first.port) in p for p in second.problems)


def test_a_client_without_the_subprotocol_is_refused(context, executor, bridge):
    node, _ = bridge()
    with pytest.raises((InvalidStatus, ConnectionClosed)):
        with connect(f'ws://127.0.0.1:{node.port}', open_timeout=TIMEOUT) as ws:
            ws.recv(timeout=TIMEOUT)
