"""Recorder: writes topics to a rosbag2 MCAP bag (``recording.bag``), as ``ros2 bag record``.

Fast topics of this process are taken from the link bus (no DDS traffic, the message objects
themselves); every other topic seen in the ROS graph is subscribed raw (already serialized),
rediscovered every second. The publisher's thread only stamps the message and queues it;
serializing (the generated CDR encoders of ``cdr``, ``serialize_message`` for other types)
and writing happen on a writer thread, off the control path. ``topics`` selects topics by
name (empty: all, but see Images below). The bag is one MCAP file per run (split by
``split_size`` or ``split_seconds`` when asked), flushed every ``flush_seconds`` (a kill
loses at most that), closed when the node is destroyed. ``segment_seconds`` is the old name
of ``flush_seconds``.

Images: with ``topics`` empty, a raw image topic (``sensor_msgs/msg/Image``) whose compressed
sibling ``<name>/compressed`` (``sensor_msgs/msg/CompressedImage``, image_transport's naming)
is in the graph is left out (``skip_raw_images``, default true): the camera's JPEG is recorded
instead, as a raw 640x480 stream at 15 fps (about 14 MB/s) is more than a Raspberry Pi's SD
card keeps up with. A raw image subscribed before its sibling appeared is dropped from then on
(the bag keeps what came before). A ``topics`` selection records what it names, raw or not.

Topics from the ROS graph are subscribed as ``ros2 bag record`` does (``recording.qos``): with
the reliability and durability every publisher offers, so that a latched topic (``mode``,
``guidance/path_available``) is recorded from its first message even when that was
published before the recorder subscribed (it comes a few milliseconds later: ``latched_pending``
lists what has not come yet), and a reliable topic is recorded reliably. The
offered profiles go to the bag's ``offered_qos_profiles``; latched topics are repeated at the
start of every file of a split bag.

Frames: the recorder writes the profile's frame tree (``EnbarrNode.frame_tree``) as
``/tf_static`` (latched: first in every file) and each dynamic frame's pose (the vessel's
estimate, ``framework.frame_sources``) as ``/tf``, so that a bag opened in Foxglove or RViz
shows the vessel and its sensors in place. These two topics are its own: the same names on
the graph (a live frame publisher) are not recorded again. With a ``topics`` selection they
are written only when selected.

Nothing is opened before ``start``: constructing the node only checks the bag path (bringup
``--check`` builds every node and must leave nothing behind). A selected topic that has not
appeared a few seconds (``MISSING_WARN_SECONDS``) after the start is warned about; one that
never appeared is a problem at the end (the run exits ``EXIT_PROBLEMS`` naming it).

Recording is not control: nothing here may slow or stop the chain. The queue to the writer
holds at most ``max_queued`` messages (a slow disk drops the newest and counts them,
``overflow``); a node with less than ``min_free_space`` free where the bag goes is refused at
start, and the free space is checked again at every chunk and flush. When the storage fails
or falls below the margin the recorder stops queueing, keeps the bag as last flushed, says so on
``/diagnostics`` (ERROR) and the log, and reports a problem, so that bringup exits non-zero
(``EXIT_PROBLEMS``) naming it at the end; the vehicle runs on.

Start and stop (``recorder/control``, std_msgs/String, ``CONTROL_WORDS``): the recorder
records from its start, into ``path``. ``stop`` closes the bag (complete and readable, as at
the end of a run); ``start`` opens a new bag beside it in the same directory (``path`` with
``_1``, ``_2`` ... appended: the first free name), which starts with the latched topics' last
messages and the frame tree, as every file of a split bag does. A word that does not apply
(``start`` while recording, ``stop`` while stopped, after a storage failure, an unknown word)
changes nothing: the reason is logged and kept in ``/diagnostics`` (``last_control_refusal``).
The status on ``/diagnostics`` (1 Hz) says whether it records, the bag (the open one, or the
last one closed), its size on disk and the free space there (``shutil.disk_usage``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import importlib
from pathlib import Path
import queue
import threading
import time
from typing import Any

from rclpy.clock import JumpThreshold
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import String

from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkPublisher

from enbarr_core.framework.errors import ConfigurationError, RecorderError
from enbarr_core.framework.frame_sources import pose_sources, PoseSource
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.recording import cdr
from enbarr_core.recording.bag import (BagStorageError, BagWriter, check_bag_path, free_bytes,
                                       MB)
from enbarr_core.recording.qos import (adapt_request, offered_qos_yaml, Qos, TF_QOS,
                                       TF_STATIC_QOS)
from enbarr_core.recording.recorder import Recorder
from enbarr_core.recording.tf import pose_encoder, tf_message_cdr, TF_MESSAGE

SPECS = [
    ParamSpec('path', '', 'Bag directory to create (must not exist or be empty)',
              read_only=True),
    ParamSpec('topics', [''], 'Topics to record (resolved names); empty: all', read_only=True,
              element=str),
    ParamSpec('skip_raw_images', True, 'With topics empty: leave out each sensor_msgs/Image '
              'topic whose <name>/compressed (sensor_msgs/CompressedImage) is in the graph, '
              'recording the JPEG only; false: record both', read_only=True),
    ParamSpec('flush_seconds', 1.0, 'Flush period: a kill loses at most this much', 's',
              0.01, 3600.0, read_only=True),
    ParamSpec('segment_seconds', 0.0, 'Deprecated: the old name of flush_seconds (0: unset); '
              'when set it is used, with a warning', 's', 0.0, 3600.0, read_only=True),
    ParamSpec('split_size', 0.0, 'Start a new file of the bag once the current one is this big '
              '(as ros2 bag record --max-bag-size); 0: one file', 'MB', 0.0, 1.0e6,
              read_only=True),
    ParamSpec('split_seconds', 0.0, 'Start a new file of the bag once the current one spans '
              'this much message time (as --max-bag-duration); 0: one file', 's', 0.0, 1.0e7,
              read_only=True),
    ParamSpec('min_free_space', 64.0, 'Free space below which recording is refused at start '
              'and stopped during the run (checked at every chunk and flush)', 'MB', 0.0,
              1.0e6, read_only=True),
    ParamSpec('max_queued', 20000, 'Messages waiting for the writer at most; more are '
              'dropped and counted (overflow)', '', 100, 10_000_000, read_only=True),
]


@dataclass(frozen=True)
class RecorderSettings:
    """Settings of ``RecorderNode`` (see ``SPECS``); all fixed for the node's life."""

    path: str                   # bag directory; empty: not set
    topics: frozenset[str]      # resolved topic names to record; empty: all
    flush_seconds: float        # [s]
    min_free_space: float = 64.0  # [MB]
    max_queued: int = 20000     # messages
    split_size: float = 0.0     # [MB], 0: no split
    split_seconds: float = 0.0  # [s], 0: no split
    segment_seconds: float = 0.0  # [s] deprecated alias of flush_seconds, 0: unset
    skip_raw_images: bool = True  # with topics empty: a raw image with a compressed sibling

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> RecorderSettings:
        """Build from the declared parameters' values (empty topic names are dropped)."""
        return cls(path=v['path'], topics=frozenset(t for t in v['topics'] if t),
                   flush_seconds=v['segment_seconds'] or v['flush_seconds'],
                   min_free_space=v['min_free_space'], max_queued=v['max_queued'],
                   split_size=v['split_size'], split_seconds=v['split_seconds'],
                   segment_seconds=v['segment_seconds'],
                   skip_raw_images=v['skip_raw_images'])


#: The types of a raw image and of its compressed sibling (``<name>/compressed``).
IMAGE_TYPE, COMPRESSED_TYPE = 'sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'

#: Messages a graph subscription keeps waiting for the executor (as the old fixed profile).
RAW_DEPTH = 100
_STOP = object()
#: The writer thread takes what is queued this often [s] (the queue bounds what waits).
DRAIN_SECONDS = 0.02
#: A recorder that got no message for this long, with no publisher left, has all [s].
QUIET_SECONDS = 0.3
#: A selected topic not in the graph this long after the start is warned about [s].
MISSING_WARN_SECONDS = 5.0
#: What ``recorder/control`` takes: close the bag, or open a new one beside it.
CONTROL_WORDS = ('start', 'stop')


def next_bag_path(base: str | Path, taken: Any = None) -> Path:
    """Return the first of ``base_1``, ``base_2`` ... that does not exist (``taken``: a test's).

    ``taken(path)`` says whether a path exists (default: the file system).
    """
    base = Path(base)
    exists = taken if taken is not None else (lambda p: p.exists())
    n = 1
    while exists(base.with_name(f'{base.name}_{n}')):
        n += 1
    return base.with_name(f'{base.name}_{n}')


def bag_bytes(path: str | Path) -> int:
    """Bytes the bag directory's files take on disk now (0: none yet)."""
    try:
        return sum(f.stat().st_size for f in Path(path).iterdir() if f.is_file())
    except OSError:
        return 0


def qos_of(profile: QoSProfile) -> Qos:
    """Return the rmw names of an rclpy ``QoSProfile`` (as the graph reports one)."""
    return Qos(history=profile.history.name.lower(), depth=profile.depth,
               reliability=profile.reliability.name.lower(),
               durability=profile.durability.name.lower(),
               deadline_ns=profile.deadline.nanoseconds,
               lifespan_ns=profile.lifespan.nanoseconds,
               liveliness=profile.liveliness.name.lower(),
               liveliness_lease_ns=profile.liveliness_lease_duration.nanoseconds,
               avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions)


def request_profile(offers: list[Qos]) -> QoSProfile:
    """Return the profile that every offer matches, losing least (``adapt_request``)."""
    r = adapt_request(offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=RAW_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if r.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if r.transient_local
                    else DurabilityPolicy.VOLATILE))


def message_class(type_name: str) -> type:
    """``pkg/msg/Type`` -> the generated Python class."""
    pkg, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


class RecorderNode(EnbarrNode, Recorder):
    """See the module docstring."""

    def __init__(self, node_name: str = 'recorder', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: RecorderSettings
        self.bind_settings(SPECS, RecorderSettings.from_params, self._apply)
        if not self.settings.path:
            raise ConfigurationError(f'node {node_name!r}: parameter path is not set',
                                     parameter='path')
        if self.settings.segment_seconds:
            self.get_logger().warn(
                'parameter segment_seconds is deprecated: it is now flush_seconds (the bag is '
                'one file, split only by split_size / split_seconds); using '
                f'flush_seconds = {self.settings.segment_seconds:g}')
        s = self.settings
        try:  # checked, not created: the bag is opened at start
            check_bag_path(s.path, round(s.min_free_space * MB))
            self._pose_sources: list[PoseSource] = pose_sources(self.frame_tree)
        except RecorderError as err:
            raise ConfigurationError(f'node {node_name!r}: {err}', parameter='path') from err
        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        self.writer: BagWriter | None = None  # opened at start
        self.written = 0
        self.dropped = 0            # messages the bag refused (bad bytes, a type change)
        self.overflow = 0           # messages dropped because the queue was full
        self.recording = True       # False once the storage failed: nothing is queued then
        self.failure: str | None = None
        self.paused = False         # stopped through recorder/control: nothing is queued
        self.bag = Path(self.settings.path)  # the open bag, or the last one closed
        self.last_control_refusal = ''
        self._opened = False        # the first bag was opened (start may run again)
        self._steps: list[Any] = []  # every _control step, replayed into a new bag
        # The closed bag's latched topics -> (type, depth, messages): the next bag's start.
        self._carry: dict[str, tuple[str, int, tuple[tuple[int, bytes], ...]]] = {}
        self._overflow_seen = 0
        self._last_received = 0.0  # monotonic time of the last message queued [s]
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._subscribed: set[str] = set()
        # Latched topics subscribed over DDS whose first message has not come yet: a latched
        # message published before the subscription arrives later, by the middleware's
        # late-joiner repair (``latched_pending``).
        self._latched_waiting: set[str] = set()
        self._raw_images: dict[str, Any] = {}  # raw image topic -> its subscription
        self.skipped_raw: set[str] = set()  # raw images left out for their compressed sibling
        self._mixed_warned: set[str] = set()
        self._missing_warned = False
        self._started_at: float | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._write_loop, name='recorder_writer',
                                        daemon=True)
        # Receive stamps: the node's clock, read as time.time_ns while it is the system clock (the
        # same CLOCK_REALTIME value, without building the rclpy Time of clock.now(): a stamp per
        # message, docs/benchmarks.md); the clock's own reading while ROS (simulated) time is
        # active. A clock-change jump callback switches between them.
        self._stamp: Any = time.time_ns
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=None, on_clock_change=True),
            post_callback=lambda _jump: self._choose_stamp())
        self._choose_stamp()
        # The static frames go first in the queue: ahead of any message of a source started
        # before this recorder, so /tf_static opens the bag's first file.
        self._latch_static_frames()
        self.link_bus.add_tap(self._on_link_publisher)
        self.create_periodic(1.0, self._discover)
        self.create_periodic(1.0, self._report)
        self.create_topic_subscription(topics.RECORDER_CONTROL, self._on_control)

    def _choose_stamp(self) -> None:
        clock = self.get_clock()
        if getattr(clock, 'ros_time_is_active', False):
            self._stamp = self.now_ns
        else:
            self._stamp = time.time_ns

    def _control(self, step: Any) -> None:
        """Run ``step(writer)`` on the writer thread, in order with the messages queued.

        How the writer learns a topic's offered QoS or that it is latched: before the topic's
        first message (the subscription is made after), without sharing the writer between
        threads. Never dropped: these are few, one per topic. Kept, so that a bag opened by
        ``start`` learns them too.
        """
        self._steps.append(step)
        self._queue.put((None, 0, step))

    def _lifecycle(self, step: Any) -> None:
        """Run ``step()`` on the writer thread, in order with the messages queued."""
        self._queue.put((None, 1, step))

    # -- start and stop (recorder/control) ----------------------------------------------------
    def _on_control(self, msg: String) -> None:
        reason = self.control(msg.data)
        if reason:
            self.last_control_refusal = reason
            self.get_logger().warn(f'recorder/control {msg.data!r} refused: {reason}')
        self._report()

    def control(self, word: str) -> str:
        """Apply one ``recorder/control`` word; '' when done, else why not (nothing changed)."""
        if word not in CONTROL_WORDS:
            return f'unknown word {word!r}: one of {", ".join(CONTROL_WORDS)}'
        if not self.recording:
            return f'recording failed, it cannot be controlled: {self.failure}'
        if not self._opened:
            return 'the recorder has not started yet'
        if word == 'stop':
            if self.paused:
                return f'not recording (the last bag, {self.bag}, is closed)'
            self.paused = True   # from now on nothing is queued; what is queued goes in
            self._lifecycle(self._close_bag)
            self.get_logger().info(f'recording stopped: {self.bag} closed')
            return ''
        if not self.paused:
            return f'already recording to {self.bag}'
        s = self.settings
        path = next_bag_path(s.path)
        try:
            writer = BagWriter(path, s.flush_seconds, round(s.min_free_space * MB),
                               split_size=round(s.split_size * MB),
                               split_seconds=s.split_seconds)
        except RecorderError as err:
            return str(err)
        self._lifecycle(lambda: self._open_bag(writer))
        self.bag = path
        self.paused = False
        self.get_logger().info(f'recording started: {path}')
        return ''

    def _close_bag(self) -> None:
        """Writer thread: close the open bag; keep its latched state for the next one."""
        writer, self.writer = self.writer, None
        if writer is not None:
            self._carry = writer.latched_messages()
            self._guarded(writer.close)

    def _open_bag(self, writer: BagWriter) -> None:
        """Writer thread: what every topic offered and the latched messages, then record."""
        for step in list(self._steps):   # one made meanwhile also comes through the queue
            step(writer)
        for topic, (msgtype, depth, messages) in self._carry.items():
            writer.latch(topic, msgtype, depth, messages)
        self.writer = writer

    def _put(self, item: tuple[tuple[str, str, Any], int, Any]) -> None:
        """Queue one message for the writer; called on the publishers' threads, never waits.

        SimpleQueue.qsize and put are single C calls: two threads may both pass the check,
        so the bound can be passed by a message per publishing thread, never more.
        """
        if not self.recording or self.paused:
            return
        self._last_received = time.monotonic()
        if self._queue.qsize() >= self.settings.max_queued:
            self.overflow += 1
            return
        self._queue.put(item)

    def _apply(self, settings: RecorderSettings) -> None:
        self.settings = settings

    def _selected(self, name: str) -> bool:
        selected = self.settings.topics
        return not selected or name in selected

    def _wanted(self, name: str) -> bool:
        return self._selected(name) and name not in self._subscribed

    def _offer(self, topic: str, msgtype: str, offers: list[Qos]) -> None:
        """Tell the writer what ``topic``'s publishers offer; latch it if all keep history."""
        text = offered_qos_yaml(offers)
        latched = adapt_request(offers).transient_local
        depth = max(1, len(offers))  # the last message of each publisher (claims: one each)

        def describe(writer: BagWriter) -> None:
            writer.set_offered_qos(topic, text)
            if latched:
                writer.latch(topic, msgtype, depth)
        self._control(describe)

    def _on_link_publisher(self, pub: LinkPublisher) -> None:
        with self._lock:
            if not self._wanted(pub.name):
                return
            self._subscribed.add(pub.name)
        self._offer(pub.name, pub.spec.type_name, [qos_of(pub.spec.qos)])
        # What the writer needs of the topic, one tuple for all its messages.
        entry = (pub.name, pub.spec.type_name, cdr.encoder(pub.spec.msg_type))
        put = self._put
        self.create_topic_subscription(pub.spec, lambda msg: put((entry, self._stamp(), msg)))

    def start(self) -> None:
        """Open the bag, write the frame tree, subscribe to what the graph has (then every 1 s).

        A bag that cannot be opened now (its directory was taken meanwhile, the disk filled)
        is a problem of the run, not a stop: the vehicle runs on unrecorded.
        """
        super().start()
        if not self._opened and self.recording:  # the first start (sources may restart)
            self._opened = True
            s = self.settings
            self._started_at = time.monotonic()
            try:
                self.writer = BagWriter(s.path, s.flush_seconds, round(s.min_free_space * MB),
                                        split_size=round(s.split_size * MB),
                                        split_seconds=s.split_seconds)
            except RecorderError as err:
                self.recording = False
                self.failure = str(err)
                self.report_problem(f'recording failed: {err}')
                return
            self._record_frames()
            self._thread.start()
        self._discover()

    def _latch_static_frames(self) -> None:
        """Queue ``/tf_static`` (the tree's static frames), latched: first in every file.

        These two topics are the recorder's own: the same names on the graph are not taken.
        """
        with self._lock:
            self._record_tf = self._wanted(topics.TF_TOPIC)
            own_static = self._wanted(topics.TF_STATIC_TOPIC)
            self._subscribed.update((topics.TF_STATIC_TOPIC, topics.TF_TOPIC))
        static = self.frame_tree.static_transforms(self.now_ns())
        if not own_static or not static:
            return
        data = tf_message_cdr(static)
        stamp = self._stamp()

        def latch(writer: BagWriter) -> None:
            writer.set_offered_qos(topics.TF_STATIC_TOPIC, offered_qos_yaml([TF_STATIC_QOS]))
            writer.latch(topics.TF_STATIC_TOPIC, TF_MESSAGE, messages=((stamp, data),))
        self._control(latch)

    def _record_frames(self) -> None:
        """``/tf`` from each pose source's messages (subscribed once the bus is connected)."""
        if not self._record_tf or not self._pose_sources:
            return
        tf_yaml = offered_qos_yaml([TF_QOS])
        self._control(lambda writer: writer.set_offered_qos(topics.TF_TOPIC, tf_yaml))
        put = self._put
        for source in self._pose_sources:
            entry = (topics.TF_TOPIC, TF_MESSAGE, pose_encoder(source))
            self.create_topic_subscription(
                source.spec, lambda msg, e=entry: put((e, self._stamp(), msg)))

    def _skips_raw(self, name: str, types: list[str], graph: dict[str, list[str]]) -> bool:
        """Whether ``name`` is a raw image left out for its compressed sibling."""
        return (self.settings.skip_raw_images and not self.settings.topics
                and types == [IMAGE_TYPE] and graph.get(f'{name}/compressed') == [COMPRESSED_TYPE])

    def _drop_raw_images(self, graph: dict[str, list[str]]) -> None:
        """Unsubscribe the raw images whose compressed sibling appeared after them."""
        for name in [n for n in self._raw_images if self._skips_raw(n, [IMAGE_TYPE], graph)]:
            self.destroy_subscription(self._raw_images.pop(name))
            self.skipped_raw.add(name)
            self.get_logger().info(f'{name}: its compressed sibling appeared; recording '
                                   f'{name}/compressed from now on, not the raw image')

    def _discover(self) -> None:
        if self.writer is None or not self.recording:
            return
        local = self.link_bus.local_topics()
        graph = dict(self.get_topic_names_and_types())
        self._drop_raw_images(graph)
        for name, types in graph.items():
            with self._lock:
                if name in local or not self._wanted(name) or len(types) != 1:
                    continue
                if types[0] not in self._typestore.types:
                    continue
                if self._skips_raw(name, types, graph):
                    if name not in self.skipped_raw:
                        self.skipped_raw.add(name)
                        self.get_logger().info(f'{name}: recording {name}/compressed, not '
                                               'the raw image (skip_raw_images)')
                    continue
                self._subscribed.add(name)
            try:
                cls = message_class(types[0])
            except (ImportError, AttributeError, ValueError):
                continue
            offers = [qos_of(i.qos_profile) for i in self.get_publishers_info_by_topic(name)]
            r = adapt_request(offers)
            if name not in self._mixed_warned and offers and (
                    (not r.reliable and any(q.reliable for q in offers))
                    or (not r.transient_local and any(q.transient_local for q in offers))):
                self._mixed_warned.add(name)
                self.get_logger().warn(
                    f'{name}: its publishers offer different reliability or durability; '
                    'recorded best effort / volatile, which matches all of them (a latched '
                    'message published before now may be missing), as ros2 bag record does')
            self._offer(name, types[0], offers)
            put = self._put
            entry = (name, types[0], None)  # raw: the bytes as DDS carried them, exact
            callback = lambda data, e=entry: put((e, self._stamp(), data))  # noqa: E731
            if r.transient_local:
                with self._lock:
                    self._latched_waiting.add(name)
                callback = self._first_latched(name, callback)
            sub = self.create_subscription(cls, name, callback, request_profile(offers),
                                           raw=True)
            if types[0] == IMAGE_TYPE:
                self._raw_images[name] = sub
        self._warn_missing()

    def _first_latched(self, name: str, callback: Any) -> Any:
        """Wrap ``callback`` of latched topic ``name``: its arrival ends ``latched_pending``."""
        def on_message(data: Any) -> None:
            if name in self._latched_waiting:
                with self._lock:
                    self._latched_waiting.discard(name)
            callback(data)
        return on_message

    def latched_pending(self) -> list[str]:
        """List the latched topics subscribed whose first message has not arrived yet.

        A latched message published before the recorder subscribed comes by the middleware's
        late-joiner repair, some milliseconds of wall time later (Fast DDS: its first
        heartbeat); if the topic changes meanwhile, only the new value comes. A run on
        simulated time (``enbarr scenario``) waits for this before its clock moves. A topic
        whose publisher has published nothing yet stays listed.
        """
        with self._lock:
            return sorted(self._latched_waiting)

    def missing_topics(self) -> list[str]:
        """List the selected topics that have not appeared (none: all are recorded)."""
        with self._lock:
            return sorted(t for t in self.settings.topics if t not in self._subscribed)

    def _warn_missing(self) -> None:
        if (self._missing_warned or self._started_at is None
                or time.monotonic() - self._started_at < MISSING_WARN_SECONDS):
            return
        missing = self.missing_topics()
        if missing:
            self._missing_warned = True
            self.get_logger().warn(
                f'recording: no such topic after {MISSING_WARN_SECONDS:g} s: '
                f'{", ".join(missing)} (asked for with topics / --record-topic)')

    def still_receiving(self) -> bool:
        """Whether messages still come to it from other nodes.

        True when one came in the last ``QUIET_SECONDS`` or a topic it records has a
        publisher in another node: the graph may lose a publisher before its last messages
        are taken, and they count.
        """
        if time.monotonic() - self._last_received < QUIET_SECONDS:
            return True
        me = (self.get_name(), self.get_namespace())
        with self._lock:  # /tf and /tf_static are its own: a live frame publisher's do not count
            names = sorted(self._subscribed - {topics.TF_TOPIC, topics.TF_STATIC_TOPIC})
        return any((info.node_name, info.node_namespace) != me
                   for name in names for info in self.get_publishers_info_by_topic(name))

    def _write_loop(self) -> None:
        # Polled, not woken per message: a blocking get() wakes this thread (a futex and a
        # GIL hand-off against the chain's thread) for nearly every message, which costs the
        # writer more CPU per message than draining in batches (docs/benchmarks.md): every
        # DRAIN_SECONDS it takes what has come.
        # self.writer changes only here (``_close_bag``, ``_open_bag``): None while stopped.
        get = self._queue.get_nowait
        while True:
            try:
                item = get()
            except queue.Empty:
                if self.recording and self.writer is not None:
                    self._guarded(self.writer.maybe_flush)
                time.sleep(DRAIN_SECONDS)
                continue
            if item is _STOP:
                break
            writer = self.writer
            if self.recording:
                try:
                    if item[0] is None and item[1]:  # start or stop (``_lifecycle``)
                        item[2]()
                    elif writer is None:
                        continue  # stopped: a step is kept for the next bag (``_steps``)
                    elif item[0] is None:  # a step for the writer itself (``_control``)
                        item[2](writer)
                    else:
                        self._write(writer, item)
                except BagStorageError as err:
                    self._stop_recording(str(err))
                except RecorderError as err:  # one topic refused: the others go on
                    self.dropped += 1
                    self.get_logger().error(str(err), throttle_duration_sec=5.0)
                except Exception as err:  # noqa: BLE001 - recording must fail alone
                    self._stop_recording(f'{self.settings.path}: recording stopped by {err!r}')
        if self.recording and self.writer is not None:
            self._guarded(self.writer.close)

    def _write(self, writer: BagWriter, item: tuple[tuple[str, str, Any], int, Any]) -> None:
        (name, type_name, encode), stamp, msg = item
        if encode is not None:
            try:
                data, exact = encode(msg), True
            except Exception:  # noqa: BLE001 - a value the encoder did not foresee
                data, exact = serialize_message(msg), False
            if data is None:  # a derived message (/tf) that this one does not give
                return
        elif type(msg) is bytes:
            data, exact = msg, True  # from DDS: exactly the CDR
        else:
            data, exact = serialize_message(msg), False
        if writer.write(name, type_name, stamp, data, exact):
            self.written += 1

    def _guarded(self, step: Any) -> None:
        """Run one writer step; a storage failure (or anything unforeseen) stops recording.

        The writer thread never dies with a traceback: it stays to take ``_STOP``.
        """
        try:
            step()
        except BagStorageError as err:
            self._stop_recording(str(err))
        except Exception as err:  # noqa: BLE001 - recording must fail alone, never the run
            self._stop_recording(f'{self.settings.path}: recording stopped by {err!r}')

    def _stop_recording(self, why: str) -> None:
        """No more queueing; what is queued is let go; the fault fails the run at its end."""
        self.recording = False
        self.failure = why
        while True:
            try:
                if self._queue.get_nowait() is _STOP:
                    self._queue.put(_STOP)
                    break
            except queue.Empty:
                break
        if self.writer is not None and not self.writer.closed:
            try:
                self.writer.close()
            except RecorderError:
                pass  # already failing: the bag stays as last flushed
        self.report_problem(f'recording failed: {why}')
        try:
            self._report()
        except Exception as err:  # noqa: BLE001 - e.g. the context already shut down
            self.get_logger().warn(f'cannot publish the recorder status: {err!r}')

    def _report(self) -> None:
        try:
            free = f'{free_bytes(self.settings.path) / MB:.1f}'
        except OSError as err:
            free = f'unknown ({err.strerror})'
        try:
            free_b: int | str = free_bytes(self.bag)
        except OSError:
            free_b = 'unknown'
        active = self.recording and self._opened and not self.paused
        values = {'path': self.settings.path, 'written': self.written,
                  'dropped': self.dropped, 'overflow': self.overflow,
                  'queued': self._queue.qsize(), 'free_space': free,
                  'recording': 'true' if active else 'false', 'bag': str(self.bag),
                  'bag_bytes': bag_bytes(self.bag), 'free_bytes': free_b,
                  'last_control_refusal': self.last_control_refusal}
        overflowed, self._overflow_seen = self.overflow > self._overflow_seen, self.overflow
        if not self.recording:
            self.publish_diagnostics(2, f'not recording: {self.failure}', values)
        elif self.paused:
            self.publish_diagnostics(0, 'stopped (recorder/control)', values)
        elif overflowed:
            self.publish_diagnostics(1, 'recording, but the writer falls behind: messages '
                                     'dropped (overflow)', values)
        else:
            self.publish_diagnostics(0, 'recording', values)

    def close(self) -> None:
        """Write what is queued and close the bag (idempotent); name the topics never seen.

        A recorder that was never started has nothing to close and reports nothing.
        """
        if self._thread.is_alive():
            self._queue.put(_STOP)
            self._thread.join(10.0)
        if self._started_at is not None and self.recording:
            for topic in self.missing_topics():
                self.report_problem(f'recording: topic {topic} was asked for but never '
                                    'appeared; the bag has none of it')
            self._started_at = None

    def destroy_node(self) -> None:
        """Stop taking link-bus messages, write what is queued, close the bag."""
        self.link_bus.remove_tap(self._on_link_publisher)
        self.close()
        super().destroy_node()
