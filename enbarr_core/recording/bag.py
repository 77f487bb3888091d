"""A rosbag2 (MCAP) writer that survives being killed: it writes in closed segments.

``rosbags`` writes an MCAP file's index and the bag's ``metadata.yaml`` only on close, so a
process killed mid-run would leave nothing readable. ``SegmentedBagWriter`` therefore
writes each ``segment_seconds`` of data as its own MCAP file through ``rosbags``, closes it,
moves it into the bag directory and rewrites ``metadata.yaml`` (atomically) to list every
closed file. That is the flush: after a kill, the bag holds everything up to the last one,
readable by the ``rosbags`` reader, by ``ros2 bag`` and, file by file, by the ``mcap`` reader.
The segment being written when the process dies stays behind as ``.segment_N/`` and is not
listed. No ROS import: messages arrive already serialized (CDR).

Storage: the writer refuses to start with less than ``min_free`` bytes free where the bag
goes, and checks again each time it opens a segment; below the margin, or when the storage
fails (``ENOSPC``, ``EIO``), it raises ``BagStorageError``, drops the unfinished segment and
writes nothing more. ``metadata.yaml`` is only ever replaced after a segment was closed and
moved, so the bag stays readable up to its last flush whatever failed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
import shutil
import time
from typing import Any

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.errors import WriterError
from rosbags.typesys import get_typestore, Stores
import yaml

from enbarr_core.framework.errors import RecorderError

ROSBAG2_VERSION = 9
MB = 1_000_000


class BagStorageError(RecorderError):
    """The bag's storage failed or is nearly full: the writer has stopped for good."""


def free_bytes(path: str | os.PathLike[str]) -> int:
    """Bytes free to this user on the filesystem that holds ``path`` (or would hold it)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


@dataclass
class _Topic:
    name: str
    type: str
    count: int = 0


@dataclass
class _Segment:
    index: int
    writer: Writer
    opened: float
    connections: dict[str, Any] = field(default_factory=dict)
    count: int = 0


class SegmentedBagWriter:
    """Write a rosbag2 MCAP bag in self-contained segments; see the module docstring."""

    def __init__(self, path: str | os.PathLike[str], segment_seconds: float = 1.0,
                 min_free: int = 0) -> None:
        self.path = Path(path)
        if not segment_seconds > 0.0:
            raise RecorderError(f'segment_seconds must be > 0, got {segment_seconds}')
        self.min_free = min_free
        try:
            self._check_free('recording refused')
        except BagStorageError as err:
            raise RecorderError(str(err)) from err
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise RecorderError(f'{self.path}: exists and is not an empty directory; '
                                'bags are never overwritten')
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise RecorderError(f'{self.path}: cannot create the bag directory: '
                                f'{err.strerror}') from err
        self.segment_seconds = segment_seconds
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.topics: dict[str, _Topic] = {}
        self.files: list[dict[str, Any]] = []
        self.unknown_types: set[str] = set()
        self._segment: _Segment | None = None
        self._next_index = 0
        self._topic_meta: dict[str, dict[str, Any]] = {}
        self._closed_counts: dict[str, int] = {}
        self._template: dict[str, Any] = {}
        self.closed = False
        self.failure: BagStorageError | None = None  # set once the storage failed

    def _check_free(self, then: str) -> None:
        """Raise ``BagStorageError`` when less than ``min_free`` bytes are free."""
        if self.min_free <= 0:
            return
        try:
            free = free_bytes(self.path)
        except OSError as err:
            raise BagStorageError(f'{self.path}: cannot tell the free space: {err.strerror}; '
                                  f'{then}') from err
        if free < self.min_free:
            raise BagStorageError(
                f'{self.path}: {free / MB:.1f} MB free, less than the {self.min_free / MB:g} MB '
                f'margin (min_free_space); {then}')

    def _fail(self, err: BagStorageError) -> BagStorageError:
        """Stop for good: drop the unfinished segment, keep the bag as last flushed."""
        self.failure = err
        self.closed = True
        seg, self._segment = self._segment, None
        if seg is not None:
            try:
                seg.writer.close()
            except Exception:  # noqa: BLE001, S110 - already failing; the segment is dropped
                pass
            shutil.rmtree(self.path / f'.segment_{seg.index}', ignore_errors=True)
        try:
            (self.path / 'metadata.yaml.tmp').unlink(missing_ok=True)
        except OSError:
            pass  # a half-written temporary file is never read: metadata.yaml is
        return err

    def knows_type(self, msgtype: str) -> bool:
        """Whether the Jazzy typestore has a definition of ``msgtype`` (``pkg/msg/Type``)."""
        return msgtype in self.typestore.types

    def write(self, topic: str, msgtype: str, timestamp_ns: int, data: bytes) -> bool:
        """Queue one serialized message; False for a type the typestore lacks.

        A type without a definition in the Jazzy typestore is remembered and skipped.
        """
        if self.failure is not None:
            raise self.failure
        if self.closed:
            raise RecorderError(f'{self.path}: bag is closed')
        if not self.knows_type(msgtype):
            self.unknown_types.add(msgtype)
            return False
        known = self.topics.get(topic)
        if known is not None and known.type != msgtype:
            raise RecorderError(f'topic {topic} changed type from {known.type} to {msgtype}')
        data = self._exact(msgtype, data)
        seg = self._segment
        if seg is not None and time.monotonic() - seg.opened >= self.segment_seconds:
            self.flush()
            seg = None
        try:
            if seg is None:
                self._check_free('recording stopped')
                seg = self._open_segment()
            conn = seg.connections.get(topic)
            if conn is None:
                conn = seg.connections[topic] = seg.writer.add_connection(
                    topic, msgtype, typestore=self.typestore)
            seg.writer.write(conn, timestamp_ns, data)
        except OSError as err:
            raise self._fail(BagStorageError(
                f'{self.path}: cannot write segment {seg.index if seg else self._next_index}: '
                f'{err.strerror or err}; recording stopped, the bag holds what was flushed '
                'before')) from err
        except BagStorageError as err:
            raise self._fail(err) from err
        self.topics.setdefault(topic, _Topic(topic, msgtype))
        seg.count += 1
        self.topics[topic].count += 1
        return True

    def _exact(self, msgtype: str, data: bytes) -> bytes:
        """Cut ``data`` to its CDR length.

        rclpy's ``serialize_message`` (rmw_fastrtps) returns a buffer of the *estimated* size
        for messages with string sequences (``JointState.name``, ``Parameter``), trailing
        bytes that readers checking the size (``rosbags``) refuse. The CDR end is found by
        decoding; payloads from DDS are exact already and pass unchanged.
        """
        msgdef = self.typestore.get_msgdef(msgtype)
        try:
            decode = msgdef.deserialize_cdr_le if data[1] else msgdef.deserialize_cdr_be
            _, pos = decode(memoryview(data)[4:], 0, msgdef.cls, self.typestore)
        except Exception as err:  # noqa: BLE001 - the decoder raises many types on bad bytes
            raise RecorderError(f'{len(data)} bytes are not a CDR {msgtype}: {err!r}') from err
        end = 4 + pos
        return data if len(data) <= end + 3 else data[:end]

    def _open_segment(self) -> _Segment:
        index = self._next_index
        self._next_index += 1
        writer = Writer(self.path / f'.segment_{index}', version=ROSBAG2_VERSION,
                        storage_plugin=StoragePlugin.MCAP)
        try:
            writer.open()
        except (WriterError, OSError) as err:
            raise BagStorageError(f'{self.path}: cannot open segment {index}: {err}; '
                                  'recording stopped') from err
        self._segment = _Segment(index, writer, time.monotonic())
        return self._segment

    def flush(self) -> None:
        """Close the current segment, move it into the bag and rewrite ``metadata.yaml``."""
        seg = self._segment
        if seg is None:
            return
        try:
            self._move_in(seg)
        except OSError as err:
            raise self._fail(BagStorageError(
                f'{self.path}: cannot close segment {seg.index}: {err.strerror or err}; '
                'recording stopped, the bag holds what was flushed before')) from err
        except BagStorageError as err:
            raise self._fail(err) from err

    def _move_in(self, seg: _Segment) -> None:
        seg.writer.close()
        self._segment = None
        seg_dir = self.path / f'.segment_{seg.index}'
        info = yaml.safe_load((seg_dir / 'metadata.yaml').read_text())[
            'rosbag2_bagfile_information']
        (src,) = info['relative_file_paths']
        dst = f'{self.path.name}_{seg.index}.mcap'
        os.replace(seg_dir / src, self.path / dst)
        shutil.rmtree(seg_dir)
        self._write_metadata(info, dst)

    def _write_metadata(self, info: dict[str, Any], dst: str) -> None:
        """List the segment just moved in (``info``, its file ``dst``) in ``metadata.yaml``.

        The bookkeeping is updated only once the new file is in place: a failed write
        leaves the old ``metadata.yaml`` and a writer that agrees with it.
        """
        files = [*self.files, {**info['files'][0], 'path': dst}]
        counts = dict(self._closed_counts)
        meta = dict(self._topic_meta)
        for tm in info['topics_with_message_count']:
            name = tm['topic_metadata']['name']
            meta.setdefault(name, tm['topic_metadata'])
            counts[name] = counts.get(name, 0) + tm['message_count']
        self._replace_metadata(info, files, meta, counts)
        self.files, self._closed_counts, self._topic_meta, self._template = (
            files, counts, meta, info)

    def maybe_flush(self) -> None:
        """Flush when the open segment is older than ``segment_seconds`` (call it when idle).

        Idle or not, the free space is checked at that period too: a disk that another
        program fills stops the recording at the margin, with the bag closed cleanly.
        """
        seg = self._segment
        if seg is not None and time.monotonic() - seg.opened >= self.segment_seconds:
            self.flush()
            if self._segment is None and not self.closed:
                try:
                    self._check_free('recording stopped')
                except BagStorageError as err:
                    raise self._fail(err) from err

    def close(self) -> None:
        """Flush the last segment; the bag is complete (after a failure: as last flushed)."""
        if not self.closed:
            self.flush()
            self.closed = True

    def _replace_metadata(self, template: dict[str, Any], files: list[dict[str, Any]],
                          meta: dict[str, dict[str, Any]], counts: dict[str, int]) -> None:
        starts = [f['starting_time']['nanoseconds_since_epoch'] for f in files]
        ends = [s + f['duration']['nanoseconds'] for s, f in zip(starts, files)]
        info = {
            **template,
            'relative_file_paths': [f['path'] for f in files],
            'files': files,
            'starting_time': {'nanoseconds_since_epoch': min(starts)},
            'duration': {'nanoseconds': max(ends) - min(starts)},
            'message_count': sum(f['message_count'] for f in files),
            'topics_with_message_count': [
                {'topic_metadata': meta[name], 'message_count': n}
                for name, n in sorted(counts.items())],
        }
        # Written beside it and moved over it: a reader (or a kill) sees the old file or the
        # new one, never a part; a failed write leaves the old one.
        tmp = self.path / 'metadata.yaml.tmp'
        try:
            tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info},
                                          default_flow_style=False, sort_keys=False))
            os.replace(tmp, self.path / 'metadata.yaml')
        except OSError as err:
            raise BagStorageError(f'{self.path}: cannot write metadata.yaml: {err.strerror}; '
                                  'recording stopped, the previous version is kept') from err


def read_bag(path: str | os.PathLike[str]) -> dict[str, list[tuple[int, Any]]]:
    """Read every message of a rosbag2 bag, deserialized, in time order.

    Returns ``{topic: [(receive time ns, msg)]}`` with rosbags' own message classes (field
    names as in the ROS types).
    """
    from rosbags.rosbag2 import Reader
    typestore = get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, list[tuple[int, Any]]] = {}
    with Reader(path) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append(
                (t, typestore.deserialize_cdr(raw, conn.msgtype)))
    return out
