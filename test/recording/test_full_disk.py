"""Recording to a full disk, on a real tmpfs (``small_disk``).

The bag writer: a full disk is a ``BagStorageError`` (never a bare ``OSError``), the bag stays
readable up to its last flush by the project's reader, ``rosbags`` and ``mcap``; the margin
refuses a start and stops a run. The recorder node: it reports the failure (problem,
/diagnostics ERROR), stops queueing, and its queue is bounded even while the writer is slow.
"""

from __future__ import annotations

from pathlib import Path
import threading
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Imu

from enbarr_core.framework.errors import ConfigurationError, RecorderError
from enbarr_core.recording.bag import BagStorageError, BagWriter
from enbarr_core.recording.recorder_node import RecorderNode
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from recording.small_disk import fill, small_disk
from support.bags import mcap_messages, metadata, read_bag
from support.nodes import TIMEOUT, add, probe

IMU = serialize_message(Imu())
MB = 1_000_000


def readable(bag: Path) -> int:
    """Read ``bag`` with all three readers, check that they agree; its message count."""
    info = metadata(bag)
    assert sorted(p.name for p in bag.iterdir()) == sorted(
        ['metadata.yaml', *info['relative_file_paths']])
    with Reader(bag) as reader:
        by_rosbags = sum(1 for _ in reader.messages())
        assert reader.message_count == by_rosbags == info['message_count']
    assert sum(len(v) for v in read_bag(bag).values()) == by_rosbags
    assert len(mcap_messages(bag)) == by_rosbags
    return by_rosbags


@pytest.mark.e2e  # a holder process owns the tmpfs
def test_a_full_disk_is_a_storage_error_and_the_bag_reads_to_its_last_flush(
        tmp_path: Path) -> None:
    with small_disk(tmp_path, '1m') as disk:
        writer = BagWriter(disk / 'bag', flush_seconds=3600.0)
        flushed = 0
        with pytest.raises(BagStorageError, match='No space left on device') as info:
            for i in range(1_000_000):
                writer.write('/imu', 'sensor_msgs/msg/Imu', i, IMU)
                if i % 200 == 199:
                    writer.flush()
                    flushed = i + 1
        assert str(disk / 'bag') in str(info.value)
        assert flushed > 0
        assert readable(disk / 'bag') == flushed
        with pytest.raises(BagStorageError):  # stopped for good
            writer.write('/imu', 'sensor_msgs/msg/Imu', 0, IMU)
        writer.close()  # no error: the bag is as last flushed
        assert readable(disk / 'bag') == flushed


@pytest.mark.e2e
def test_a_disk_that_fills_before_a_flush_loses_only_what_was_not_flushed(
        tmp_path: Path) -> None:
    with small_disk(tmp_path, '1m') as disk:
        writer = BagWriter(disk / 'bag', flush_seconds=3600.0)
        for i in range(100):
            writer.write('/imu', 'sensor_msgs/msg/Imu', i, IMU)
        writer.flush()
        with pytest.raises(BagStorageError, match=r'cannot write bag_0\.mcap: No space left on '
                                                  r'device; recording stopped'):
            for i in range(100, 1_000_000):  # no explicit flush: full chunks are written
                writer.write('/imu', 'sensor_msgs/msg/Imu', i, IMU)
        assert readable(disk / 'bag') >= 100  # up to the last chunk written whole
        writer.close()


@pytest.mark.e2e
def test_too_little_free_space_refuses_to_start(tmp_path: Path) -> None:
    with small_disk(tmp_path, '2m') as disk:
        with pytest.raises(RecorderError,
                           match=r'/bag: 2\.1 MB free, less than the 3 MB margin '
                                 r'\(min_free_space\); recording refused'):
            BagWriter(disk / 'bag', min_free=3 * MB)
        assert not (disk / 'bag').exists()


@pytest.mark.e2e
def test_the_margin_stops_a_run_with_the_bag_closed(tmp_path: Path) -> None:
    with small_disk(tmp_path, '8m') as disk:
        writer = BagWriter(disk / 'bag', flush_seconds=3600.0, min_free=2 * MB)
        for i in range(100):
            writer.write('/imu', 'sensor_msgs/msg/Imu', i, IMU)
        writer.flush()
        fill(disk, leave=MB)  # another program takes the space
        with pytest.raises(BagStorageError, match=r'less than the 2 MB margin .*stopped'):
            writer.write('/imu', 'sensor_msgs/msg/Imu', 100, IMU)
        assert readable(disk / 'bag') == 100


# -- the node -------------------------------------------------------------------------------

def recorder(context: Any, executor: Any, bag: Path, **params: Any) -> RecorderNode:
    overrides = [Parameter('path', value=str(bag)), Parameter('flush_seconds', value=0.05),
                 *(Parameter(k, value=v) for k, v in params.items())]
    return add(executor, RecorderNode(context=context, parameter_overrides=overrides))


def diagnostics_of(context: Any, executor: Any) -> list[Any]:
    seen: list[Any] = []
    listener = probe(context, executor, 'listener')
    listener.create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS.name,
        lambda m: seen.extend(s for s in m.status if s.hardware_id == 'recorder'),
        topics.DIAGNOSTICS.qos)
    return seen


def test_a_full_disk_is_reported_and_nothing_more_is_queued(context, executor, spin,
                                                            tmp_path) -> None:
    with small_disk(tmp_path, '2m') as disk:
        rec = recorder(context, executor, disk / 'bag', min_free_space=0.0)
        seen = diagnostics_of(context, executor)
        pub = probe(context, executor, 'source').create_topic_publisher(topics.THRUSTER_OUTPUT)
        LinkBus.of(context).connect()
        rec.start()
        msg = topics.THRUSTER_OUTPUT.msg_type(name=[f't{i}' for i in range(8)],
                                              effort=[0.5] * 8)

        def publish() -> bool:
            for _ in range(200):
                pub.publish(msg)
            return bool(rec.problems)

        # before the fix: the writer thread died with OSError, no problem was ever reported
        assert spin(executor, publish, 60.0), f'no problem reported; {rec.written} written'
        [problem] = rec.problems
        assert problem.startswith(f'recording failed: {disk / "bag"}: cannot ')
        assert 'No space left on device' in problem
        assert spin(executor, lambda: any(s.level == b'\x02' for s in seen), TIMEOUT)
        error = next(s for s in seen if s.level == b'\x02')
        assert error.message.startswith('not recording: ')
        for _ in range(5000):  # the chain goes on publishing: nothing is kept for the bag
            pub.publish(msg)
        assert rec._queue.qsize() == 0
        rec.close()
        assert readable(disk / 'bag') > 0


def test_too_little_free_space_refuses_the_node(context, tmp_path) -> None:
    with small_disk(tmp_path, '2m') as disk:
        with pytest.raises(ConfigurationError,
                           match=r"node 'recorder': .*/bag: 2\.1 MB free, less than the 64 MB "
                                 r'margin \(min_free_space\); recording refused') as info:
            RecorderNode(context=context,
                         parameter_overrides=[Parameter('path', value=str(disk / 'bag'))])
        assert info.value.parameter == 'path'


def test_the_queue_is_bounded_while_the_writer_is_slow(context, executor, spin,
                                                       tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag', max_queued=100)
    seen = diagnostics_of(context, executor)
    release = threading.Event()
    pub = probe(context, executor, 'source').create_topic_publisher(topics.THRUSTER_OUTPUT)
    LinkBus.of(context).connect()
    rec.start()  # the bag opens here
    slow_write = rec.writer.write

    def stuck(*args: Any) -> bool:
        release.wait(TIMEOUT)
        return slow_write(*args)

    rec.writer.write = stuck  # a disk that hangs (NFS, a dying SD card)
    msg = topics.THRUSTER_OUTPUT.msg_type(name=['t0'], effort=[0.0])
    for _ in range(1000):
        pub.publish(msg)
    # before the fix: all 1000 queued (the queue had no bound)
    assert rec._queue.qsize() <= 100
    assert rec.overflow >= 899
    assert spin(executor, lambda: any(s.level == b'\x01' for s in seen), TIMEOUT)
    release.set()
    rec.close()
    assert rec.recording and not rec.problems
    assert 1 <= readable(tmp_path / 'bag') <= 101
