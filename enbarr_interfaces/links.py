"""The in-process fast path: composed nodes hand messages to each other as direct calls.

Why: in rclpy every topic hop costs a DDS round trip plus an executor dispatch
(``docs/benchmarks.md``), so a five-hop IMU -> thruster chain cannot run at 400 Hz. A ``LinkBus``
exists per rclpy ``Context``. A node publishes a *fast* topic through a ``LinkPublisher``: every
in-process ``LinkSubscription`` of the same resolved name is called synchronously with the message
object, and the message goes out over DDS only while some other process (``ros2 topic echo``, a
recorder elsewhere, a node in another group) subscribes. A ``LinkSubscription`` with no publisher
in its process falls back to an ordinary ROS subscription when the bus is connected, so a chain
split over processes (profile groups) or fed by a third-party node still works. See
``docs/architecture.md``.

Graph visibility: every link subscription fed by the bus owns a *shadow reader*, a DDS reader of
its topic created on the subscribing node but never handed to an executor, so ``ros2 topic
info``, rqt_graph and ``Node.get_subscriptions_info_by_topic`` show the node subscribing, as
rclcpp shows its intra-process subscriptions. Nothing ever takes from it (history KEEP_LAST 1:
a sample arriving replaces the previous one in the middleware). A link publisher does not count
its bus's shadows when it decides whether anyone outside the fast path listens.

Rules that follow: a fast topic has its producer(s) in one process; a published message is
never modified afterwards (subscribers may keep it, e.g. a recorder's queue); callbacks are
short and must not block (they run on the publisher's thread); a callback that raises is logged and
counted, and never breaks the publisher or the other subscribers.
"""

from __future__ import annotations

from collections.abc import Callable
import copy
import threading
import time
from typing import Any, TYPE_CHECKING, TypeVar
import weakref

from rclpy.event_handler import PublisherEventCallbacks
from rclpy.exceptions import InvalidHandle
# rclpy 7.1.6 has no public way to create a subscription that no executor waits on: the
# executors (SingleThreadedExecutor in Python, EventsExecutor in C++) take every entity of
# ``Node.subscriptions``, and the EventsExecutor ignores callback groups. A shadow reader is
# therefore the bare rcl subscription, the object ``Node.create_subscription`` wraps.
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.type_support import check_is_valid_msg_type

if TYPE_CHECKING:
    from rclpy.node import Node
    from rclpy.subscription import Subscription

    from enbarr_interfaces.topics import TopicSpec

Callback = Callable[[Any], None]
P = TypeVar('P', bound='PerContext')
#: How often a link publisher asks DDS whether anyone outside the process listens [s].
READER_CHECK_PERIOD = 0.1


class LinkSubscription:
    """An in-process subscriber of one resolved topic.

    It always has exactly one DDS reader, so the ROS graph shows its node subscribing: the
    shadow reader while the bus feeds it (``local``), the fallback ROS subscription otherwise.
    """

    def __init__(self, bus: LinkBus, node: Node, spec: TopicSpec, name: str,
                 callback: Callback) -> None:
        self.bus = bus
        self.node = node
        self.spec = spec
        self.name = name
        self.callback = callback
        self.errors = 0
        self.ros_subscription: Subscription | None = None
        self.shadow_reader: Any | None = None

    @property
    def local(self) -> bool:
        """True when fed by in-process publishers, False when through DDS."""
        return self.ros_subscription is None

    def deliver(self, msg: Any) -> None:
        """Hand ``msg`` to the callback (errors are logged, never raised)."""
        try:
            self.callback(msg)
        except Exception as err:  # noqa: BLE001 - one faulty node must not stop the chain
            self.failed(err)

    def failed(self, err: Exception) -> None:
        """Count and log a callback that raised ``err`` (``deliver``, ``LinkPublisher``)."""
        self.errors += 1
        self.node.get_logger().error(
            f'callback for {self.name} failed ({self.errors} so far): {err!r}',
            throttle_duration_sec=1.0)

    def destroy(self) -> None:
        """Leave the bus and the ROS graph."""
        self.bus._remove_subscription(self)
        if self.ros_subscription is not None:
            self.node.destroy_subscription(self.ros_subscription)
            self.ros_subscription = None
        self._drop_shadow()

    # -- the shadow reader (see the module docstring) ---------------------------------------
    def _add_shadow(self) -> None:
        if self.shadow_reader is not None:
            return
        spec = self.spec
        check_is_valid_msg_type(spec.msg_type)  # loads the type support, as create_* does
        with self.node.handle:
            # The same name resolution as Node.create_subscription (namespace, remapping).
            self.shadow_reader = _rclpy.Subscription(
                self.node.handle, spec.msg_type, spec.name,
                shadow_qos(spec.qos).get_c_qos_profile())

    def _drop_shadow(self) -> None:
        reader, self.shadow_reader = self.shadow_reader, None
        if reader is not None:
            # Deferred while a publisher thread is counting its matches (``with reader``).
            reader.destroy_when_not_in_use()


def shadow_qos(qos: QoSProfile) -> QoSProfile:
    """Return the QoS of a shadow reader: the topic's, with a history of one sample.

    Reliability and durability stay the topic's, so graph tools show the QoS the subscriber
    really asks for and the shadow matches exactly the writers its subscription would.
    """
    shadow = copy.copy(qos)
    shadow.history = HistoryPolicy.KEEP_LAST
    shadow.depth = 1
    return shadow


class LinkPublisher:
    """Publishes to in-process subscribers directly and to DDS only when it has readers."""

    def __init__(self, bus: LinkBus, node: Node, spec: TopicSpec, name: str) -> None:
        self.bus = bus
        self.node = node
        self.spec = spec
        self.name = name
        self._subscribers: tuple[LinkSubscription, ...] = ()
        self._shadows: tuple[Any, ...] = ()
        # No QoS event handlers: every handler is one more entity the executor re-adds to its
        # wait set at each wake-up, and the fast path has a dozen publishers (the matched
        # event plus rclpy's two default handlers per publisher made every dispatch of the
        # executor dearer: docs/benchmarks.md).
        self.ros_publisher = node.create_publisher(
            spec.msg_type, spec.name, spec.qos,
            event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        self._readers = 0
        self._readers_checked = -READER_CHECK_PERIOD

    @property
    def topic_name(self) -> str:
        """Return the resolved topic name."""
        return self.name

    def publish(self, msg: Any) -> None:
        """Deliver ``msg`` to every subscriber of the topic."""
        for sub in self._subscribers:
            # ``sub.deliver(msg)`` inlined: one call less per subscriber and sample.
            try:
                sub.callback(msg)
            except Exception as err:  # noqa: BLE001 - one faulty node must not stop the chain
                sub.failed(err)
        if self._dds_readers():
            self.ros_publisher.publish(msg)

    def has_readers(self) -> bool:
        """Return whether a message published now reaches anyone, in the process or outside.

        For a message that costs more to build than to send (a status at the control rate):
        build it only when someone reads it.
        """
        return bool(self._subscribers) or self._dds_readers() > 0

    def _dds_readers(self) -> int:
        # Only DDS readers outside the fast path count (``external_readers``), asked of the
        # middleware at most every READER_CHECK_PERIOD (a new reader waits that long).
        now = time.monotonic()
        if now - self._readers_checked >= READER_CHECK_PERIOD:
            self._readers = self.external_readers()
            self._readers_checked = now
        return self._readers

    def external_readers(self) -> int:
        """Return how many DDS readers outside this bus's fast path this publisher reaches.

        The writer's matched count minus the shadow readers of this bus it has matched. Which
        readers a writer has matched is not visible in rclpy, so a shadow counts as matched
        once it has matched any writer: the rmw matches the endpoints of one participant
        synchronously (Fast DDS), and where matching is asynchronous the two sides may
        disagree only until both have seen each other (a check later). Two matched counts per
        check, never a graph query (many times dearer: ``docs/benchmarks.md``).
        """
        matched = self.ros_publisher.get_subscription_count()
        if matched == 0:
            return 0
        shadows = 0
        for reader in self._shadows:
            try:
                with reader:
                    shadows += reader.get_publisher_count() > 0
            except InvalidHandle:  # destroyed meanwhile: it no longer counts anywhere
                pass
        return max(0, matched - shadows)

    def destroy(self) -> None:
        """Leave the bus."""
        self.bus._remove_publisher(self)
        self.node.destroy_publisher(self.ros_publisher)


class PerContext:
    """One instance of the subclass per rclpy ``Context``: ``Sub.of(context)``.

    Composed nodes share what belongs to their process through it (the link bus, the
    supervision ``Ticker`` of ``enbarr_core.framework.node``); a context that is gone takes its
    instance with it.
    """

    _instances: weakref.WeakKeyDictionary[Any, Any]
    _instances_lock: threading.Lock

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls._instances = weakref.WeakKeyDictionary()
        cls._instances_lock = threading.Lock()

    @classmethod
    def of(cls: type[P], context: Any) -> P:
        """Return the instance of ``context`` (created on first use)."""
        with cls._instances_lock:
            instance = cls._instances.get(context)
            if instance is None:
                instance = cls._instances[context] = cls()
            return instance


class LinkBus(PerContext):
    """All link publishers and subscriptions of one rclpy ``Context``."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._publishers: dict[str, list[LinkPublisher]] = {}
        self._subscriptions: dict[str, list[LinkSubscription]] = {}
        self._connected = False
        self._taps: list[Callable[[LinkPublisher], None]] = []

    # -- creation ---------------------------------------------------------------------------
    def create_publisher(self, node: Node, spec: TopicSpec) -> LinkPublisher:
        """Create a publisher of the fast topic ``spec`` for ``node``."""
        _require_fast(spec)
        name = node.resolve_topic_name(spec.name)
        pub = LinkPublisher(self, node, spec, name)
        with self._lock:
            self._publishers.setdefault(name, []).append(pub)
            subs = list(self._subscriptions.get(name, ()))
            taps = list(self._taps)
        for sub in subs:
            if sub.ros_subscription is not None:
                # It fell back to DDS before this publisher existed: switch it to the link.
                sub.node.destroy_subscription(sub.ros_subscription)
                sub.ros_subscription = None
                sub._add_shadow()
        self._rewire(name)
        for tap in taps:
            tap(pub)
        return pub

    def create_subscription(self, node: Node, spec: TopicSpec,
                            callback: Callback) -> LinkSubscription:
        """Create a subscription to the fast topic ``spec`` for ``node``."""
        _require_fast(spec)
        name = node.resolve_topic_name(spec.name)
        sub = LinkSubscription(self, node, spec, name, callback)
        with self._lock:
            self._subscriptions.setdefault(name, []).append(sub)
            has_local = bool(self._publishers.get(name))
            connected = self._connected
        if connected and not has_local:
            self._fall_back(sub)
        else:
            # Fed by the bus, or undecided until connect(): either way the node subscribes.
            sub._add_shadow()
            self._rewire(name)
        return sub

    def connect(self) -> None:
        """Give every subscription without an in-process publisher a DDS subscription.

        Called once all nodes of a process exist (``bringup`` does it); subscriptions created
        afterwards decide at creation.
        """
        with self._lock:
            self._connected = True
            pending = [s for name, subs in self._subscriptions.items()
                       if not self._publishers.get(name) for s in subs
                       if s.ros_subscription is None]
        for sub in pending:
            self._fall_back(sub)

    def add_tap(self, tap: Callable[[LinkPublisher], None]) -> None:
        """Call ``tap`` for every link publisher, now and when one is created (recorders)."""
        with self._lock:
            self._taps.append(tap)
            pubs = [p for ps in self._publishers.values() for p in ps]
        for pub in pubs:
            tap(pub)

    def remove_tap(self, tap: Callable[[LinkPublisher], None]) -> None:
        """Stop calling ``tap`` for new publishers."""
        with self._lock:
            if tap in self._taps:
                self._taps.remove(tap)

    def local_topics(self) -> dict[str, TopicSpec]:
        """Return the resolved names and specs of the topics published through this bus."""
        with self._lock:
            return {name: pubs[0].spec for name, pubs in self._publishers.items() if pubs}

    # -- internals --------------------------------------------------------------------------
    def _fall_back(self, sub: LinkSubscription) -> None:
        # The ROS subscription replaces the shadow: one reader per subscription in the graph.
        sub._drop_shadow()
        sub.ros_subscription = sub.node.create_subscription(
            sub.spec.msg_type, sub.spec.name, sub.deliver, sub.spec.qos)
        self._rewire(sub.name)

    def _rewire(self, name: str) -> None:
        with self._lock:
            subs = tuple(s for s in self._subscriptions.get(name, ())
                         if s.ros_subscription is None)
            shadows = tuple(s.shadow_reader for s in subs if s.shadow_reader is not None)
            for pub in self._publishers.get(name, ()):
                pub._subscribers = subs
                pub._shadows = shadows
                pub._readers_checked = -READER_CHECK_PERIOD  # judge the new wiring at once

    def _remove_publisher(self, pub: LinkPublisher) -> None:
        with self._lock:
            pubs = self._publishers.get(pub.name, [])
            if pub in pubs:
                pubs.remove(pub)

    def _remove_subscription(self, sub: LinkSubscription) -> None:
        with self._lock:
            subs = self._subscriptions.get(sub.name, [])
            if sub in subs:
                subs.remove(sub)
        self._rewire(sub.name)


def _require_fast(spec: TopicSpec) -> None:
    """Only topics the contract marks ``fast`` travel on the bus (``TopicSpec.fast``)."""
    if not spec.fast:
        raise ValueError(f'topic {spec.name!r} is not a fast topic in the contract '
                         '(enbarr_interfaces.topics); publish it as an ordinary ROS topic')
