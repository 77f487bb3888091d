"""A Foxglove WebSocket server in the vessel process: live topics, parameters, teleop.

Foxglove (the app, or Studio) opens ``ws://<host>:<port>`` (``foxglove.sdk.v1`` WebSocket
subprotocol, served by the maintained ``foxglove-sdk``) and sees:

- Topics: every topic of the ROS graph, found every second with
  ``get_topic_names_and_types`` and advertised with its ROS 2 schema (message encoding
  ``cdr``, schema encoding ``ros2msg``: the full definition from ``recording.schemas``, the
  one the bags carry). A topic is subscribed in ROS only while some client subscribes to its
  channel, raw (the CDR bytes as DDS carried them, never decoded here), with the QoS the
  recorder would ask (``recording.recorder_node.request_profile``: a latched topic such as
  ``mode`` arrives at once), and forwarded stamped with its receive time. A fast topic of
  this process is taken from the link bus instead, as the recorder takes it, and encoded
  with the recorder's generated CDR encoders (``recording.cdr``) on the publisher's thread,
  only while a client listens: over DDS it would cost its publisher a serialization and the
  executor a dispatch per message (``docs/benchmarks.md``, "Foxglove").
- Frames: ``/tf`` and ``/tf_static`` are topics like any other when a node publishes them
  (the frame publisher, with tf2_msgs installed). Where none does (a pip install has no
  tf2_msgs), the bridge offers them itself as the recorder writes them into bags: the
  profile's static frames (``EnbarrNode.frame_tree``), sent to each client that subscribes,
  and each dynamic frame's pose from its source topic (``framework.frame_sources``), encoded
  while a client listens; so Foxglove's 3D panel places the vessel and its sensors.
- Parameters: every declared parameter of the nodes of this process (the nodes of the
  bridge's executor), named ``/<node>.<parameter>`` (``foxglove.parameters``). A set goes
  through the node's own ``set_parameters``, what ``ros2 param set`` reaches through the
  parameter service: the same ParamSpec checks, a refusal keeps the old value and its reason
  is sent to the clients as an error status. Writes are refused unless the profile sets
  ``allow_parameter_writes``.
- Client publish (Foxglove's teleop and publish panels): refused unless the profile sets
  ``allow_client_publish``, and then only to ``client_publish_topics`` (default the command
  receiver's twist and the joystick topic), with the topic's own type. A message is decoded
  first (bad bytes never reach DDS), then published as an ordinary ROS message, so the
  command receiver's staleness, arbitration and failsafe checks apply to it as to any other.
  Foxglove's Teleop panel sends an unstamped ``geometry_msgs/Twist``: offered on a topic of
  ``geometry_msgs/TwistStamped`` (``surface_command/twist``), each one is stamped with the
  bridge's clock as it arrives (frame ``base_link``), so its age at the receiver is the
  bridge's latency, and a panel that stops sending leaves the receiver's timeout to zero the
  goal as for any source.

Why both are off and the server binds to loopback by default: anyone who reaches the port
could retune or drive the vessel, and the protocol has no authentication. Open them in a
profile that means it (docs/profiles.md "Foxglove").

Threads: the SDK calls the listener on its own threads. Everything that touches rclpy entities
or nodes' parameters runs on the executor's thread instead, handed over through a queue that a
timer empties every ``JOB_PERIOD`` (bringup's ``EventsExecutor`` takes no guard condition, the
one wake-up from another thread rclpy has), in the order the client sent it; a parameter
request waits for its answer at most ``request_timeout``. Nothing is opened before ``start``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, TimeoutError as FutureTimeout
from dataclasses import dataclass
import queue
import threading
from typing import Any

import foxglove
from foxglove import Channel, Schema, StatusLevel
from foxglove.websocket import (Capability, ChannelView, Client, ClientChannel, ServerListener,
                                WebSocketServer)
from geometry_msgs.msg import Twist, TwistStamped
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frame_sources import pose_sources
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.recording import cdr
from enbarr_core.recording.recorder_node import message_class, qos_of, request_profile
from enbarr_core.recording.schemas import MESSAGE_ENCODING, ros2msg_definition, SCHEMA_ENCODING
from enbarr_core.recording.tf import pose_encoder, tf_message_cdr, TF_MESSAGE
from enbarr_interfaces import topics
from enbarr_interfaces.topics import TopicSpec
from enbarr_plugins.foxglove.parameters import foxglove_name, split_name, to_foxglove, to_ros

#: Foxglove's Teleop panel publishes TWIST; a topic of TWIST_STAMPED takes it stamped.
TWIST, TWIST_STAMPED = 'geometry_msgs/msg/Twist', 'geometry_msgs/msg/TwistStamped'

#: The name the server gives itself in its serverInfo.
SERVER_NAME = 'enbarr'
#: How often the executor takes the clients' requests [s]: the most a teleop message or a
#: parameter request waits for the executor when it is idle.
JOB_PERIOD = 0.05

SPECS = [
    ParamSpec('host', '127.0.0.1', 'Address the WebSocket server binds to (127.0.0.1: this '
              'machine only; 0.0.0.0: every interface, anyone on the network)', read_only=True),
    ParamSpec('port', 8765, 'TCP port of the server; 0: any free port (the bound one is '
              'logged and on /diagnostics)', '', 0, 65535, read_only=True),
    ParamSpec('allow_parameter_writes', False, 'Whether clients may set parameters (they '
              'may always read them)', read_only=True),
    ParamSpec('allow_client_publish', False, 'Whether clients may publish to '
              'client_publish_topics (teleop)', read_only=True),
    ParamSpec('client_publish_topics', [topics.SURFACE_TWIST.name, topics.JOY.name],
              'The only topics a client may publish to, when allow_client_publish',
              read_only=True, element=str),
    ParamSpec('request_timeout', 5.0, 'How long a parameter request waits for the executor',
              's', 0.1, 60.0, read_only=True),
]

#: Exceptions of rclpy's ``set_parameters`` that are a refusal, with their text as reason.
_SET_REFUSALS = (ParameterException, TypeError, ValueError)


@dataclass(frozen=True)
class FoxgloveBridgeSettings:
    """Settings of ``FoxgloveBridgeNode`` (see ``SPECS``)."""

    host: str
    port: int                      # 0: any free port
    allow_parameter_writes: bool
    allow_client_publish: bool
    client_publish_topics: tuple[str, ...]
    request_timeout: float         # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> FoxgloveBridgeSettings:
        """Build from the declared parameters' values; ValueError names a bad one."""
        if not v['host'].strip():
            raise ValueError('host is empty: 127.0.0.1 serves this machine only')
        names = tuple(v['client_publish_topics'])
        for i, name in enumerate(names):
            if not name.strip():
                raise ValueError(f'client_publish_topics[{i}] is empty')
        return cls(host=v['host'].strip(), port=v['port'],
                   allow_parameter_writes=v['allow_parameter_writes'],
                   allow_client_publish=v['allow_client_publish'],
                   client_publish_topics=names, request_timeout=v['request_timeout'])


@dataclass(frozen=True)
class _Advertised:
    """A topic offered to clients: from the graph, or the bridge's own frames."""

    msgtype: str
    channel: Channel
    own: bool = False


@dataclass(frozen=True)
class _ClientPublisher:
    """Where a client's channel goes: its topic, message class and ROS publisher."""

    topic: str
    cls: type
    publisher: Any
    stamp_twist: bool = False   # a Twist from the client, published as a TwistStamped now


class _Listener(ServerListener):
    """The SDK's callbacks, handed to the node (kept apart: the SDK holds this object)."""

    def __init__(self, node: FoxgloveBridgeNode) -> None:
        self._node = node

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._node._client_subscribes(channel.topic, +1)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self._node._client_subscribes(channel.topic, -1)

    def on_client_advertise(self, client: Client, channel: ClientChannel) -> None:
        key, topic = (client.id, channel.id), channel.topic
        encoding, schema_name = channel.encoding, channel.schema_name
        self._node._post(lambda: self._node._client_advertise(key, topic, encoding, schema_name))

    def on_client_unadvertise(self, client: Client, client_channel_id: int) -> None:
        key = (client.id, client_channel_id)
        self._node._post(lambda: self._node._client_unadvertise(key))

    def on_message_data(self, client: Client, client_channel_id: int, data: bytes) -> None:
        key, payload = (client.id, client_channel_id), bytes(data)
        self._node._post(lambda: self._node._client_message(key, payload))

    def on_get_parameters(self, client: Client, param_names: list[str],
                          request_id: str | None = None) -> list[foxglove.Parameter]:
        return self._node._get_parameters(param_names)

    def on_set_parameters(self, client: Client, parameters: list[foxglove.Parameter],
                          request_id: str | None = None) -> list[foxglove.Parameter]:
        return self._node._set_parameters(parameters)


class FoxgloveBridgeNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'foxglove_bridge', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: FoxgloveBridgeSettings
        self.bind_settings(SPECS, FoxgloveBridgeSettings.from_params, self._apply)
        s = self.settings
        try:
            self._allowed = frozenset(self.resolve_topic_name(t)
                                      for t in s.client_publish_topics)
        except NameValidationException as err:
            raise ConfigurationError(f'node {node_name!r}: client_publish_topics: {err}',
                                     parameter='client_publish_topics') from err
        self.server: WebSocketServer | None = None   # started in start()
        self.port: int | None = None                  # the bound port, once serving
        self.failure: str | None = None
        self._fox = foxglove.Context()  # this bridge's channels only, whatever else logs
        self._listener = _Listener(self)
        self._lock = threading.Lock()
        self._advertised: dict[str, _Advertised] = {}   # topic -> channel (lock)
        self._wanted: dict[str, int] = {}               # topic -> client subscriptions (lock)
        self._ros_subs: dict[str, Any] = {}        # topic -> raw subscription
        self._client_pubs: dict[tuple[int, int], _ClientPublisher] = {}
        self._refused_channels: set[tuple[int, int]] = set()
        self._unknown_types: set[str] = set()
        self._pose_sources = pose_sources(self.frame_tree)
        self._linked: set[str] = set()                  # fast topics followed on the bus
        self._following_poses = False
        self.forwarded = 0          # messages sent to clients
        self.client_messages = 0    # client messages published in ROS
        self.refused_messages = 0   # client messages not published (refused channel, bad CDR)
        self._jobs: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self.create_timer(JOB_PERIOD, self._run_jobs)
        self.create_periodic(1.0, self._discover)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: FoxgloveBridgeSettings) -> None:
        self.settings = settings

    # -- life cycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Start the server and advertise the graph's topics (then every second).

        A port that cannot be bound is a problem of the run, not a stop: the vessel runs on
        without a viewer.
        """
        super().start()
        if self.server is None and self.failure is None:
            s = self.settings
            capabilities = [Capability.Parameters]
            if s.allow_client_publish:
                capabilities.append(Capability.ClientPublish)
            try:
                self.server = foxglove.start_server(
                    name=SERVER_NAME, host=s.host, port=s.port, capabilities=capabilities,
                    server_listener=self._listener, context=self._fox,
                    supported_encodings=[MESSAGE_ENCODING] if s.allow_client_publish else None)
            except RuntimeError as err:  # the SDK's FoxgloveError (bind failures)
                self.failure = f'cannot serve Foxglove on {s.host}:{s.port}: {err}'
                self.report_problem(self.failure)
                return
            self.port = self.server.port
            publish = ('on to ' + ', '.join(sorted(self._allowed))
                       if s.allow_client_publish else 'off')
            self.get_logger().info(
                f'Foxglove: ws://{s.host}:{self.port} (parameter writes '
                f'{"on" if s.allow_parameter_writes else "off"}, client publish {publish})')
        self._discover()

    def destroy_node(self) -> None:
        """Stop the server, then destroy the node."""
        if self.server is not None:
            self.server.stop()
            self.server = None
        with self._lock:
            advertised = list(self._advertised.values())
            self._advertised.clear()
        for a in advertised:
            a.channel.close()
        super().destroy_node()

    # -- executor-thread work ---------------------------------------------------------------
    def _post(self, job: Callable[[], None]) -> None:
        """Run ``job`` on the executor's thread (from the SDK's), in posting order."""
        self._jobs.put(job)

    def _run_jobs(self) -> None:
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                return
            try:
                job()
            except Exception as err:  # noqa: BLE001 - one bad request must not stop the rest
                self.get_logger().error(f'Foxglove request failed: {err!r}')

    def _ask(self, job: Callable[[], Any]) -> Any:
        """Run ``job`` on the executor's thread and return its result (SDK thread side)."""
        future: Future[Any] = Future()

        def run() -> None:
            try:
                future.set_result(job())
            except Exception as err:  # noqa: BLE001 - handed back to the asking thread
                future.set_exception(err)
        self._post(run)
        return future.result(timeout=self.settings.request_timeout)

    def _status(self, level: StatusLevel, message: str) -> None:
        """Tell the clients (and the log)."""
        log = self.get_logger()
        (log.warn if level != StatusLevel.Error else log.error)(message)
        if self.server is not None:
            self.server.publish_status(message, level)

    # -- topics -----------------------------------------------------------------------------
    def _discover(self) -> None:
        """Advertise new graph topics, withdraw gone ones (a type change: both)."""
        if self.server is None:
            return
        graph = dict(self.get_topic_names_and_types())
        for name, types in graph.items():
            msgtype = types[0] if len(types) == 1 else None  # mixed types: no one schema
            with self._lock:
                known = self._advertised.get(name)
            if known is not None and known.msgtype == msgtype and not known.own:
                continue
            if known is not None:
                self._withdraw(name)
            if msgtype is None:
                continue
            text = ros2msg_definition(msgtype)
            if text is None:
                if msgtype not in self._unknown_types:
                    self._unknown_types.add(msgtype)
                    self.get_logger().warn(f'{name}: no definition of {msgtype} in the Jazzy '
                                           'type store; not offered to Foxglove')
                continue
            self._advertise(name, msgtype, text)
        with self._lock:
            gone = [n for n, a in self._advertised.items() if n not in graph and not a.own]
        for name in gone:
            self._withdraw(name)
        self._advertise_frames(graph)

    def _advertise(self, name: str, msgtype: str, text: str, own: bool = False) -> None:
        channel = Channel(name, message_encoding=MESSAGE_ENCODING, context=self._fox,
                          schema=Schema(name=msgtype, encoding=SCHEMA_ENCODING,
                                        data=text.encode()))
        with self._lock:
            self._advertised[name] = _Advertised(msgtype, channel, own)
        self._reconcile(name)

    def _advertise_frames(self, graph: Mapping[str, Any]) -> None:
        """Offer the frame tree as ``/tf_static`` and ``/tf`` where no node publishes it."""
        text = ros2msg_definition(TF_MESSAGE)
        assert text is not None  # the Jazzy store has tf2_msgs
        for name, has in ((topics.TF_STATIC_TOPIC, bool(self.frame_tree.static_edges())),
                          (topics.TF_TOPIC, bool(self._pose_sources))):
            with self._lock:
                known = name in self._advertised
            if has and not known and name not in graph:
                self._advertise(name, TF_MESSAGE, text, own=True)

    def _withdraw(self, name: str) -> None:
        with self._lock:
            gone = self._advertised.pop(name, None)
        self._reconcile(name)
        if gone is not None:
            gone.channel.close()

    def _client_subscribes(self, topic: str, step: int) -> None:
        """Count a client (un)subscribing to ``topic`` (SDK thread)."""
        with self._lock:
            n = self._wanted[topic] = max(0, self._wanted.get(topic, 0) + step)
            if n == 0:
                del self._wanted[topic]
        self._post(lambda: self._reconcile(topic))
        if step > 0 and topic == topics.TF_STATIC_TOPIC:
            self._post(self._send_static_frames)

    def _send_static_frames(self) -> None:
        """Send the static frames (again: latched, a new client needs them; executor)."""
        with self._lock:
            a = self._advertised.get(topics.TF_STATIC_TOPIC)
        if a is not None and a.own:
            now = self.now_ns()
            a.channel.log(tf_message_cdr(self.frame_tree.static_transforms(now)), log_time=now)

    def _follow_poses(self) -> None:
        """Forward each dynamic frame's pose on ``/tf`` while a client listens (executor)."""
        self._following_poses = True
        wanted = self._wanted
        for source in self._pose_sources:
            encode = pose_encoder(source)

            def on_pose(msg: Any, encode: Callable[[Any], bytes | None] = encode) -> None:
                # Runs on the source's thread (a fast topic: the control path): nothing is
                # encoded unless a client listens. A read without the lock: a stale answer
                # costs one message either way.
                if not wanted.get(topics.TF_TOPIC):
                    return
                a = self._advertised.get(topics.TF_TOPIC)
                data = encode(msg)
                if data is not None and a is not None and a.own:
                    a.channel.log(data, log_time=self.now_ns())
                    self.forwarded += 1
            self.create_topic_subscription(source.spec, on_pose)

    def _reconcile(self, topic: str) -> None:
        """Subscribe to ``topic`` in ROS while a client wants it and it is advertised."""
        with self._lock:
            advertised = self._advertised.get(topic)
            wanted = self._wanted.get(topic, 0) > 0
        if advertised is not None and advertised.own:
            if wanted and topic == topics.TF_TOPIC and not self._following_poses:
                self._follow_poses()
            return
        sub = self._ros_subs.get(topic)
        if sub is not None and (not wanted or advertised is None):
            self.destroy_subscription(self._ros_subs.pop(topic))
        elif sub is None and wanted and advertised is not None:
            self._subscribe(topic, advertised)

    def _subscribe(self, topic: str, advertised: _Advertised) -> None:
        try:
            cls = message_class(advertised.msgtype)
        except (ImportError, AttributeError, ValueError):
            self._status(StatusLevel.Warning, f'{topic}: no Python message class for '
                         f'{advertised.msgtype} in this process; it cannot be forwarded')
            return
        local = self.link_bus.local_topics().get(topic)
        if local is not None and local.type_name == advertised.msgtype:
            self._follow_link(topic, local)
            return
        offers = [qos_of(i.qos_profile) for i in self.get_publishers_info_by_topic(topic)]
        log = advertised.channel.log
        stamp = self.now_ns

        def forward(data: bytes) -> None:
            log(data, log_time=stamp())
            self.forwarded += 1
        self._ros_subs[topic] = self.create_subscription(
            cls, topic, forward, request_profile(offers), raw=True)

    def _follow_link(self, topic: str, spec: TopicSpec) -> None:
        """Forward a fast topic of this process from the bus while a client wants it."""
        if topic in self._linked:
            return  # subscribed once: the gate below does the rest
        self._linked.add(topic)
        encode = cdr.encoder(spec.msg_type) or serialize_message
        wanted, advertised, stamp = self._wanted, self._advertised, self.now_ns

        def forward(msg: Any) -> None:
            # The publisher's thread (the control path): nothing is encoded unless a client
            # listens. Reads without the lock: a stale answer costs one message either way.
            a = advertised.get(topic)
            if a is None or not wanted.get(topic):
                return
            a.channel.log(encode(msg), log_time=stamp())
            self.forwarded += 1
        self.create_topic_subscription(spec, forward)

    @property
    def advertised_topics(self) -> dict[str, str]:
        """The topics offered to clients and their types."""
        with self._lock:
            return {name: a.msgtype for name, a in self._advertised.items()}

    @property
    def subscribed_topics(self) -> tuple[str, ...]:
        """Return the topics taken for clients now (raw from DDS, or fast from the bus)."""
        with self._lock:
            linked = {t for t in self._linked if self._wanted.get(t)}
        return tuple(sorted(set(self._ros_subs) | linked))

    # -- parameters -------------------------------------------------------------------------
    def _process_nodes(self) -> dict[str, Node]:
        """Return the nodes of this process: the bridge's executor's (itself without one)."""
        executor = self.executor
        nodes = list(executor.get_nodes()) if executor is not None else [self]
        return {n.get_fully_qualified_name(): n for n in nodes}

    def _get_parameters(self, names: Sequence[str]) -> list[foxglove.Parameter]:
        """Return the parameters named (empty: all of every node), SDK thread side."""
        wanted = list(names)
        try:
            return list(self._ask(lambda: self._read_parameters(wanted)))
        except FutureTimeout:
            self._status(StatusLevel.Error, 'parameters: the vessel process did not answer in '
                         f'{self.settings.request_timeout:g} s')
            return []

    def _read_parameters(self, names: Sequence[str]) -> list[foxglove.Parameter]:
        nodes = self._process_nodes()
        out = []
        if not names:
            for fqn, each in sorted(nodes.items()):
                # The prefix '' lists every declared name (its values are read as Parameters).
                for name in sorted(each.get_parameters_by_prefix('')):
                    out.append(to_foxglove(foxglove_name(fqn, name), each.get_parameter(name)))
            return out
        for full in names:
            where = split_name(full)
            node = nodes.get(where.node) if where is not None else None
            if node is not None and where is not None and node.has_parameter(where.name):
                out.append(to_foxglove(full, node.get_parameter(where.name)))
        return out

    def _set_parameters(self, params: Sequence[foxglove.Parameter]) -> list[foxglove.Parameter]:
        """Set what a client asks, report refusals; the values after it (SDK thread side)."""
        requests = [(p.name, p.get_value()) for p in params]
        names = [name for name, _ in requests]
        if not self.settings.allow_parameter_writes:
            for name in names:
                self._status(StatusLevel.Error, f'{name}: not set: parameter writes are off '
                             '(allow_parameter_writes is false in the profile)')
            return self._get_parameters(names)
        try:
            values, refusals = self._ask(lambda: self._write_parameters(requests))
        except FutureTimeout:
            self._status(StatusLevel.Error, 'parameters: the vessel process did not answer in '
                         f'{self.settings.request_timeout:g} s; nothing known of the set')
            return []
        for refusal in refusals:
            self._status(StatusLevel.Error, refusal)
        return list(values)

    def _write_parameters(self, requests: Sequence[tuple[str, Any]]
                          ) -> tuple[list[foxglove.Parameter], list[str]]:
        nodes = self._process_nodes()
        values: list[foxglove.Parameter] = []
        refusals: list[str] = []
        for full, value in requests:
            where = split_name(full)
            node = nodes.get(where.node) if where is not None else None
            if node is None or where is None:
                refusals.append(f'{full}: not set: no node of that name in this process')
                continue
            if not node.has_parameter(where.name):
                refusals.append(f'{full}: not set: {where.node} declares no {where.name}')
                continue
            current = node.get_parameter(where.name)
            try:
                result = node.set_parameters([to_ros(where.name, value, current.type_)])[0]
                ok, reason = result.successful, result.reason
            except _SET_REFUSALS as err:
                ok, reason = False, str(err)
            if ok:
                self.get_logger().info(f'{full} set by a Foxglove client')
            else:
                refusals.append(f'{full}: not set: {reason}')
            values.append(to_foxglove(full, node.get_parameter(where.name)))
        return values, refusals

    # -- client publish ---------------------------------------------------------------------
    def _client_advertise(self, key: tuple[int, int], topic: str, encoding: str,
                          schema_name: str) -> None:
        """Give a client's channel a ROS publisher, or refuse it (executor)."""
        s = self.settings
        try:
            name = self.resolve_topic_name(topic)
        except NameValidationException:  # refused below: no allowed topic has that name
            name = topic
        why = None
        msgtype = self._topic_type(name) or self._contract_type(name) or schema_name
        stamp_twist = (schema_name == TWIST and msgtype == TWIST_STAMPED)
        if not s.allow_client_publish:
            why = 'client publish is off (allow_client_publish is false in the profile)'
        elif name not in self._allowed:
            why = f'not one of client_publish_topics ({", ".join(sorted(self._allowed))})'
        elif encoding != MESSAGE_ENCODING:
            why = f'encoding {encoding!r}, not {MESSAGE_ENCODING!r}'
        elif schema_name != msgtype and not stamp_twist:
            why = f'it carries {msgtype}, the client offers {schema_name}'
        cls = None
        if why is None:
            try:
                cls = message_class(msgtype)
            except (ImportError, AttributeError, ValueError):
                why = f'no Python message class for {msgtype}'
        if why is not None or cls is None:
            self._refused_channels.add(key)
            self._status(StatusLevel.Error, f'client publish to {topic} refused: {why}')
            return
        spec = next((t for t in topics.ALL_TOPICS if self.resolve_topic_name(t.name) == name),
                    None)
        qos = spec.qos if spec is not None else topics.COMMAND_QOS
        self._refused_channels.discard(key)
        self._client_pubs[key] = _ClientPublisher(name, cls,
                                                 self.create_publisher(cls, name, qos),
                                                 stamp_twist)
        self.get_logger().info(f'a Foxglove client publishes to {name}'
                               + (' (Twist, stamped on arrival)' if stamp_twist else ''))

    def _contract_type(self, name: str) -> str | None:
        """Return the type of the contract's topic (``topics.ALL_TOPICS``) named ``name``."""
        spec = next((t for t in topics.ALL_TOPICS if self.resolve_topic_name(t.name) == name),
                    None)
        return spec.type_name if spec is not None else None

    def _topic_type(self, name: str) -> str | None:
        types = dict(self.get_topic_names_and_types()).get(name, [])
        return types[0] if len(types) == 1 else None

    def _client_unadvertise(self, key: tuple[int, int]) -> None:
        self._refused_channels.discard(key)
        pub = self._client_pubs.pop(key, None)
        if pub is not None:
            self.destroy_publisher(pub.publisher)

    def _client_message(self, key: tuple[int, int], data: bytes) -> None:
        """Publish a client's message in ROS, decoded first (executor)."""
        pub = self._client_pubs.get(key)
        if pub is None:
            self.refused_messages += 1
            return
        cls = Twist if pub.stamp_twist else pub.cls
        try:
            msg = deserialize_message(data, cls)
        except Exception as err:  # noqa: BLE001 - rclpy raises plain exceptions on bad CDR
            self.refused_messages += 1
            self._status(StatusLevel.Error, f'client message on {pub.topic} dropped: not a '
                         f'valid {cls.__name__} ({err})')
            return
        if pub.stamp_twist:   # the Teleop panel's Twist: stamped as it arrives
            stamped = TwistStamped(twist=msg)
            stamped.header.stamp = self.get_clock().now().to_msg()
            stamped.header.frame_id = topics.BODY_FRAME
            msg = stamped
        pub.publisher.publish(msg)
        self.client_messages += 1

    # -- supervision ------------------------------------------------------------------------
    def _report(self) -> None:
        s = self.settings
        values = {'host': s.host, 'port': self.port if self.port is not None else '',
                  'advertised': len(self._advertised), 'subscribed': len(self.subscribed_topics),
                  'forwarded': self.forwarded, 'client_messages': self.client_messages,
                  'refused_messages': self.refused_messages,
                  'parameter_writes': s.allow_parameter_writes,
                  'client_publish': s.allow_client_publish}
        if self.failure is not None:
            self.publish_diagnostics(2, self.failure, values)
        elif self.server is not None:
            self.publish_diagnostics(0, f'serving Foxglove on ws://{s.host}:{self.port}', values)
