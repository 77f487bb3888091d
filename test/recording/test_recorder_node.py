"""The recorder node: what it records (link-bus topics, graph topics, a selection) and with
which QoS, the frame tree it writes (/tf_static, /tf), what it opens (nothing until it
starts), how it refuses a bad bag directory, names a topic that never came and reports a
full disk, and its typed settings.
"""

from __future__ import annotations

import errno
import math
import os
import time
from pathlib import Path
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import String
import yaml

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frames import ned_to_enu, parse_frames, Transform
from enbarr_core.framework.node import install_frame_tree
from enbarr_core.recording import recorder_node
from enbarr_core.recording.recorder import Recorder
from enbarr_core.recording.recorder_node import RecorderNode, RecorderSettings
from enbarr_core.recording.tf import read_transforms
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_interfaces.topics import TopicSpec
from support.bags import read_bag
from support.nodes import TIMEOUT, add, probe


def recorder(context: Any, executor: Any, bag: Path, *selected: str) -> RecorderNode:
    params = [Parameter('path', value=str(bag))]
    if selected:
        params.append(Parameter('topics', value=list(selected)))
    return add(executor, RecorderNode(context=context, parameter_overrides=params))


def close(executor: Any, rec: RecorderNode) -> dict[str, list[Any]]:
    """Take the recorder down (the bag is complete then) and read the bag back."""
    executor.remove_node(rec)
    rec.destroy_node()
    return read_bag(rec.settings.path)


def io_message() -> ParameterMsg:
    return ParameterMsg(name='gpio_12', value=convert.python_to_parameter_value(True))


def record_while_publishing(context: Any, executor: Any, spin: Any, rec: RecorderNode,
                            *specs: topics.TopicSpec, count: int = 3) -> None:
    """Publish on every topic of ``specs`` until the recorder wrote ``count`` messages."""
    source = probe(context, executor, 'source')
    pubs = [source.create_topic_publisher(s) for s in specs]
    LinkBus.of(context).connect()
    rec.start()

    def publish_and_check() -> bool:
        for pub in pubs:
            pub.publish(io_message())
        return rec.written >= count

    assert spin(executor, publish_and_check, TIMEOUT), f'{rec.written} written'


def test_records_a_fast_topic_from_the_link_bus(context, executor, spin, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag')
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE)
    msgs = close(executor, rec)
    assert len(msgs['/io_state']) >= 3
    assert msgs['/io_state'][0][1].name == 'gpio_12'


def test_records_a_topic_seen_in_the_graph(context, executor, spin, tmp_path) -> None:
    assert not topics.SURFACE_IO.fast  # travels over DDS, found by graph discovery
    rec = recorder(context, executor, tmp_path / 'bag')
    record_while_publishing(context, executor, spin, rec, topics.SURFACE_IO)
    msgs = close(executor, rec)
    assert len(msgs['/surface_command/io']) >= 3


def test_topics_selects_what_is_recorded(context, executor, spin, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag', '/io_state')
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE, topics.SURFACE_IO,
                            count=20)
    msgs = close(executor, rec)
    assert set(msgs) == {'/io_state'}


def test_settings_are_typed(context, executor, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag', '/io_state')
    assert rec.settings == RecorderSettings(path=str(tmp_path / 'bag'),
                                            topics=frozenset({'/io_state'}),
                                            flush_seconds=1.0)


def test_is_a_recorder_for_bringup(context, executor, tmp_path) -> None:
    assert isinstance(recorder(context, executor, tmp_path / 'bag'), Recorder)


def test_without_a_path_is_refused(context) -> None:
    with pytest.raises(ConfigurationError, match="node 'recorder': parameter path is not set"
                       ) as info:
        RecorderNode(context=context)
    assert info.value.parameter == 'path'


def test_a_bag_directory_in_use_is_refused(context, tmp_path) -> None:
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'other.txt').write_text('not ours')
    with pytest.raises(ConfigurationError, match="node 'recorder': ") as info:
        RecorderNode(context=context,
                     parameter_overrides=[Parameter('path', value=str(tmp_path / 'bag'))])
    assert info.value.parameter == 'path'


def test_empty_topic_names_mean_all() -> None:
    settings = RecorderSettings.from_params({'path': 'bag', 'topics': [''],
                                             'flush_seconds': 1.0, 'segment_seconds': 0.0,
                                             'split_size': 0.0, 'split_seconds': 0.0,
                                             'min_free_space': 64.0, 'max_queued': 20000,
                                             'skip_raw_images': True})
    assert settings.topics == frozenset()


def test_segment_seconds_is_the_old_name_of_flush_seconds() -> None:
    settings = RecorderSettings.from_params({'path': 'bag', 'topics': [],
                                             'flush_seconds': 1.0, 'segment_seconds': 0.25,
                                             'split_size': 0.0, 'split_seconds': 0.0,
                                             'min_free_space': 64.0, 'max_queued': 20000,
                                             'skip_raw_images': True})
    assert settings.flush_seconds == 0.25


def test_stamps_follow_the_node_clock_under_sim_time(context, executor, spin, tmp_path) -> None:
    """Receive stamps come from the node's clock: with use_sim_time and no /clock yet it
    reads 0 (the system clock would give ~1.7e18 ns), and back on the system clock after."""
    from rosbags.rosbag2 import Reader
    bag = tmp_path / 'bag'
    rec = add(executor, RecorderNode(context=context, parameter_overrides=[
        Parameter('path', value=str(bag)), Parameter('use_sim_time', value=True)]))
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE, count=3)
    rec.set_parameters([Parameter('use_sim_time', value=False)])
    before = rec.written
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE,
                            count=before + 3)
    close(executor, rec)
    with Reader(bag) as reader:
        stamps = [t for _, t, _ in reader.messages()]
    assert stamps[:3] == [0, 0, 0]
    assert stamps[-1] > 1_600_000_000 * 10 ** 9


# -- images: the JPEG by default, not the raw stream ---------------------------------------------

RAW = TopicSpec('cam/image_raw', Image, topics.SENSOR_QOS, '', '', '')
JPEG = TopicSpec('cam/image_raw/compressed', CompressedImage, topics.SENSOR_QOS, '', '', '')
LONE_RAW = TopicSpec('other/image_raw', Image, topics.SENSOR_QOS, '', '', '')


def record_images(context, executor, spin, rec, specs, until) -> dict[str, list[Any]]:
    source = probe(context, executor, 'source')
    pubs = [source.create_topic_publisher(s) for s in specs]
    rec.start()

    def publish() -> bool:
        for pub in pubs:
            pub.publish(pub.msg_type(format='bgr8; jpeg compressed bgr8', data=b'\xff\xd8')
                        if pub.msg_type is CompressedImage else
                        Image(height=1, width=1, encoding='bgr8', step=3, data=b'abc'))
        return until(rec)
    assert spin(executor, publish, TIMEOUT), f'{rec.written} written'
    return close(executor, rec)


def test_all_topics_leave_out_a_raw_image_that_has_a_compressed_sibling(
        context, executor, spin, tmp_path) -> None:
    """topics empty: /cam/image_raw/compressed and the lone /other/image_raw are recorded,
    not /cam/image_raw; skip_raw_images false, or a selection naming it, records it."""
    rec = recorder(context, executor, tmp_path / 'bag')
    msgs = record_images(context, executor, spin, rec, (RAW, JPEG, LONE_RAW),
                         lambda r: r.written >= 10 and r.skipped_raw)
    assert {'/cam/image_raw/compressed', '/other/image_raw'} <= set(msgs)
    assert '/cam/image_raw' not in msgs
    assert rec.skipped_raw == {'/cam/image_raw'}

    rec = add(executor, RecorderNode(context=context, parameter_overrides=[
        Parameter('path', value=str(tmp_path / 'both')),
        Parameter('skip_raw_images', value=False)]))
    msgs = record_images(context, executor, spin, rec, (RAW, JPEG),
                         lambda r: {'/cam/image_raw', '/cam/image_raw/compressed'}
                         <= r._subscribed and r.written >= 10)
    assert {'/cam/image_raw', '/cam/image_raw/compressed'} <= set(msgs)

    rec = recorder(context, executor, tmp_path / 'named', '/cam/image_raw')
    msgs = record_images(context, executor, spin, rec, (RAW, JPEG), lambda r: r.written >= 3)
    assert set(msgs) == {'/cam/image_raw'}


def test_a_raw_image_is_dropped_once_its_compressed_sibling_appears(
        context, executor, spin, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag')
    source = probe(context, executor, 'source')
    raw = source.create_topic_publisher(RAW)
    rec.start()
    image = Image(height=1, width=1, encoding='bgr8', step=3, data=b'abc')
    assert spin(executor, lambda: raw.publish(image) or rec.written >= 3, TIMEOUT)
    jpeg = source.create_topic_publisher(JPEG)
    assert spin(executor, lambda: raw.publish(image) or jpeg.publish(CompressedImage(
        format='bgr8; jpeg compressed bgr8', data=b'\xff\xd8')) or bool(rec.skipped_raw),
        TIMEOUT)
    dropped_at, before = time.time_ns(), rec.written  # the recorder's stamps: system time
    sent = [0]   # pairs published after the drop: the writes may still be the backlog's

    def more() -> bool:
        raw.publish(image)
        jpeg.publish(CompressedImage(format='bgr8; jpeg compressed bgr8', data=b'\xff\xd8'))
        sent[0] += 1
        return sent[0] >= 25 and rec.written >= before + 20

    assert spin(executor, more, TIMEOUT)
    msgs = close(executor, rec)
    assert len(msgs['/cam/image_raw']) >= 3
    assert len([t for t, _ in msgs['/cam/image_raw/compressed'] if t > dropped_at]) >= 15
    # nothing of the raw image after the drop (one in flight at most)
    assert len([t for t, _ in msgs['/cam/image_raw'] if t > dropped_at]) <= 1


# -- opens nothing until started ---------------------------------------------------------------

def test_constructing_the_recorder_creates_nothing(context, tmp_path) -> None:
    """bringup --check builds every node: the bag appears only when the recorder starts."""
    bag = tmp_path / 'bag'
    rec = RecorderNode(context=context, parameter_overrides=[Parameter('path', value=str(bag))])
    assert not bag.exists()
    rec.destroy_node()
    assert not bag.exists() and rec.problems == ()


# -- QoS as the publishers offer it (ros2 bag record's rule) -----------------------------------

LATCHED_TOPIC = TopicSpec('test/latched', String, topics.LATCHED_QOS, '', '', '')
RELIABLE_TOPIC = TopicSpec('test/reliable', String, topics.COMMAND_QOS, '', '', '')


def offered(bag: Path) -> dict[str, list[Any]]:
    with Reader(bag) as reader:
        return {c.topic: c.ext.offered_qos_profiles for c in reader.connections}


def test_a_latched_topic_published_before_the_start_is_recorded(context, executor, spin,
                                                                tmp_path) -> None:
    """Before the fix the recorder subscribed best effort and volatile: a state published
    once at start (mode 'manual', guidance/path_available) was missing from the bag."""
    source = probe(context, executor, 'source')
    pub = source.create_topic_publisher(LATCHED_TOPIC)
    pub.publish(String(data='manual'))  # once, before any recorder exists
    rec = recorder(context, executor, tmp_path / 'bag')
    rec.start()
    assert spin(executor, lambda: rec.written >= 1, TIMEOUT), 'the latched message never came'
    msgs = close(executor, rec)
    assert [m.data for _, m in msgs['/test/latched']] == ['manual']
    [qos] = offered(tmp_path / 'bag')['/test/latched']
    assert (qos.reliability, qos.durability) == (QosReliability.RELIABLE,
                                                 QosDurability.TRANSIENT_LOCAL)


def test_a_latched_topic_is_pending_until_its_first_message_came(context, executor, spin,
                                                                tmp_path) -> None:
    """What ``enbarr scenario`` waits for before its simulated clock moves: a latched message
    published before the recorder subscribed comes by the middleware's late-joiner repair,
    milliseconds later; a value published before then replaces it in the writer's history.
    At 30 times real time the scenarios' bags started without their initial mode
    (2026-11-27)."""
    from enbarr_core.tools.scenario import wait_for_latched
    source = probe(context, executor, 'source')
    pub = source.create_topic_publisher(LATCHED_TOPIC)
    pub.publish(String(data='manual'))
    rec = recorder(context, executor, tmp_path / 'bag', '/test/latched')
    rec.start()
    assert rec.latched_pending() == ['/test/latched']
    assert wait_for_latched([source, rec], lambda: executor.spin_once(timeout_sec=0.0),
                            timeout=TIMEOUT) == []
    pub.publish(String(data='automatic'))  # the mode changes at once
    assert spin(executor, lambda: rec.written >= 2, TIMEOUT), f'{rec.written} written'
    msgs = close(executor, rec)
    assert [m.data for _, m in msgs['/test/latched']] == ['manual', 'automatic']


def test_a_reliable_topic_is_subscribed_reliably(context, executor, spin, tmp_path) -> None:
    source = probe(context, executor, 'source')
    pub = source.create_topic_publisher(RELIABLE_TOPIC)
    rec = recorder(context, executor, tmp_path / 'bag')
    rec.start()

    def published_and_written() -> bool:
        pub.publish(String(data='x'))
        return rec.written >= 3
    assert spin(executor, published_and_written, TIMEOUT)
    [mine] = [i for i in source.get_subscriptions_info_by_topic('/test/reliable')
              if i.node_name == 'recorder']
    assert mine.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert mine.qos_profile.durability == DurabilityPolicy.VOLATILE
    close(executor, rec)
    [qos] = offered(tmp_path / 'bag')['/test/reliable']
    assert (qos.reliability, qos.durability) == (QosReliability.RELIABLE,
                                                 QosDurability.VOLATILE)


def test_mixed_offers_are_recorded_best_effort(context, executor, spin, tmp_path) -> None:
    a = probe(context, executor, 'a').create_publisher(String, '/test/mixed', 10)
    probe(context, executor, 'b').create_publisher(
        String, '/test/mixed', topics.SENSOR_QOS)  # best effort
    rec = recorder(context, executor, tmp_path / 'bag')
    rec.start()

    def published_and_written() -> bool:
        a.publish(String(data='x'))
        return rec.written >= 1
    assert spin(executor, published_and_written, TIMEOUT)
    [mine] = [i for i in rec.get_subscriptions_info_by_topic('/test/mixed')
              if i.node_name == 'recorder']
    assert mine.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    close(executor, rec)
    assert len(offered(tmp_path / 'bag')['/test/mixed']) == 2


# -- the frame tree: /tf_static and /tf ---------------------------------------------------------

TREE = {'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'observer/odometry'},
        'laser': {'parent': 'base_link', 'xyz': [0.0, 0.0, 0.15]},
        'camera_link': {'parent': 'base_link', 'xyz': [-0.08, 0.0, 0.25]},
        'camera_optical_frame': {'parent': 'camera_link',
                                 'rpy': [-math.pi / 2, 0.0, -math.pi / 2]}}


def raw_topic(bag: Path, topic: str) -> list[tuple[int, bytes]]:
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [(t, raw) for _, t, raw in reader.messages(connections=conns)]


def test_the_frame_tree_and_the_estimate_are_in_the_bag(context, executor, spin,
                                                        tmp_path) -> None:
    """/tf_static from the tree, /tf from observer/odometry; composed from the bag alone:
    the manual's pose [N 2, E 1, psi 30 deg] puts a return 1 m ahead of the lidar at
    E 1.5, N 2 + sin 60 deg, 0.15 m up (worked by hand)."""
    install_frame_tree(context, parse_frames(TREE))
    source = probe(context, executor, 'source')
    odom_pub = source.create_topic_publisher(topics.OBSERVER_ODOMETRY)
    rec = recorder(context, executor, tmp_path / 'bag')
    LinkBus.of(context).connect()
    rec.start()
    msg = Odometry()
    msg.header.frame_id, msg.child_frame_id = 'odom', 'base_link'
    convert.set_pose_eta(msg.pose.pose, ned_to_enu([2.0, 1.0, math.radians(30.0)]))

    def publish() -> bool:
        convert.ns_to_stamp(rec.now_ns(), msg.header.stamp)
        odom_pub.publish(msg)
        return rec.written >= 5
    assert spin(executor, publish, TIMEOUT)
    close(executor, rec)
    bag = tmp_path / 'bag'
    static = read_transforms(raw_topic(bag, '/tf_static'))
    assert {(s.parent, s.child) for s in static} == {
        ('base_link', 'laser'), ('base_link', 'camera_link'),
        ('camera_link', 'camera_optical_frame')}
    dynamic = read_transforms(raw_topic(bag, '/tf'))
    assert len(dynamic) >= 4 and {(s.parent, s.child) for s in dynamic} == {
        ('odom', 'base_link')}
    t = dynamic[-1].transform
    assert t.is_close(Transform((1.0, 2.0, 0.0), (0.0, 0.0, 0.5, math.sqrt(0.75))))
    laser = next(s.transform for s in static if s.child == 'laser')
    assert np.allclose((t @ laser).apply([1.0, 0.0, 0.0]),
                       [1.5, 2.0 + math.sin(math.radians(60.0)), 0.15])
    with Reader(bag) as reader:  # /tf_static is the first message of the file
        first = next(iter(reader.messages()))[0].topic
        assert first == '/tf_static'
    [qos] = offered(bag)['/tf_static']
    assert qos.durability == QosDurability.TRANSIENT_LOCAL


def test_a_selection_without_the_frames_leaves_them_out(context, executor, spin,
                                                        tmp_path) -> None:
    install_frame_tree(context, parse_frames(TREE))
    rec = recorder(context, executor, tmp_path / 'bag', '/io_state')
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE)
    assert set(close(executor, rec)) == {'/io_state'}


# -- a topic asked for that never comes; a full disk --------------------------------------------

def test_a_topic_that_never_appeared_is_a_problem(context, executor, spin, tmp_path,
                                                  monkeypatch) -> None:
    """Before the fix: an empty bag directory and exit 0 without a word."""
    monkeypatch.setattr(recorder_node, 'MISSING_WARN_SECONDS', 0.0)
    rec = recorder(context, executor, tmp_path / 'bag', '/nonexistent')
    warnings: list[str] = []
    monkeypatch.setattr(rec.get_logger(), 'warn', lambda m, **kw: warnings.append(m))
    rec.start()
    assert spin(executor, lambda: bool(warnings), TIMEOUT)
    assert warnings == ['recording: no such topic after 0 s: /nonexistent (asked for with '
                        'topics / --record-topic)']
    assert rec.problems == ()  # not yet: it may still come
    executor.remove_node(rec)
    rec.destroy_node()
    assert rec.problems == ('recording: topic /nonexistent was asked for but never appeared; '
                            'the bag has none of it',)
    assert yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['message_count'] == 0


def test_a_full_disk_is_reported_at_once(context, executor, spin, tmp_path,
                                         monkeypatch) -> None:
    """Injected at os.pwritev (the flush's one write): no tmpfs, no minute-long spin."""
    rec = recorder(context, executor, tmp_path / 'bag')

    def enospc(fd: int, parts: Any, at: int) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, 'pwritev', enospc)
    source = probe(context, executor, 'source')
    pub = source.create_topic_publisher(topics.IO_STATE)
    LinkBus.of(context).connect()
    rec.start()

    def publish() -> bool:
        pub.publish(io_message())
        return bool(rec.problems)
    assert spin(executor, publish, TIMEOUT), f'{rec.written} written, no problem'
    [problem] = rec.problems
    assert problem.startswith(f'recording failed: {tmp_path / "bag"}: cannot write bag_0.mcap')
    assert 'No space left on device' in problem and not rec.recording
