"""What the recorder writes besides the messages it takes (pure, unit tier): ``/tf`` and
``/tf_static`` serialized without tf2_msgs, the offered QoS as rosbag2 stores it, latched
topics repeated at the start of every file of a split bag, and the storage faults a
full disk or a short ``pwritev`` cause, injected at ``os.pwritev``.
"""

from __future__ import annotations

import errno
import math
import os
from pathlib import Path
import struct
from typing import Any

from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
from sensor_msgs.msg import Imu
from std_msgs.msg import String

from enbarr_core.framework.frames import parse_frames, StampedTransform, Transform
from enbarr_core.recording.bag import BagStorageError, BagWriter, repair_bag
from enbarr_core.recording.qos import adapt_request, offered_qos_yaml, Qos, TF_STATIC_QOS
from enbarr_core.recording.tf import decode_transforms, tf_message_cdr, TF_MESSAGE
from support.bags import metadata

T0 = 1_700_000_000_000_000_000
IMU = serialize_message(Imu())
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def by_file(bag: Path) -> list[list[tuple[str, int]]]:
    """(topic, log time) of every message, file by file, in file order (the mcap reader)."""
    out = []
    for name in metadata(bag)['relative_file_paths']:
        with open(bag / name, 'rb') as f:
            out.append([(ch.topic, m.log_time) for _, ch, m in
                        make_reader(f).iter_messages(log_time_order=False)])
    return out


# -- TFMessage -------------------------------------------------------------------------------

def test_a_tf_message_is_the_cdr_the_spec_lays_out() -> None:
    """One TransformStamped, laid out by hand from the CDR rules (little endian, each
    primitive aligned to its size from the end of the 4-byte encapsulation header)."""
    data = tf_message_cdr([StampedTransform(
        3 * 1_000_000_000 + 7, 'odom', 'base_link',
        Transform((1.0, 2.0, 0.0), (0.0, 0.0, 0.5, math.sqrt(0.75))))])
    body = bytearray()
    body += struct.pack('<I', 1)                                    # transforms: 1
    body += struct.pack('<iI', 3, 7)                                # stamp sec, nanosec
    body += struct.pack('<I', 5) + b'odom\0'                        # frame_id
    body += b'\0' * (-len(body) % 4)
    body += struct.pack('<I', 10) + b'base_link\0'                  # child_frame_id
    body += b'\0' * (-len(body) % 8)                                # float64 alignment
    body += struct.pack('<7d', 1.0, 2.0, 0.0, 0.0, 0.0, 0.5, math.sqrt(0.75))
    assert data == b'\x00\x01\x00\x00' + bytes(body)


def test_the_packer_agrees_with_rosbags_serializer() -> None:
    """A second formulation: rosbags' own CDR serializer, on random names and poses."""
    rng = np.random.default_rng(5)
    t = TYPESTORE.types
    for n in range(6):
        transforms = [StampedTransform(
            int(rng.integers(0, 2 ** 31 * 10 ** 9)), 'p' * int(rng.integers(0, 9)),
            'c' * int(rng.integers(1, 12)),
            Transform(tuple(rng.normal(size=3)), tuple(rng.normal(size=4))))
            for _ in range(n)]
        msg = t[TF_MESSAGE](transforms=[t['geometry_msgs/msg/TransformStamped'](
            header=t['std_msgs/msg/Header'](
                stamp=t['builtin_interfaces/msg/Time'](sec=s.stamp_ns // 10 ** 9,
                                                       nanosec=s.stamp_ns % 10 ** 9),
                frame_id=s.parent),
            child_frame_id=s.child,
            transform=t['geometry_msgs/msg/Transform'](
                translation=t['geometry_msgs/msg/Vector3'](*s.transform.translation),
                rotation=t['geometry_msgs/msg/Quaternion'](*s.transform.rotation)))
            for s in transforms])
        assert tf_message_cdr(transforms) == bytes(TYPESTORE.serialize_cdr(msg, TF_MESSAGE))


def test_a_tf_message_decodes_with_the_mcap_ros2_decoder() -> None:
    msgdef, _ = TYPESTORE.generate_msgdef(TF_MESSAGE, ros_version=2)
    tree = parse_frames({'base_link': {}, 'laser': {'parent': 'base_link',
                                                    'xyz': [0.1, 0.0, 0.15],
                                                    'rpy': [0.0, 0.0, 0.3]}})
    data = tf_message_cdr(tree.static_transforms(T0))
    decode = DecoderFactory().decoder_for('cdr', Schema(id=1, name=TF_MESSAGE,
                                                        encoding='ros2msg',
                                                        data=msgdef.encode()))
    msg = decode(data)
    [t] = msg.transforms
    assert (t.header.frame_id, t.child_frame_id) == ('base_link', 'laser')
    assert (t.header.stamp.sec, t.header.stamp.nanosec) == divmod(T0, 1_000_000_000)
    assert np.allclose([t.transform.translation.x, t.transform.translation.z], [0.1, 0.15])
    assert math.isclose(t.transform.rotation.z, math.sin(0.15))
    [back] = decode_transforms(data)
    assert back.transform.is_close(tree.frames['laser'].transform)


# -- QoS as rosbag2 ------------------------------------------------------------------------------

@pytest.mark.parametrize('offers, reliable, latched', [
    ([], False, False),
    ([Qos(reliability='reliable')], True, False),
    ([Qos(reliability='reliable'), Qos(reliability='best_effort')], False, False),
    ([TF_STATIC_QOS], True, True),
    ([TF_STATIC_QOS, Qos(reliability='reliable', durability='volatile')], True, False),
])
def test_the_request_matches_every_offer(offers: list[Qos], reliable: bool,
                                         latched: bool) -> None:
    r = adapt_request(offers)
    assert (r.reliable, r.transient_local) == (reliable, latched)


def test_offered_qos_is_written_as_rosbag2_writes_it() -> None:
    """Bag version 9 (Jazzy): policies by rmw's names, durations as sec/nsec; the keys in
    rosbag2_storage's order (qos.cpp, convert<Rosbag2QoS>::encode)."""
    text = offered_qos_yaml([Qos(history='unknown', depth=0, reliability='reliable',
                                 durability='transient_local', deadline_ns=2 ** 63 - 1,
                                 lifespan_ns=2 ** 63 - 1, liveliness='automatic',
                                 liveliness_lease_ns=2 ** 63 - 1)])
    assert text == (
        '- history: unknown\n  depth: 0\n  reliability: reliable\n'
        '  durability: transient_local\n  deadline:\n    sec: 9223372036\n'
        '    nsec: 854775807\n  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n'
        '  liveliness: automatic\n  liveliness_lease_duration:\n    sec: 9223372036\n'
        '    nsec: 854775807\n  avoid_ros_namespace_conventions: false\n')
    assert offered_qos_yaml([]) == ''


def test_the_offered_qos_reaches_metadata_channels_and_a_repair(tmp_path: Path) -> None:
    bag = tmp_path / 'qos'
    writer = BagWriter(bag, flush_seconds=3600.0)
    writer.set_offered_qos('/mode', offered_qos_yaml([TF_STATIC_QOS]))
    assert writer.write('/mode', 'std_msgs/msg/String', T0, serialize_message(String()))
    assert writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + 1, IMU)
    writer.close()

    def check() -> None:
        with Reader(bag) as reader:
            qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        [mode] = qos['/mode']
        assert (mode.reliability, mode.durability, mode.history.name) == (
            QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, 'KEEP_LAST')
        assert qos['/imu'] == []
        with open(bag / 'qos_0.mcap', 'rb') as f:
            channels = make_reader(f).get_summary().channels.values()
        assert {c.topic: c.metadata['offered_qos_profiles'] for c in channels} == {
            '/mode': offered_qos_yaml([TF_STATIC_QOS]), '/imu': ''}

    check()
    (bag / 'metadata.yaml').unlink()
    repair_bag(bag)  # metadata.yaml rebuilt from the files: the QoS from the channels
    check()


# -- latched topics ----------------------------------------------------------------------------

def test_latched_messages_open_every_file_of_a_split_bag(tmp_path: Path) -> None:
    bag = tmp_path / 'split'
    writer = BagWriter(bag, flush_seconds=3600.0, split_seconds=1.0)
    static = tf_message_cdr([StampedTransform(T0, 'base_link', 'laser', Transform())])
    writer.latch('/tf_static', TF_MESSAGE, messages=((T0 + 5, static),))
    writer.latch('/mode', 'std_msgs/msg/String')
    writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + 10, IMU)
    writer.write('/mode', 'std_msgs/msg/String', T0 + 20, serialize_message(String(data='a')))
    for k in range(1, 4):  # a new file every second of message time
        writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + k * 1_000_000_000 + 10, IMU)
    writer.close()
    files = by_file(bag)
    assert len(files) == 4
    # the first file opens at its first message: /tf_static first, at that message's time
    assert files[0] == [('/tf_static', T0 + 10), ('/imu', T0 + 10), ('/mode', T0 + 20)]
    for k, f in enumerate(files[1:], start=1):
        t = T0 + k * 1_000_000_000 + 10
        assert f == [('/tf_static', t), ('/mode', t), ('/imu', t)]
    with Reader(bag) as reader:  # every file stands alone, and the bag reads as one
        assert reader.message_count == 3 + 3 * 3


def test_latched_while_a_file_is_open_goes_in_at_once(tmp_path: Path) -> None:
    bag = tmp_path / 'late'
    writer = BagWriter(bag, flush_seconds=3600.0, split_seconds=1.0)
    writer.write('/imu', 'sensor_msgs/msg/Imu', T0, IMU)
    static = tf_message_cdr([StampedTransform(T0, 'base_link', 'laser', Transform())])
    writer.latch('/tf_static', TF_MESSAGE, messages=((T0 + 1, static),))
    writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + 2_000_000_000, IMU)  # a second file
    writer.close()
    assert by_file(bag) == [[('/imu', T0), ('/tf_static', T0 + 1)],
                            [('/tf_static', T0 + 2_000_000_000), ('/imu', T0 + 2_000_000_000)]]


def test_a_bag_with_nothing_but_latched_messages_keeps_them(tmp_path: Path) -> None:
    bag = tmp_path / 'quiet'
    writer = BagWriter(bag)
    static = tf_message_cdr([StampedTransform(T0, 'base_link', 'laser', Transform())])
    writer.latch('/tf_static', TF_MESSAGE, messages=((T0, static),))
    writer.close()
    assert by_file(bag) == [[('/tf_static', T0)]]


def test_an_empty_bag_still_gets_its_metadata(tmp_path: Path) -> None:
    bag = tmp_path / 'empty'
    BagWriter(bag).close()
    assert metadata(bag)['message_count'] == 0
    with Reader(bag) as reader:
        assert reader.message_count == 0


def test_a_bag_path_is_checked_without_creating_anything(tmp_path: Path) -> None:
    from enbarr_core.framework.errors import RecorderError
    from enbarr_core.recording.bag import check_bag_path
    check_bag_path(tmp_path / 'a' / 'b' / 'bag')
    assert list(tmp_path.iterdir()) == []
    (tmp_path / 'file').write_text('x')
    with pytest.raises(RecorderError, match=r'file/sub/bag: cannot create the bag directory: '
                                            r'\S+/file is not a directory'):
        check_bag_path(tmp_path / 'file' / 'sub' / 'bag')
    with pytest.raises(RecorderError, match='exists and is not an empty directory'):
        check_bag_path(tmp_path / 'file')


def test_a_latched_message_of_another_definition_is_refused(tmp_path: Path) -> None:
    from enbarr_core.framework.errors import RecorderError
    writer = BagWriter(tmp_path / 'bad')
    with pytest.raises(RecorderError, match='are not a CDR tf2_msgs/msg/TFMessage'):
        writer.latch('/tf_static', TF_MESSAGE, messages=((T0, b'\x00\x01\x00\x00\x07'),))
    writer.close()


# -- storage faults, injected at os.pwritev ------------------------------------------------------

def test_a_short_pwritev_is_completed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The kernel may write less than asked (a signal, a nearly full disk): the rest follows."""
    real = os.pwritev
    shorts = []

    def short(fd: int, parts: list[Any], at: int) -> int:
        blob = b''.join(bytes(p) for p in parts)
        n = max(1, len(blob) // 3)
        shorts.append(n)
        return os.pwrite(fd, blob[:n], at)

    bag = tmp_path / 'short'
    writer = BagWriter(bag, flush_seconds=3600.0)
    monkeypatch.setattr(os, 'pwritev', short)
    for k in range(50):
        writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + k, IMU)
        if k % 10 == 9:
            writer.flush()
    monkeypatch.setattr(os, 'pwritev', real)
    writer.close()
    assert len(shorts) == 5
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + k for k in range(50)]
    with open(bag / 'short_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == 50
        assert sum(1 for _ in reader.iter_decoded_messages()) == 50


def test_a_full_disk_stops_the_writer_at_once_with_the_bag_as_last_flushed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    bag = tmp_path / 'full'
    writer = BagWriter(bag, flush_seconds=3600.0)
    for k in range(10):
        writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + k, IMU)
    writer.flush()

    def enospc(fd: int, parts: list[Any], at: int) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, 'pwritev', enospc)
    for k in range(10, 15):
        writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + k, IMU)
    with pytest.raises(BagStorageError, match=r'full/?: cannot write full_0\.mcap: No space '
                                              r'left on device; recording stopped'):
        writer.flush()
    with pytest.raises(BagStorageError):
        writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + 99, IMU)
    writer.close()
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + k for k in range(10)]
