"""A rosbag2 (MCAP) writer that survives being killed: it writes in closed segments.

``rosbags`` writes an MCAP file's index and the bag's ``metadata.yaml`` only on close, so a
process killed mid-run would leave nothing readable. ``SegmentedBagWriter`` therefore
writes each ``segment_seconds`` of data as its own MCAP file through ``rosbags``, closes it,
moves it into the bag directory and rewrites ``metadata.yaml`` (atomically) to list every
closed file. That is the flush: after a kill, the bag holds everything up to the last one,
readable by the ``rosbags`` reader, by ``ros2 bag`` and, file by file, by the ``mcap`` reader.
The segment being written when the process dies stays behind as ``.segment_N/`` and is not
listed. No ROS import: messages arrive already serialized (CDR).
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

    def __init__(self, path: str | os.PathLike[str], segment_seconds: float = 1.0) -> None:
        self.path = Path(path)
        if not segment_seconds > 0.0:
            raise RecorderError(f'segment_seconds must be > 0, got {segment_seconds}')
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

    def knows_type(self, msgtype: str) -> bool:
        """Whether the Jazzy typestore has a definition of ``msgtype`` (``pkg/msg/Type``)."""
        return msgtype in self.typestore.types

    def write(self, topic: str, msgtype: str, timestamp_ns: int, data: bytes) -> bool:
        """Queue one serialized message; False for a type the typestore lacks.

        A type without a definition in the Jazzy typestore is remembered and skipped.
        """
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
        if seg is None:
            seg = self._open_segment()
        conn = seg.connections.get(topic)
        if conn is None:
            self.topics.setdefault(topic, _Topic(topic, msgtype))
            conn = seg.connections[topic] = seg.writer.add_connection(
                topic, msgtype, typestore=self.typestore)
        seg.writer.write(conn, timestamp_ns, data)
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
            raise RecorderError(f'{self.path}: cannot open segment {index}: {err}') from err
        self._segment = _Segment(index, writer, time.monotonic())
        return self._segment

    def flush(self) -> None:
        """Close the current segment, move it into the bag and rewrite ``metadata.yaml``."""
        seg, self._segment = self._segment, None
        if seg is None:
            return
        seg.writer.close()
        seg_dir = self.path / f'.segment_{seg.index}'
        info = yaml.safe_load((seg_dir / 'metadata.yaml').read_text())[
            'rosbag2_bagfile_information']
        (src,) = info['relative_file_paths']
        dst = f'{self.path.name}_{seg.index}.mcap'
        os.replace(seg_dir / src, self.path / dst)
        shutil.rmtree(seg_dir)
        self.files.append({**info['files'][0], 'path': dst})
        for tm in info['topics_with_message_count']:
            name = tm['topic_metadata']['name']
            self._topic_meta.setdefault(name, tm['topic_metadata'])
            self._closed_counts[name] = self._closed_counts.get(name, 0) + tm['message_count']
        self._template = info
        self._write_metadata()

    def maybe_flush(self) -> None:
        """Flush when the open segment is older than ``segment_seconds`` (call it when idle)."""
        seg = self._segment
        if seg is not None and time.monotonic() - seg.opened >= self.segment_seconds:
            self.flush()

    def close(self) -> None:
        """Flush the last segment; the bag is complete."""
        if not self.closed:
            self.flush()
            self.closed = True

    def _write_metadata(self) -> None:
        starts = [f['starting_time']['nanoseconds_since_epoch'] for f in self.files]
        ends = [s + f['duration']['nanoseconds'] for s, f in zip(starts, self.files)]
        info = {
            **self._template,
            'relative_file_paths': [f['path'] for f in self.files],
            'files': self.files,
            'starting_time': {'nanoseconds_since_epoch': min(starts)},
            'duration': {'nanoseconds': max(ends) - min(starts)},
            'message_count': sum(f['message_count'] for f in self.files),
            'topics_with_message_count': [
                {'topic_metadata': self._topic_meta[name], 'message_count': n}
                for name, n in sorted(self._closed_counts.items())],
        }
        # Written beside it and moved over it: a reader (or a kill) sees the old file or the
        # new one, never a part; a failed write leaves the old one.
        tmp = self.path / 'metadata.yaml.tmp'
        try:
            tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info},
                                          default_flow_style=False, sort_keys=False))
            os.replace(tmp, self.path / 'metadata.yaml')
        except OSError as err:
            raise RecorderError(f'{self.path}: cannot write metadata.yaml: {err.strerror}; '
                                'the previous version is kept') from err


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
