"""McapFile (enbarr_core.recording.mcap_file): a summary that stops growing the cost of a flush.

The summary indexes every chunk, so rewriting it at each flush grows with the run. Past
``SUMMARY_ALWAYS`` bytes it is rewritten only when it costs at most ``1/SUMMARY_RATIO`` of
the data written since the last one; the other flushes end the file with a footer that points
at no summary. Every state is read back by the ``mcap`` reader and ``rosbags`` (independent
of the writer), and by ``recover`` (which must find it intact).
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil

import pytest
from mcap.reader import make_reader
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import Imu

from enbarr_core.recording import mcap_file
from enbarr_core.recording.bag import BagWriter
from enbarr_core.recording.mcap_file import BARE_TAIL, McapFile, recover

T0 = 1_700_000_000_000_000_000
CHANNELS = 40
ONE = b'\x00\x01\x00\x00\x01\x00\x00\x00\x00'  # a CDR std_msgs/String ''


def open_file(path: Path) -> tuple[McapFile, list[int]]:
    f = McapFile(path)
    f.add_schema('std_msgs/msg/String', 'ros2msg', 'string data')
    return f, [f.add_channel(f'/topic_{k}', 'std_msgs/msg/String', 'cdr', {})
               for k in range(CHANNELS)]


def read_times(path: Path) -> list[int]:
    with open(path, 'rb') as stream:
        return [m.log_time for _, _, m in make_reader(stream).iter_messages(log_time_order=False)]


def summary_of(path: Path):
    with open(path, 'rb') as stream:
        return make_reader(stream).get_summary()


@pytest.fixture
def no_summary(monkeypatch: pytest.MonkeyPatch) -> None:
    """Flushes end with a bare footer until close (the summary is never cheap enough)."""
    monkeypatch.setattr(mcap_file, 'SUMMARY_ALWAYS', 0)
    monkeypatch.setattr(mcap_file, 'SUMMARY_RATIO', 10 ** 9)


def write_imu_bag(bag: Path, messages: int, every: int) -> BagWriter:
    """A bag of ``messages`` Imu flushed every ``every``; returned open."""
    writer = BagWriter(bag, flush_seconds=3600.0)
    data = serialize_message(Imu())
    for k in range(messages):
        assert writer.write('/imu/data', 'sensor_msgs/msg/Imu', T0 + k, data)
        if k % every == every - 1:
            writer.flush()
    return writer


def test_the_summary_is_rewritten_at_its_share_of_the_data(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / 'long.mcap'
    f, cids = open_file(path)
    summaries: list[int] = []
    real = McapFile._summary
    def counted(self: McapFile, *args: object) -> bytes:
        out = real(self, *args)
        if self is f:  # the writer's, not recover's on a copy
            summaries.append(len(out))
        return out
    monkeypatch.setattr(McapFile, '_summary', counted)
    text = b'x' * 400
    payload = b'\x00\x01\x00\x00' + (len(text) + 1).to_bytes(4, 'little') + text + b'\x00'
    data_start = f.data_end
    bare_after_summary = 0
    t = T0
    for flush in range(400):  # a chunk of one message per channel: one index of 40 entries
        for cid in cids:
            f.write(cid, t, payload)
            t += 1
        before = f.summarized
        size_before = os.path.getsize(path)
        assert f.flush()
        if not f.summarized:
            if before:  # the first bare tail after a summary: the file was cut to it
                bare_after_summary += 1
                assert os.path.getsize(path) < size_before
            assert path.read_bytes().endswith(BARE_TAIL)
        if flush in (0, 150, 399) or (flush > 150 and before and not f.summarized):
            assert read_times(path) == list(range(T0, t))  # complete after every flush
            copy = tmp_path / 'copy.mcap'                  # what a kill would leave
            shutil.copyfile(path, copy)
            info = recover(copy)                           # intact; indexed if it had none
            assert not info.repaired and info.indexed == (not f.summarized)
            assert len(summary_of(copy).chunk_indexes) == f.chunks
    # A small summary at every flush; then at most a tenth of the data since the last.
    small = [n for n in summaries if n <= mcap_file.SUMMARY_ALWAYS]
    large = summaries[len(small):]
    assert len(small) > 50 and len(large) >= 3 and bare_after_summary == len(large)
    assert sum(large) <= (f.data_end - data_start) / mcap_file.SUMMARY_RATIO + large[-1]
    assert summary_of(path) is None  # the last flush left a bare tail
    f.close()
    summary = summary_of(path)
    assert summary is not None and len(summary.chunk_indexes) == 400  # close: the full index
    assert read_times(path) == list(range(T0, t))


def test_close_right_after_a_summary_keeps_it(tmp_path: Path) -> None:
    path = tmp_path / 'short.mcap'
    f, cids = open_file(path)
    f.write(cids[0], T0, ONE)
    assert f.flush() and f.summarized
    f.close()
    assert len(summary_of(path).chunk_indexes) == 1


def write_killed_between_summaries(path: Path, messages: int) -> None:
    """A file of ``messages`` one-message chunks, each flushed with a bare tail, then
    abandoned as a kill between summaries leaves it (needs ``no_summary``)."""
    f, cids = open_file(path)
    for k in range(messages):
        f.write(cids[k], T0 + k, ONE)
        f.flush()
    assert not f.summarized
    f.abandon()


def test_an_intact_file_without_summary_gets_one(tmp_path: Path, no_summary: None) -> None:
    path = tmp_path / 'bare.mcap'
    write_killed_between_summaries(path, 4)
    assert summary_of(path) is None
    info = recover(path)
    assert info.indexed and not info.repaired and info.dropped_bytes == 0
    assert info.message_count == 4 and len(summary_of(path).chunk_indexes) == 4
    assert read_times(path) == [T0 + k for k in range(4)]
    again = recover(path)
    assert not again.indexed and not again.repaired  # now intact with its summary


def test_a_torn_bare_tail_is_repaired_with_a_summary(tmp_path: Path, no_summary: None) -> None:
    path = tmp_path / 'torn.mcap'
    write_killed_between_summaries(path, 5)
    os.truncate(path, os.path.getsize(path) - 10)  # a kill tore the footer
    info = recover(path)
    assert info.repaired and not info.indexed and info.message_count == 5
    assert len(summary_of(path).chunk_indexes) == 5
    assert read_times(path) == [T0 + k for k in range(5)]


def test_rosbags_reads_an_open_bag_whose_file_has_no_summary(tmp_path: Path,
                                                            no_summary: None) -> None:
    bag = tmp_path / 'bag'
    writer = write_imu_bag(bag, 30, every=10)
    assert summary_of(bag / 'bag_0.mcap') is None
    with Reader(bag) as reader:  # what a kill would leave
        assert [t for _, t, _ in reader.messages()] == [T0 + k for k in range(30)]
    writer.close()
    assert len(summary_of(bag / 'bag_0.mcap').chunk_indexes) == 3


def test_bag_repair_writes_the_index_of_a_bag_killed_between_summaries(
        tmp_path: Path, no_summary: None, capsys: pytest.CaptureFixture[str]) -> None:
    from enbarr_core.commands.main import main
    bag = tmp_path / 'run'
    writer = write_imu_bag(bag, 20, every=5)
    writer._file.mcap.abandon()  # the process dies: nothing more is written
    assert main(['bag', 'repair', str(bag)]) == 0
    assert capsys.readouterr().out == 'run_0.mcap: 20 messages, intact, its index written\n'
    assert len(summary_of(bag / 'run_0.mcap').chunk_indexes) == 4
    with Reader(bag) as reader:
        assert [t for _, t, _ in reader.messages()] == [T0 + k for k in range(20)]
    assert main(['bag', 'repair', str(bag)]) == 0
    assert capsys.readouterr().out == 'run_0.mcap: 20 messages, intact\n'


def test_after_a_revert_or_a_failed_write_the_index_lists_only_what_the_file_holds(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / 'undo.mcap'
    f, cids = open_file(path)
    f.write(cids[0], T0, ONE)
    assert f.flush()
    f.write(cids[0], T0 + 1, ONE)
    assert f.flush()
    f.revert()  # what lists the file failed: the second chunk is gone
    f.write(cids[1], T0 + 2, ONE)
    real = McapFile._pwritev

    def full_disk(self, parts, at):
        raise OSError(28, 'No space left on device')
    monkeypatch.setattr(McapFile, '_pwritev', full_disk)
    with pytest.raises(OSError):
        f.flush()
    monkeypatch.setattr(McapFile, '_pwritev', real)
    assert f.flush()  # the same chunk, written once there is room
    f.close()
    assert len(summary_of(path).chunk_indexes) == 2
    assert read_times(path) == [T0, T0 + 2]


def test_the_supervisor_writes_the_index_of_a_killed_recorder_group(
        tmp_path: Path, no_summary: None, caplog: pytest.LogCaptureFixture) -> None:
    import logging
    from types import SimpleNamespace

    from enbarr_core.bringup.repair import repair_recording
    from enbarr_core.bringup.profile import NodeSpec
    bag = tmp_path / 'killed'
    writer = write_imu_bag(bag, 10, every=10)
    writer._file.mcap.abandon()
    node = NodeSpec(name='recorder', plugin='recorder', parameters={'path': str(bag)},
                    group='recorder')
    with caplog.at_level(logging.WARNING, logger='enbarr.bringup'):
        repair_recording(SimpleNamespace(nodes=(node,)), 'recorder', 'signal SIGKILL')
    assert ('died (signal SIGKILL) while writing killed_0.mcap: intact, 10 messages, its index '
            'written') in caplog.text
    assert len(summary_of(bag / 'killed_0.mcap').chunk_indexes) == 1


def _messages(path: Path) -> list[tuple[int, int, bytes]]:
    with open(path, 'rb') as stream:
        return [(c.id, m.log_time, m.data) for _, c, m in make_reader(stream).iter_messages(
            log_time_order=False)]


def _indexed_messages(path: Path) -> list[tuple[int, int, bytes]]:
    """The messages each chunk's message indexes point at (channel, time, offset)."""
    import struct
    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader
    found = []
    chunk = None
    with open(path, 'rb') as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                chunk = record.data
            elif isinstance(record, MessageIndex):
                for t, offset in record.records:
                    op, length, cid, _, log_t, _ = struct.unpack_from('<BQHIQQ', chunk, offset)
                    assert op == 0x05 and cid == record.channel_id and log_t == t
                    found.append((cid, t, bytes(chunk[offset + 31:offset + 9 + length])))
    return sorted(found)


def test_big_messages_written_by_reference_read_back_whole(tmp_path: Path) -> None:
    """Frames of at least BIG bytes (kept by reference, not copied into the chunk) between
    small messages, chunks flushed after some: the mcap reader finds every byte in order,
    and ``recover`` (which walks the records one by one) keeps the chunks before a tear."""
    path = tmp_path / 'big.mcap'
    f = McapFile(path)
    f.add_schema('sensor_msgs/msg/Image', 'ros2msg', 'x')
    f.add_schema('sensor_msgs/msg/Imu', 'ros2msg', 'x')
    cam = f.add_channel('/camera', 'sensor_msgs/msg/Image', 'cdr', {})
    imu = f.add_channel('/imu', 'sensor_msgs/msg/Imu', 'cdr', {})
    small = serialize_message(Imu())
    sent: list[tuple[int, int, bytes]] = []
    t = T0
    for k in range(5):
        frame = bytes([k + 1]) * (mcap_file.BIG + 1000 * k)
        for data, cid in ((small, imu), (frame, cam), (small, imu)):
            f.write(cid, t, data)
            sent.append((cid, t, data))
            t += 1
        if k in (1, 3):
            assert f.size >= f.data_end + 2 * mcap_file.BIG   # pending counts whole
            f.flush()
    f.flush()
    assert _messages(path) == sent
    assert _indexed_messages(path) == sorted(sent)
    flushed = f.data_end
    f.write(cam, t, bytes(mcap_file.BIG))      # a sixth frame, torn in its chunk
    f.flush()
    os.truncate(path, flushed + mcap_file.BIG // 2)
    f.abandon()
    info = recover(path)
    assert info.repaired and _messages(path) == sent


def test_a_bag_of_camera_frames_reads_back_with_rosbags(tmp_path: Path) -> None:
    from sensor_msgs.msg import Image
    writer = BagWriter(tmp_path / 'bag', flush_seconds=3600.0)
    images = [Image(height=480, width=640, encoding='rgb8', step=1920,
                    data=bytes([k]) * (480 * 1920)) for k in range(4)]
    for k, image in enumerate(images):
        assert writer.write('/imu', 'sensor_msgs/msg/Imu', T0 + 2 * k, serialize_message(Imu()))
        assert writer.write('/camera', 'sensor_msgs/msg/Image', T0 + 2 * k + 1,
                            serialize_message(image))
    writer.close()
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(tmp_path / 'bag') as reader:
        got = [store.deserialize_cdr(raw, conn.msgtype) for conn, _, raw in reader.messages()
               if conn.topic == '/camera']
    assert [bytes(m.data) for m in got] == [bytes(i.data) for i in images]
