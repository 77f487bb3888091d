"""BagWriter (enbarr_core.recording.bag): a rosbag2 MCAP bag that survives being killed.

One MCAP file per run (more only when asked to split), complete after every flush; a kill
at any instant leaves it readable up to its last flush, after ``repair_bag`` when the kill
tore the tail being rewritten.

Payloads come from rclpy's ``serialize_message`` as in the recorder; the bags are read back
with three independent readers: ``rosbags`` (the whole bag through ``metadata.yaml``), the
``mcap`` reader with the ROS 2 decoder (file by file) and rclpy's ``deserialize_message``.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
import signal
import subprocess
import sys
import textwrap
import time
from types import SimpleNamespace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import WrenchStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Header

from enbarr_core.framework.errors import RecorderError
from enbarr_core.guidance.guidance import Reference
from enbarr_core.guidance.guidance_node import msg_to_reference, reference_to_msg
from enbarr_core.recording.bag import BagWriter
from enbarr_interfaces import convert, topics
from support.bags import mcap_messages, metadata

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
T0 = 1_700_000_000_000_000_000  # ns
CLASSES = {'sensor_msgs/msg/Imu': Imu, 'sensor_msgs/msg/JointState': JointState,
           'rcl_interfaces/msg/Parameter': Parameter,
           'geometry_msgs/msg/WrenchStamped': WrenchStamped}


def stamp(msg: Any, t: int) -> Any:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
    msg.header.frame_id = 'base_link'
    return msg


def make_messages(i: int, t: int) -> list[tuple[str, str, Any]]:
    """One of each type, with contents that depend on ``i``."""
    imu = stamp(Imu(), t)
    imu.orientation.w = 1.0
    imu.angular_velocity.z = 0.01 * i
    imu.linear_acceleration.x = float(i)
    imu.orientation_covariance[0] = -1.0
    joints = stamp(JointState(), t)
    joints.name = [f'joint_{k}' for k in range(1 + i % 4)]  # string sequence: trailing bytes
    joints.position = [0.5 * k + i for k in range(len(joints.name))]
    param = Parameter(name=f'kp_{i}', value=ParameterValue(
        type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=['a', 'bb' * i, 'ccc']))
    wrench = stamp(WrenchStamped(), t)
    wrench.wrench.force.x = -float(i)
    wrench.wrench.torque.z = 0.25 * i
    return [('/imu/data', 'sensor_msgs/msg/Imu', imu),
            ('/joint_states', 'sensor_msgs/msg/JointState', joints),
            ('/parameter_events_like', 'rcl_interfaces/msg/Parameter', param),
            ('/control/wrench', 'geometry_msgs/msg/WrenchStamped', wrench)]


def write_bag(bag: Path, batches: int = 3, per_batch: int = 5) -> list[tuple[str, int, Any]]:
    """Three batches, each ended by an explicit flush; returns (topic, time, message)."""
    writer = BagWriter(bag, flush_seconds=3600.0)
    written = []
    for b in range(batches):
        for k in range(per_batch):
            i = b * per_batch + k
            for j, (topic, msgtype, msg) in enumerate(make_messages(i, T0 + i * 10_000_000)):
                t = T0 + i * 10_000_000 + j  # distinct, increasing receive times
                assert writer.write(topic, msgtype, t, serialize_message(msg))
                written.append((topic, t, msg))
        writer.flush()
    writer.close()
    return written


@dataclass(frozen=True)
class Written:
    """A bag of three flushes, what went into it, and its metadata."""

    bag: Path
    messages: list[tuple[str, int, Any]]  # (topic, receive time, message)
    info: dict[str, Any]


@pytest.fixture(scope='module')
def written(tmp_path_factory: pytest.TempPathFactory) -> Written:
    bag = tmp_path_factory.mktemp('bag') / 'run'
    messages = write_bag(bag)
    return Written(bag, messages, metadata(bag))


def test_a_run_is_one_mcap_file(written: Written) -> None:
    info = written.info
    assert info['relative_file_paths'] == ['run_0.mcap']
    assert info['storage_identifier'] == 'mcap'


def test_metadata_counts_messages_per_file_and_topic(written: Written) -> None:
    info = written.info
    assert info['message_count'] == len(written.messages) == 60
    assert [f['message_count'] for f in info['files']] == [60]
    counts = {tm['topic_metadata']['name']: tm['message_count']
              for tm in info['topics_with_message_count']}
    assert counts == {'/imu/data': 15, '/joint_states': 15, '/parameter_events_like': 15,
                      '/control/wrench': 15}


def test_metadata_start_and_duration(written: Written) -> None:
    info, messages = written.info, written.messages
    assert info['starting_time']['nanoseconds_since_epoch'] == messages[0][1]
    assert info['duration']['nanoseconds'] == messages[-1][1] - messages[0][1]


def test_nothing_else_is_left(written: Written) -> None:
    assert sorted(p.name for p in written.bag.iterdir()) == ['metadata.yaml', 'run_0.mcap']


def test_each_flush_is_a_chunk_of_the_one_file(written: Written) -> None:
    with open(written.bag / 'run_0.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert len(summary.chunk_indexes) == summary.statistics.chunk_count == 3
    assert summary.statistics.message_count == 60


def rosbags_read(bag: Path) -> tuple[int, dict[str, str], list[tuple[str, int, str, Any]]]:
    """rosbags' view of the whole bag: message count, topic types, messages in time order."""
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        read = [(c.topic, t, c.msgtype, raw) for c, t, raw in reader.messages()]
        return reader.message_count, types, read


def test_rosbags_reads_the_whole_bag_in_time_order(written: Written) -> None:
    count, types, read = rosbags_read(written.bag)
    assert count == 60
    assert types == {'/imu/data': 'sensor_msgs/msg/Imu',
                     '/joint_states': 'sensor_msgs/msg/JointState',
                     '/parameter_events_like': 'rcl_interfaces/msg/Parameter',
                     '/control/wrench': 'geometry_msgs/msg/WrenchStamped'}
    assert [(topic, t) for topic, t, _, _ in read] == [
        (topic, t) for topic, t, _ in written.messages]


def test_payloads_decode_to_what_was_written(written: Written) -> None:
    _, _, read = rosbags_read(written.bag)
    for (topic, t, msgtype, raw), (_, _, original) in zip(read, written.messages):
        assert deserialize_message(bytes(raw), CLASSES[msgtype]) == original
        decoded = TYPESTORE.deserialize_cdr(raw, msgtype)  # exact size: must not raise
        if msgtype == 'sensor_msgs/msg/JointState':
            assert list(decoded.name) == list(original.name)
            assert list(decoded.position) == list(original.position)
        elif msgtype == 'rcl_interfaces/msg/Parameter':
            assert decoded.name == original.name
            assert list(decoded.value.string_array_value) == list(
                original.value.string_array_value)
        elif msgtype == 'sensor_msgs/msg/Imu':
            assert decoded.linear_acceleration.x == original.linear_acceleration.x
        else:
            assert decoded.wrench.torque.z == original.wrench.torque.z


def mcap_read(written: Written) -> list[tuple[str, int, Any]]:
    """Each file read on its own by the mcap reader: complete (summary, statistics) and
    agreeing with the metadata; returns the decoded messages of all files in order.
    """
    by_file = []
    for name, finfo in zip(written.info['relative_file_paths'], written.info['files']):
        assert finfo['path'] == name
        with open(written.bag / name, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            assert summary.statistics.message_count == finfo['message_count']
            msgs = [(ch.topic, m.log_time, dec)
                    for _, ch, m, dec in reader.iter_decoded_messages(log_time_order=True)]
        assert len(msgs) == finfo['message_count']
        assert msgs[0][1] == finfo['starting_time']['nanoseconds_since_epoch']
        by_file += msgs
    return by_file


def test_mcap_reads_each_file_complete_and_in_order(written: Written) -> None:
    by_file = mcap_read(written)
    assert [(topic, t) for topic, t, _ in by_file] == [
        (topic, t) for topic, t, _ in written.messages]


def test_mcap_decodes_what_was_written(written: Written) -> None:
    for (topic, _, dec), (_, _, original) in zip(mcap_read(written), written.messages):
        if topic == '/joint_states':
            assert list(dec.name) == list(original.name)
        elif topic == '/parameter_events_like':
            assert list(dec.value.string_array_value) == list(
                original.value.string_array_value)
        elif topic == '/imu/data':
            assert dec.header.frame_id == 'base_link'
            assert dec.angular_velocity.z == original.angular_velocity.z


JOINTS = JointState(name=['a', 'bb', 'ccc'], position=[1.0, 2.0, 3.0])


def test_rclpy_joint_state_buffer_has_trailing_bytes() -> None:
    # the premise: rclpy's buffer is longer than the CDR message and rosbags refuses it
    with pytest.raises(Exception, match='size mismatch'):
        TYPESTORE.deserialize_cdr(serialize_message(JOINTS), 'sensor_msgs/msg/JointState')


def stored_payloads(bag: Path, data: bytes, exact: bytes) -> dict[str, bytes]:
    """Write a JointState (``data``) and an Imu (``exact``); the payloads the bag keeps."""
    writer = BagWriter(bag)
    assert writer.write('/joint_states', 'sensor_msgs/msg/JointState', T0, data)
    assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + 1, exact)
    writer.close()
    with Reader(bag) as reader:
        return {c.topic: bytes(raw) for c, _, raw in reader.messages()}


def test_joint_state_trailing_bytes_are_trimmed(tmp_path: Path) -> None:
    data = serialize_message(JOINTS)
    stored = stored_payloads(tmp_path / 'js', data, serialize_message(Imu()))
    assert len(stored['/joint_states']) < len(data)
    assert data.startswith(stored['/joint_states'])
    decoded = TYPESTORE.deserialize_cdr(stored['/joint_states'], 'sensor_msgs/msg/JointState')
    assert list(decoded.name) == ['a', 'bb', 'ccc']
    assert deserialize_message(stored['/joint_states'], JointState) == JOINTS


def test_fixed_size_payload_is_stored_unchanged(tmp_path: Path) -> None:
    exact = serialize_message(Imu())  # fixed size: passes unchanged
    stored = stored_payloads(tmp_path / 'js', serialize_message(JOINTS), exact)
    assert stored['/imu/data'] == exact


def write_timed_flushes(bag: Path) -> BagWriter:
    """Three pairs of messages 60 ms apart, flushed every 50 ms; the writer, still open.

    On the writer's own clock, advanced by hand: a loaded machine takes longer than 50 ms
    over the first message (its schema is generated then), which flushed it alone.
    """
    now = [0.0]
    writer = BagWriter(bag, flush_seconds=0.05, clock=lambda: now[0])
    data = serialize_message(Imu())
    for i in range(3):
        assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i, data)
        assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i, data)
        now[0] += 0.06
    return writer


def test_flushes_by_time_into_one_file(tmp_path: Path) -> None:
    bag = tmp_path / 'timed'
    writer = write_timed_flushes(bag)
    writer.maybe_flush()  # idle: the last flush is old enough
    assert metadata(bag)['relative_file_paths'] == ['timed_0.mcap']
    assert metadata(bag)['message_count'] == 6  # all flushed, the writer still open
    with open(bag / 'timed_0.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == 3
    writer.close()


def test_close_after_time_flushes_keeps_every_message(tmp_path: Path) -> None:
    bag = tmp_path / 'timed'
    writer = write_timed_flushes(bag)
    writer.maybe_flush()
    writer.close()
    assert metadata(bag)['message_count'] == 6


def test_full_chunks_flush_the_file_and_metadata_follows_at_its_period(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Camera-sized messages fill a chunk each: each is flushed (the file is complete), but
    metadata.yaml is rewritten only at flush_seconds or when it would miss a topic; a reader
    of the open bag gets every flushed message, the lagging counts notwithstanding."""
    from enbarr_core.recording import bag as bag_module
    rewrites: list[int] = []
    real = bag_module.write_metadata
    monkeypatch.setattr(bag_module, 'write_metadata', lambda path, files, typestore: (
        rewrites.append(sum(f.message_count for f in files)), real(path, files, typestore)))
    now = [0.0]
    bag = tmp_path / 'frames'
    writer = BagWriter(bag, flush_seconds=1.0, clock=lambda: now[0])
    frame = JointState()
    frame.position = [0.5] * (bag_module.CHUNK_BYTES // 8 + 1)  # one message fills a chunk
    data = serialize_message(stamp(frame, T0))
    for i in range(10):  # 10 frames in 0.45 s: 10 chunks
        now[0] = 0.05 * i
        assert writer.write('/camera', 'sensor_msgs/msg/JointState', T0 + i, data)
    assert rewrites == [1]  # the first chunk lists the topic; then none is due
    with Reader(bag) as reader:  # the writer still open: what a kill would leave
        assert reader.message_count == 1
        assert [t for _, t, _ in reader.messages()] == [T0 + i for i in range(10)]
    now[0] = 0.5
    imu = serialize_message(make_messages(0, T0)[0][2])
    assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + 10, imu)
    assert writer.write('/camera', 'sensor_msgs/msg/JointState', T0 + 11, data)
    assert rewrites == [1, 12]  # a new topic in the flushed chunk: listed at once
    with open(bag / 'frames_0.mcap', 'rb') as f:
        assert len(make_reader(f).get_summary().chunk_indexes) == 11
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + i for i in range(12)]
    for i in range(12, 33):  # a frame every 50 ms until 1.55 s: full chunks, none timed
        now[0] = 0.5 + 0.05 * (i - 11)
        assert writer.write('/camera', 'sensor_msgs/msg/JointState', T0 + i, data)
    # rewritten once more, by the first full chunk flush_seconds after the last rewrite (0.5 s)
    assert rewrites == [1, 12, 32]
    writer.close()
    assert metadata(bag)['message_count'] == 33


# -- killed at any instant ---------------------------------------------------------------------

CHILD = textwrap.dedent("""
    import os, sys, time
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu, JointState
    from enbarr_core.recording.bag import BagWriter

    writer = BagWriter(sys.argv[1], flush_seconds=3600.0)
    if len(sys.argv) > 2:  # freeze inside the tail rewrite of the 4th flush, to be killed there
        flushes = []
        pwritev = os.pwritev
        def tearing(fd, parts, at):  # the flush's one pwritev: half of it, then frozen
            flushes.append(1)
            if len(flushes) == 4:
                blob = b''.join(parts)
                os.pwrite(fd, blob[:len(blob) // 2], at)
                print('torn', flush=True)
                time.sleep(60)
            return pwritev(fd, parts, at)
        os.pwritev = tearing
    i = 0
    while True:
        imu = Imu()
        imu.linear_acceleration.x = float(i)
        imu.header.frame_id = 'x' * (i % 13)
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', 1000 + 2 * i, serialize_message(imu))
        if i % 4 == 0:
            js = JointState(name=['n%d' % i], position=[float(i)])
            writer.write('/joint_states', 'sensor_msgs/msg/JointState', 1001 + 2 * i,
                         serialize_message(js))
        i += 1
        if i % 5 == 0:
            writer.flush()
            print(i, flush=True)  # everything up to imu i-1 is flushed
""")


def run_and_kill(bag: Path, after: float | None, tear: bool = False) -> int:
    """Run the writer child on ``bag``, SIGKILL it; the last flushed count it reported.

    ``after``: seconds after its first flush; with ``tear``, kill it frozen inside the
    rewrite of its fourth flush (half the tail written).
    """
    args = [sys.executable, '-c', CHILD, str(bag)] + (['tear'] if tear else [])
    proc = subprocess.Popen(args, env=os.environ, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline()]
        assert lines[0], proc.stderr.read()
        if tear:
            while lines[-1].strip() != 'torn':
                lines.append(proc.stdout.readline())
                assert lines[-1], proc.stderr.read()
        else:
            time.sleep(after)
        proc.kill()
        assert proc.wait(10) == -signal.SIGKILL
        lines += proc.stdout.read().split()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stdout.close()
        proc.stderr.close()
    return max(int(x) for x in lines if x.strip().isdigit())


def read_both(bag: Path) -> list[int]:
    """The bag by rosbags (through metadata.yaml) and by mcap (file by file): they agree;
    the imu sequence numbers in time order."""
    info = metadata(bag)
    with Reader(bag) as reader:
        assert reader.message_count == info['message_count']
        msgs = [(c.topic, t, TYPESTORE.deserialize_cdr(raw, c.msgtype))
                for c, t, raw in reader.messages()]
    assert len(msgs) == info['message_count']
    assert mcap_messages(bag) == [(topic, t) for topic, t, _ in msgs]
    times = [t for _, t, _ in msgs]
    assert times == sorted(times)
    joints = [m for topic, _, m in msgs if topic == '/joint_states']
    assert [list(m.name) for m in joints] == [[f'n{4 * k}'] for k in range(len(joints))]
    return [int(m.linear_acceleration.x) for topic, _, m in msgs if topic == '/imu/data']


@pytest.mark.e2e  # processes, killed
def test_killed_at_random_instants_the_bag_reads_to_its_last_flush(tmp_path: Path) -> None:
    from enbarr_core.recording.bag import repair_bag
    rng = np.random.default_rng(10)
    torn = 0
    for k in range(12):
        bag = tmp_path / f'crash{k}'
        flushed = run_and_kill(bag, after=float(rng.uniform(0.0, 0.3)))
        intact = True
        try:
            with Reader(bag) as reader:
                sum(1 for _ in reader.messages())
        except Exception:  # noqa: BLE001 - a torn tail: the repair's job
            intact = False
        torn += not intact
        repaired = repair_bag(bag)
        assert [r.name for r in repaired] == [f'crash{k}_0.mcap']
        assert repaired[0].repaired == (not intact) or intact and not repaired[0].repaired
        seq = read_both(bag)
        assert seq == list(range(len(seq)))  # no gap, nothing out of order
        assert len(seq) >= flushed           # nothing lost up to the last flush
        assert repair_bag(bag)[0].repaired is False  # repaired once is intact


@pytest.mark.e2e  # a process, killed
def test_killed_inside_the_tail_rewrite_is_repaired_to_the_flush_before(tmp_path: Path) -> None:
    from enbarr_core.recording.bag import repair_bag
    bag = tmp_path / 'torn'
    flushed = run_and_kill(bag, None, tear=True)
    assert flushed == 15  # three flushes done; killed with half of the fourth's tail written
    with pytest.raises(Exception, match='magic|footer|summary|Invalid'):
        with Reader(bag) as reader:  # torn: no reader opens it as it is
            list(reader.messages())
    (r,) = repair_bag(bag)
    assert r.repaired
    seq = read_both(bag)
    # The three flushes before, and the torn one's chunk too when its first half held the
    # chunk and its message indexes whole (it does here: the summary is the larger part).
    assert seq in (list(range(15)), list(range(20)))
    assert metadata(bag)['relative_file_paths'] == ['torn_0.mcap']


def test_repair_refuses_what_is_not_a_bag(tmp_path: Path) -> None:
    from enbarr_core.recording.bag import repair_bag
    with pytest.raises(RecorderError, match='not a bag directory'):
        repair_bag(tmp_path / 'nothing')
    (tmp_path / 'other').mkdir()
    with pytest.raises(RecorderError, match=r'no other_N\.mcap files'):
        repair_bag(tmp_path / 'other')
    (tmp_path / 'other' / 'other_0.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(RecorderError, match=r'other_0\.mcap: cannot repair: .*not an MCAP'):
        repair_bag(tmp_path / 'other')


# -- splitting, as ros2 bag record --max-bag-size / --max-bag-duration ------------------------

def test_split_by_duration_of_message_time(tmp_path: Path) -> None:
    bag = tmp_path / 'split'
    writer = BagWriter(bag, flush_seconds=3600.0, split_seconds=1.0)
    for i in range(25):  # 0.1 s of message time apart: 10 per file
        assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i * 100_000_000, IMU_DATA)
    writer.close()
    info = metadata(bag)
    assert info['relative_file_paths'] == ['split_0.mcap', 'split_1.mcap', 'split_2.mcap']
    assert [f['message_count'] for f in info['files']] == [10, 10, 5]
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + i * 100_000_000 for i in range(25)]


def test_split_by_size(tmp_path: Path) -> None:
    bag = tmp_path / 'sized'
    writer = BagWriter(bag, flush_seconds=3600.0, split_size=20_000)
    for i in range(300):
        assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i, IMU_DATA)
        if i % 20 == 19:
            writer.flush()
    writer.close()
    info = metadata(bag)
    names = info['relative_file_paths']
    assert len(names) > 3 and names == [f'sized_{k}.mcap' for k in range(len(names))]
    for name in names[:-1]:  # each file stops at the first flush past the size
        assert 20_000 <= (bag / name).stat().st_size < 20_000 + 20 * (len(IMU_DATA) + 40) + 2000
    assert sum(f['message_count'] for f in info['files']) == 300
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + i for i in range(300)]


def test_no_split_by_default(tmp_path: Path) -> None:
    bag = tmp_path / 'one'
    writer = BagWriter(bag, flush_seconds=3600.0)
    for i in range(300):
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i * 1_000_000_000, IMU_DATA)
        if i % 20 == 19:
            writer.flush()
    writer.close()
    assert metadata(bag)['relative_file_paths'] == ['one_0.mcap']


def test_refuses_negative_splits(tmp_path: Path) -> None:
    with pytest.raises(RecorderError, match='split_size and split_seconds must be >= 0'):
        BagWriter(tmp_path / 'new', split_seconds=-1.0)


IMU_DATA = serialize_message(Imu())


# -- refusals ----------------------------------------------------------------------------------
def test_refuses_to_overwrite(tmp_path: Path) -> None:
    bag = tmp_path / 'old'
    bag.mkdir()
    (bag / 'metadata.yaml').write_text('precious')
    with pytest.raises(RecorderError) as info:
        BagWriter(bag)
    assert str(info.value) == (f'{bag}: exists and is not an empty directory; bags are never '
                               'overwritten')
    assert (bag / 'metadata.yaml').read_text() == 'precious'


def test_refuses_a_file_as_the_bag(tmp_path: Path) -> None:
    a_file = tmp_path / 'file'
    a_file.write_text('x')
    with pytest.raises(RecorderError, match='exists and is not an empty directory'):
        BagWriter(a_file)


def test_an_empty_directory_is_fine(tmp_path: Path) -> None:
    empty = tmp_path / 'empty'
    empty.mkdir()
    BagWriter(empty).close()  # an empty directory is fine


def test_refuses_a_flush_period_of_zero(tmp_path: Path) -> None:
    with pytest.raises(RecorderError, match='flush_seconds must be > 0, got 0'):
        BagWriter(tmp_path / 'new', flush_seconds=0)


def test_knows_the_types_of_the_jazzy_typestore(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'unknown')
    assert writer.knows_type('sensor_msgs/msg/Imu')
    assert not writer.knows_type('my_msgs/msg/Nope')


def test_unknown_type_is_skipped_and_remembered(tmp_path: Path) -> None:
    bag = tmp_path / 'unknown'
    writer = BagWriter(bag)
    assert writer.write('/x', 'my_msgs/msg/Nope', T0, b'\x00\x01\x00\x00') is False
    assert writer.write('/y', 'my_msgs/msg/Nope', T0, b'\x00\x01\x00\x00') is False
    assert writer.unknown_types == {'my_msgs/msg/Nope'}
    assert list(bag.iterdir()) == []  # no file opened for nothing
    assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0, serialize_message(Imu()))
    writer.close()
    assert metadata(bag)['message_count'] == 1
    assert [tm['topic_metadata']['name'] for tm in metadata(bag)['topics_with_message_count']
            ] == ['/imu/data']


def test_write_after_close(tmp_path: Path) -> None:
    bag = tmp_path / 'closed'
    writer = BagWriter(bag)
    writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0, serialize_message(Imu()))
    writer.close()
    writer.close()  # idempotent
    with pytest.raises(RecorderError) as info:
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + 1, serialize_message(Imu()))
    assert str(info.value) == f'{bag}: bag is closed'
    assert metadata(bag)['message_count'] == 1


IMU, JS = serialize_message(Imu()), serialize_message(JointState(name=['a']))


def test_topic_changing_type_is_refused_before_a_flush(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'typed', flush_seconds=3600.0)
    assert writer.write('/a', 'sensor_msgs/msg/Imu', T0, IMU)
    with pytest.raises(RecorderError, match='topic /a changed type from sensor_msgs/msg/Imu '
                                            'to sensor_msgs/msg/JointState'):
        writer.write('/a', 'sensor_msgs/msg/JointState', T0 + 1, JS)  # not flushed yet
    writer.close()


def test_topic_changing_type_is_refused_across_flushes(tmp_path: Path) -> None:
    bag = tmp_path / 'typed'
    writer = BagWriter(bag, flush_seconds=3600.0)
    imu, js = IMU, JS
    assert writer.write('/a', 'sensor_msgs/msg/Imu', T0, imu)
    with pytest.raises(RecorderError, match='changed type'):
        writer.write('/a', 'sensor_msgs/msg/JointState', T0 + 1, js)  # same segment
    writer.flush()
    with pytest.raises(RecorderError, match='changed type'):
        writer.write('/a', 'sensor_msgs/msg/JointState', T0 + 2, js)  # after a flush
    assert writer.write('/a', 'sensor_msgs/msg/Imu', T0 + 3, imu)
    writer.close()
    with Reader(bag) as reader:
        got = [(c.msgtype, TYPESTORE.deserialize_cdr(raw, c.msgtype))
               for c, _, raw in reader.messages()]
    assert [t for t, _ in got] == ['sensor_msgs/msg/Imu'] * 2


def test_malformed_payload_is_a_recorder_error(tmp_path: Path) -> None:
    """Bytes that are not the named type (e.g. a peer with another definition) must be a
    RecorderError, which the recorder counts as dropped, not any exception that would end
    its writer thread; and nothing half-written is left behind. The first message of a topic
    is checked (such a peer sends nothing else), even when said to be exact (from DDS).
    """
    bag = tmp_path / 'malformed'
    writer = BagWriter(bag)
    for bad in (b'', b'\x00\x01', b'\x00\x01\x00\x00\x01\x02', serialize_message(Imu())[:30]):
        with pytest.raises(RecorderError, match='not a CDR sensor_msgs/msg/Imu'):
            writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0, bad)
        with pytest.raises(RecorderError, match='not a CDR sensor_msgs/msg/Imu'):
            writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0, bad, exact=True)
    assert list(bag.iterdir()) == []
    assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0, serialize_message(Imu()))
    writer.close()
    assert metadata(bag)['message_count'] == 1


def test_a_guidance_reference_reads_back_with_rosbags_and_mcap(tmp_path: Path) -> None:
    """``guidance/reference`` (MultiDOFJointTrajectory, NaN where not fed back) in a bag."""
    ref = Reference(np.array([1.0, 2.0, 0.3]), np.array([0.2, -0.1, 0.05]),
                    np.array([0.01, -0.02, 0.003]), (False, False, True))
    header = Header(stamp=convert.ns_to_stamp(T0), frame_id=topics.WORLD_FRAME)
    original = reference_to_msg(ref, header)
    name, msgtype = f'/{topics.GUIDANCE_REFERENCE.name}', topics.GUIDANCE_REFERENCE.type_name
    assert msgtype == 'trajectory_msgs/msg/MultiDOFJointTrajectory'
    writer = BagWriter(tmp_path / 'bag')
    assert writer.write(name, msgtype, T0, serialize_message(original))
    writer.close()
    with Reader(tmp_path / 'bag') as reader:
        [(conn, _, raw)] = list(reader.messages())
        assert conn.msgtype == msgtype
        decoded = TYPESTORE.deserialize_cdr(raw, msgtype)
    [mcap_file] = (tmp_path / 'bag').glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        [(_, _, _, mcap_decoded)] = list(
            make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    for msg in (decoded, mcap_decoded):
        back = msg_to_reference(msg)  # duck-typed: reads either reader's classes
        assert back.position_mask == (False, False, True)
        np.testing.assert_allclose(back.eta_d, [np.nan, np.nan, 0.3], atol=1e-12)
        np.testing.assert_allclose(back.nu_d, ref.nu_d, atol=1e-12)
        np.testing.assert_allclose(back.nu_d_dot, ref.nu_d_dot, atol=1e-12)
        assert convert.stamp_to_ns(msg.header.stamp) == T0


# -- metadata.yaml is replaced atomically -----------------------------------------------------
#
# The writer is single-threaded, so "a reader never sees a partial file" is checked without
# races by stepping into its file writes: every write into the bag's directory is done in two
# halves, and between them the test reads ``metadata.yaml`` as a reader would. A writer that
# wrote the file in place would show the reader half a file there.

def one_segment(writer: BagWriter, i: int) -> None:
    for j, (topic, msgtype, msg) in enumerate(make_messages(i, T0 + i * 10_000_000)):
        assert writer.write(topic, msgtype, T0 + i * 10_000_000 + j, serialize_message(msg))
    writer.flush()


class HalfWrites:
    """Path.write_text into ``bag`` split in two; ``check`` runs between the halves."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, bag: Path, check: Any) -> None:
        self.bag, self.check, self.calls = bag, check, 0
        original = Path.write_text

        def write_text(path: Path, data: str, *args: Any, **kwargs: Any) -> int:
            if path.parent != self.bag:
                return original(path, data, *args, **kwargs)
            self.calls += 1
            original(path, data[:len(data) // 2], *args, **kwargs)
            self.check(path)
            return original(path, data, *args, **kwargs)

        monkeypatch.setattr(Path, 'write_text', write_text)


def test_a_reader_never_sees_a_partial_metadata_file(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    bag = tmp_path / 'atomic'
    writer = BagWriter(bag, flush_seconds=3600.0)
    seen: list[int | None] = []
    committed: int | None = None   # the count in the last complete metadata.yaml

    def reader(_: Path) -> None:
        target = bag / 'metadata.yaml'
        if not target.exists():
            seen.append(None)
            assert committed is None, 'metadata.yaml vanished while being rewritten'
            return
        info = yaml.safe_load(target.read_text())['rosbag2_bagfile_information']
        assert info['message_count'] == committed          # the previous version, whole
        seen.append(info['message_count'])

    halves = HalfWrites(monkeypatch, bag, reader)
    inodes = []
    for i in range(3):
        one_segment(writer, i)
        committed = 4 * (i + 1)
        assert metadata(bag)['message_count'] == committed
        assert metadata(bag)['relative_file_paths'] == ['atomic_0.mcap']
        inodes.append((bag / 'metadata.yaml').stat().st_ino)
    writer.close()
    assert halves.calls == 3 and seen == [None, 4, 8]
    # Each version is a new file moved over the old one, created while the old one still
    # existed, so its inode differs from the previous version's (an in-place rewrite keeps it).
    assert inodes[0] != inodes[1] and inodes[1] != inodes[2]
    assert sorted(p.name for p in bag.iterdir()) == ['atomic_0.mcap', 'metadata.yaml']


def test_a_failed_metadata_write_leaves_the_previous_version(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The disk fills up half way through writing the new metadata: the flush fails with a
    RecorderError naming the file, and the bag (file and metadata.yaml) still reads as it was
    before that flush: the file's last chunk is taken back."""
    bag = tmp_path / 'full'
    writer = BagWriter(bag, flush_seconds=3600.0)
    one_segment(writer, 0)
    one_segment(writer, 1)
    before = (bag / 'metadata.yaml').read_bytes()

    def disk_full(_: Path) -> None:
        raise OSError(28, 'No space left on device')

    HalfWrites(monkeypatch, bag, disk_full)
    with pytest.raises(RecorderError, match=r'metadata\.yaml.*No space left'):
        one_segment(writer, 2)
    assert (bag / 'metadata.yaml').read_bytes() == before
    with Reader(bag) as reader:
        assert reader.message_count == 8
        assert len(list(reader.messages())) == 8


def test_enbarr_bag_repair_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from enbarr_core.commands.main import main
    bag = tmp_path / 'run'
    write_bag(bag)
    data = (bag / 'run_0.mcap').read_bytes()
    (bag / 'run_0.mcap').write_bytes(data[:-20])  # a torn end
    assert main(['bag', 'repair', str(bag)]) == 0
    assert capsys.readouterr().out.startswith('run_0.mcap: 60 messages, repaired')
    assert main(['bag', 'repair', str(bag)]) == 0
    assert capsys.readouterr().out == 'run_0.mcap: 60 messages, intact\n'
    with Reader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == 60
    assert main(['bag', 'repair', str(tmp_path / 'none')]) == 2
    assert capsys.readouterr().err == (
        f'enbarr bag: error: {tmp_path / "none"}: not a bag directory\n')


def test_every_joint_state_is_trimmed_not_only_the_first(tmp_path: Path) -> None:
    bag = tmp_path / 'js'
    writer = BagWriter(bag)
    data = serialize_message(JOINTS)
    for i in range(3):
        assert writer.write('/joint_states', 'sensor_msgs/msg/JointState', T0 + i, data)
    writer.close()
    with Reader(bag) as reader:
        stored = [bytes(raw) for _, _, raw in reader.messages()]
    assert len(stored) == 3 and all(len(s) < len(data) for s in stored)
    for s in stored:
        assert list(TYPESTORE.deserialize_cdr(s, 'sensor_msgs/msg/JointState').name) == [
            'a', 'bb', 'ccc']


@pytest.mark.parametrize('written', [1, 9, 100, 'most'])
def test_a_short_write_that_leaves_the_old_footer_is_repaired(tmp_path: Path,
                                                               written: Any) -> None:
    """The kill cut the tail write short before the old footer: the file still ends with a
    valid-looking footer whose summary was overwritten. repair_bag must not trust it."""
    from enbarr_core.recording.bag import repair_bag
    bag = tmp_path / 'short'
    writer = BagWriter(bag, flush_seconds=3600.0)
    for i in range(10):
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i, IMU_DATA)
    writer.flush()
    mcap = writer._file.mcap
    at = mcap.data_end
    first = (bag / 'short_0.mcap').read_bytes()
    for i in range(10, 12):  # a second flush
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + i, IMU_DATA)
    writer.flush()
    writer.close()
    second = (bag / 'short_0.mcap').read_bytes()
    old_tail = len(first) - at
    k = old_tail - 40 if written == 'most' else written
    assert k < old_tail
    torn = second[:at + k] + first[at + k:]  # the new blob written k bytes over the old tail
    assert len(torn) == len(first) and torn.endswith(first[-37:])  # the old footer
    (bag / 'short_0.mcap').write_bytes(torn)
    (r,) = repair_bag(bag)
    assert r.repaired
    with Reader(bag) as reader:
        times = [t for _, t, _ in reader.messages()]
    # the first flush; the second one's chunk too when it was written whole before the cut
    assert times in ([T0 + i for i in range(10)], [T0 + i for i in range(12)])
    with open(bag / 'short_0.mcap', 'rb') as f:
        assert sum(1 for _ in make_reader(f).iter_messages()) == len(times)


@pytest.mark.e2e  # a process, killed
def test_the_supervisor_repairs_the_bag_of_a_killed_recorder_group(tmp_path: Path, caplog) -> None:
    # bringup's supervisor, on a group that died from a signal: repair.repair_recording.
    import logging

    from enbarr_core.bringup.repair import repair_recording
    from enbarr_core.bringup.profile import NodeSpec
    bag = tmp_path / 'killed'
    flushed = run_and_kill(bag, None, tear=True)
    with pytest.raises(Exception):  # noqa: B017 - torn: the readers refuse it, as they do
        read_both(bag)
    node = NodeSpec(name='recorder', plugin='recorder', parameters={'path': str(bag)},
                    group='recorder')
    profile = SimpleNamespace(nodes=(node,))
    with caplog.at_level(logging.WARNING, logger='enbarr.bringup'):
        repair_recording(profile, 'main', 'signal SIGKILL')      # not that group: untouched
        assert not caplog.records
        repair_recording(profile, 'recorder', 'signal SIGKILL')
    assert read_both(bag) in (list(range(flushed)), list(range(flushed + 5)))  # as above
    assert 'died (signal SIGKILL) while writing killed_0.mcap: repaired' in caplog.text


def test_read_counts_gives_messages_and_topics_with_messages(tmp_path: Path) -> None:
    from enbarr_core.recording.bag import BagCounts, read_counts
    (tmp_path / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  message_count: 7\n  topics_with_message_count:\n'
        '    - {topic_metadata: {name: /a}, message_count: 7}\n'
        '    - {topic_metadata: {name: /b}, message_count: 0}\n')
    assert read_counts(tmp_path) == BagCounts(messages=7, topics=1)
    assert read_counts(tmp_path / 'nowhere') is None
    (tmp_path / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    assert read_counts(tmp_path) is None
