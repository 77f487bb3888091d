"""A rosbag2 (MCAP) bag that survives being killed: one file per run, complete at every flush.

``BagWriter`` writes ``<bag>/<bag>_0.mcap`` (and ``_1``, ``_2``... only when asked to split,
by size or duration, as ``ros2 bag record --max-bag-size / --max-bag-duration``) through
``McapFile``: messages collect in a chunk in memory and every ``flush_seconds`` the chunk is
written with a new summary and footer (see ``mcap_file``), then ``metadata.yaml`` is replaced
(atomically) to list the files and counts. That is the flush: after a kill, the bag holds
everything up to the last one, readable by the ``rosbags`` reader, ``ros2 bag`` and the
``mcap`` reader. A chunk that fills up (1 MiB: a camera frame or two) is flushed at once;
``metadata.yaml`` is then rewritten only when it would miss a file or topic, or is
``flush_seconds`` old, so its counts may lag the file by less than that (readers take the
messages from the file's own index). A kill inside the tail write itself (a fraction of a
millisecond per flush) can tear the file's end: ``repair_bag`` (``enbarr bag repair PATH``)
puts it back as of the last complete flush and rewrites ``metadata.yaml`` from the files. No
ROS import: messages arrive serialized (CDR).

Latched topics (``latch``: transient local, as ``/tf_static`` and ``mode``): the writer keeps
their last messages and writes them again at the start of every file of a split bag, stamped
with the time of the message that opens the file, so that each file stands alone (a viewer
that opens one file still places the sensors and knows the mode). The offered QoS of each
topic (``set_offered_qos``) goes to the channel's and ``metadata.yaml``'s
``offered_qos_profiles``, as rosbag2 writes them. A bag closed with no message still gets its
``metadata.yaml`` (zero messages), as ``ros2 bag record`` leaves one.

Storage: the writer refuses to start with less than ``min_free`` bytes free where the bag
goes, and checks again at each new chunk and each flush; below the margin, or when the
storage fails (``ENOSPC``, ``EIO``), it raises ``BagStorageError``, puts the file back as of
its last flush and writes nothing more. ``metadata.yaml`` is only ever replaced after a flush
succeeded, so the bag stays readable up to its last flush whatever failed.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
import os
from pathlib import Path
import re
import shutil
import time
from typing import Any

from rosbags.typesys import get_typestore, Stores
import yaml

from enbarr_core.framework.errors import RecorderError
from enbarr_core.recording.mcap_file import FileInfo, McapError, McapFile, recover
from enbarr_core.recording.schemas import MESSAGE_ENCODING, ros2msg_definition, SCHEMA_ENCODING

ROSBAG2_VERSION = 9
MB = 1_000_000
#: A chunk is flushed early once this big (rosbag2's MCAP default chunk is 768 KiB).
CHUNK_BYTES = 1 << 20


class BagStorageError(RecorderError):
    """The bag's storage failed or is nearly full: the writer has stopped for good."""


def free_bytes(path: str | os.PathLike[str]) -> int:
    """Bytes free to this user on the filesystem that holds ``path`` (or would hold it)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free




def _strings_in_sequences(typestore: Any, msgtype: str, inside: bool = False,
                          seen: frozenset[str] = frozenset()) -> bool:
    """Whether ``msgtype`` has a string inside a sequence or array (at any depth).

    Those are the types whose ``serialize_message`` buffer (rmw_fastrtps) is the *estimated*
    size, with trailing bytes; everything else is exact.
    """
    if msgtype in seen:
        return False
    for _, (kind, detail) in typestore.fielddefs[msgtype][1]:
        # rosbags' field kinds: 1 base, 2 name (nested), 3 array, 4 sequence
        if kind == 1:
            if inside and detail[0] == 'string':
                return True
        elif kind == 2:
            if _strings_in_sequences(typestore, detail, inside, seen | {msgtype}):
                return True
        else:
            (sub_kind, sub_detail), _ = detail
            if sub_kind == 1 and sub_detail[0] == 'string':
                return True
            if sub_kind == 2 and _strings_in_sequences(typestore, sub_detail, True,
                                                         seen | {msgtype}):
                return True
    return False


def check_bag_path(path: str | os.PathLike[str], min_free: int = 0) -> None:
    """Refuse (``RecorderError``) a bag where one cannot go; creates nothing.

    The path must be absent or an empty directory (bags are never overwritten), and at least
    ``min_free`` bytes must be free on its filesystem.
    """
    p = Path(path)
    above = p.absolute().parent
    while not above.exists() and above != above.parent:
        above = above.parent
    if not above.is_dir():
        raise RecorderError(f'{p}: cannot create the bag directory: {above} is not a '
                            'directory')
    if min_free > 0:
        try:
            free = free_bytes(p)
        except OSError as err:
            raise RecorderError(f'{p}: cannot tell the free space: {err.strerror}; '
                                'recording refused') from err
        if free < min_free:
            raise RecorderError(
                f'{p}: {free / MB:.1f} MB free, less than the {min_free / MB:g} MB margin '
                '(min_free_space); recording refused')
    if p.exists() and (not p.is_dir() or any(p.iterdir())):
        raise RecorderError(f'{p}: exists and is not an empty directory; '
                            'bags are never overwritten')


@dataclass
class _File:
    name: str
    mcap: McapFile
    first_t: int | None = None      # log time of its first message [ns]


class BagWriter:
    """Write a rosbag2 MCAP bag, complete at every flush; see the module docstring."""

    def __init__(self, path: str | os.PathLike[str], flush_seconds: float = 1.0,
                 min_free: int = 0, split_size: int = 0, split_seconds: float = 0.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = Path(path)
        if not flush_seconds > 0.0:
            raise RecorderError(f'flush_seconds must be > 0, got {flush_seconds}')
        if split_size < 0 or split_seconds < 0:
            raise RecorderError('split_size and split_seconds must be >= 0 (0: no split), '
                                f'got {split_size} and {split_seconds}')
        self.min_free = min_free
        check_bag_path(self.path, min_free)
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise RecorderError(f'{self.path}: cannot create the bag directory: '
                                f'{err.strerror}') from err
        self.flush_seconds = flush_seconds
        self.split_size = split_size
        self.split_ns = round(split_seconds * 1e9)
        self._clock = clock
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.unknown_types: set[str] = set()
        self.topics: dict[str, str] = {}          # topic -> type
        self._inexact: dict[str, bool] = {}       # type -> serialize_message over-estimates
        self._checked: set[str] = set()           # topics whose first message decoded
        # topic -> (type, inexact, open file, channel): what write's fast path needs
        self._fast: dict[str, tuple[str, bool, McapFile, int]] = {}
        self._split = bool(split_size or split_seconds)
        self._done: list[FileInfo] = []           # closed files (split)
        self._file: _File | None = None
        self._last_flush = clock()
        self._last_metadata = self._last_flush
        self._described: tuple[int, str, int] | None = None  # (closed files, open file, channels)
        self._metadata_behind = False  # a chunk flushed since metadata.yaml was written
        self.closed = False
        self.failure: BagStorageError | None = None  # set once the storage failed
        self._qos: dict[str, str] = {}            # topic -> offered_qos_profiles (YAML)
        # latched topic -> (type, its last messages as (log time, CDR)), see the docstring
        self._latched: dict[str, tuple[str, deque[tuple[int, bytes]]]] = {}

    @property
    def files(self) -> list[str]:
        """Names of the bag's files so far (the open one last)."""
        return [f.path.name for f in self._done] + ([self._file.name] if self._file else [])

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
        """Stop for good: drop what was not flushed, keep the bag as last flushed."""
        self.failure = err
        self.closed = True
        self._fast.clear()
        f, self._file = self._file, None
        if f is not None:
            f.mcap.abandon()
            if f.mcap.chunks == 0:  # never flushed: not listed, nothing to keep
                try:
                    f.mcap.path.unlink()
                except OSError:
                    pass  # an empty, unlisted file is never read
        try:
            (self.path / 'metadata.yaml.tmp').unlink(missing_ok=True)
        except OSError:
            pass  # a half-written temporary file is never read: metadata.yaml is
        return err

    def set_offered_qos(self, topic: str, offered_qos_profiles: str) -> None:
        """Say what ``topic``'s publishers offer (``recording.qos.offered_qos_yaml``).

        Set it before the topic's first message: it goes to the channel when the channel is
        created (and to ``metadata.yaml`` at every rewrite).
        """
        self._qos[topic] = offered_qos_profiles

    def latch(self, topic: str, msgtype: str, depth: int = 1,
              messages: tuple[tuple[int, bytes], ...] = ()) -> None:
        """Keep the last ``depth`` messages of ``topic`` and repeat them in every new file.

        ``messages``: ``(log time, CDR)`` to keep from now: the next file to open starts with
        them (``/tf_static``: the first file opens at the first message recorded, so the
        transforms are there from its first instant); written at once if a file is open.
        """
        if depth < 1:
            raise RecorderError(f'{topic}: latched depth must be >= 1, got {depth}')
        known = self.topics.get(topic)
        if known is not None and known != msgtype:
            raise RecorderError(f'topic {topic} changed type from {known} to {msgtype}')
        if messages and not self.knows_type(msgtype):
            raise RecorderError(f'{topic}: no definition of {msgtype} in the type store')
        old = self._latched.get(topic)
        kept = deque(old[1] if old else (), maxlen=depth)
        self._latched[topic] = (msgtype, kept)
        self._fast.pop(topic, None)  # its messages must be kept: the slow path
        checked = [(t, self._exact(msgtype, data)) for t, data in messages]
        if self._file is None:
            kept.extend(checked)  # the next file to open starts with them
            return
        for t, data in checked:  # a file is open: they go in now (and are kept)
            self.write(topic, msgtype, t, data, exact=True)

    def latched_messages(self) -> dict[str, tuple[str, int, tuple[tuple[int, bytes], ...]]]:
        """Each latched topic's type, depth and kept ``(log time, CDR)`` messages.

        What a bag opened after this one needs to start with the same latched state
        (``latch(topic, type, depth, messages)``): a recorder stopped and started again.
        """
        return {topic: (msgtype, kept.maxlen or 1, tuple(kept))
                for topic, (msgtype, kept) in self._latched.items()}

    def knows_type(self, msgtype: str) -> bool:
        """Whether the Jazzy typestore has a definition of ``msgtype`` (``pkg/msg/Type``)."""
        return msgtype in self.typestore.types

    def write(self, topic: str, msgtype: str, timestamp_ns: int, data: bytes,
              exact: bool = False) -> bool:
        """Add one serialized message; False for a type the typestore lacks.

        ``exact``: ``data`` ends where its CDR does (from DDS, or the generated encoders);
        otherwise a type whose ``serialize_message`` buffer may be too long is cut to its CDR
        length (decided once per type). The first message of each topic is decoded, so that
        bytes of another definition (a peer built against other messages) are refused with a
        ``RecorderError``; later ones are not decoded. A type without a definition in the Jazzy
        typestore is remembered and skipped.
        """
        fast = self._fast.get(topic)
        if fast is not None and fast[0] is msgtype and (exact or not fast[1]):
            # A topic already written to the open file, bytes that need no cut, a chunk
            # already begun (its free-space check done): append, flush when due.
            mcap = fast[2]
            if mcap.pending and not self._split:
                mcap.write(fast[3], timestamp_ns, data)
                if self._clock() - self._last_flush >= self.flush_seconds:
                    self.flush()
                elif mcap.size - mcap.data_end >= CHUNK_BYTES:
                    self.flush(metadata=False)
                return True
        if self.failure is not None:
            raise self.failure
        if self.closed:
            raise RecorderError(f'{self.path}: bag is closed')
        known = self.topics.get(topic)
        if known is None:
            if not self.knows_type(msgtype):
                self.unknown_types.add(msgtype)
                return False
        elif known != msgtype:
            raise RecorderError(f'topic {topic} changed type from {known} to {msgtype}')
        if topic not in self._checked or (not exact and self._inexact_type(msgtype)):
            data = self._exact(msgtype, data)
            self._checked.add(topic)
        f = self._file
        try:
            if f is not None and (
                    (self.split_ns and f.first_t is not None
                     and timestamp_ns - f.first_t >= self.split_ns)
                    or (self.split_size and f.mcap.size >= self.split_size)):
                self._roll_over()
                f = None
            if f is None:
                self._check_free('recording stopped')
                f = self._open_file()
                self._repeat_latched(f, timestamp_ns)
            mcap = f.mcap
            if not mcap.pending:
                self._check_free('recording stopped')  # at every new chunk
            cid = mcap.channels.get(topic)
            if cid is None:
                cid = self._add_channel(mcap, topic, msgtype)
            if f.first_t is None:
                f.first_t = timestamp_ns
            mcap.write(cid, timestamp_ns, data)
            latched = self._latched.get(topic)
            if latched is None:
                self._fast[topic] = (msgtype, self._inexact_type(msgtype), mcap, cid)
            else:
                latched[1].append((timestamp_ns, data))
            if self._clock() - self._last_flush >= self.flush_seconds:
                self._flush_file()
            elif mcap.size - mcap.data_end >= CHUNK_BYTES:
                self._flush_file(metadata=False)
        except OSError as err:
            raise self._fail(BagStorageError(
                f'{self.path}: cannot write {f.name if f else "a new file"}: '
                f'{err.strerror or err}; recording stopped, the bag holds what was flushed '
                'before')) from err
        except BagStorageError as err:
            raise self._fail(err) from err
        self.topics.setdefault(topic, msgtype)
        return True

    def _add_channel(self, mcap: McapFile, topic: str, msgtype: str) -> int:
        if msgtype not in mcap.schemas:
            text = ros2msg_definition(msgtype, self.typestore)
            assert text is not None  # write() took only types the store knows
            mcap.add_schema(msgtype, SCHEMA_ENCODING, text)
        return mcap.add_channel(topic, msgtype, MESSAGE_ENCODING,
                                {'offered_qos_profiles': self._qos.get(topic, '')})

    def _repeat_latched(self, f: _File, timestamp_ns: int | None) -> None:
        """Write the kept latched messages first in a new file (at ``timestamp_ns``).

        ``timestamp_ns`` None: each at its own log time (a bag that got nothing else).
        """
        for topic, (msgtype, kept) in self._latched.items():
            if not kept:
                continue
            cid = f.mcap.channels.get(topic)
            if cid is None:
                cid = self._add_channel(f.mcap, topic, msgtype)
            for t, data in kept:
                t = t if timestamp_ns is None else timestamp_ns
                if f.first_t is None:
                    f.first_t = t
                f.mcap.write(cid, t, data)
            self.topics.setdefault(topic, msgtype)

    def _exact(self, msgtype: str, data: bytes) -> bytes:
        """Decode ``data`` as a ``msgtype`` and cut it to its CDR length.

        rclpy's ``serialize_message`` (rmw_fastrtps) returns a buffer of the *estimated* size
        for messages with strings inside sequences (``JointState.name``, ``Parameter``),
        trailing bytes that readers checking the size (``rosbags``) refuse.
        """
        msgdef = self.typestore.get_msgdef(msgtype)
        try:
            decode = msgdef.deserialize_cdr_le if data[1] else msgdef.deserialize_cdr_be
            _, pos = decode(memoryview(data)[4:], 0, msgdef.cls, self.typestore)
        except Exception as err:  # noqa: BLE001 - the decoder raises many types on bad bytes
            raise RecorderError(f'{len(data)} bytes are not a CDR {msgtype}: {err!r}') from err
        end = 4 + pos
        return data if len(data) <= end + 3 else data[:end]

    def _inexact_type(self, msgtype: str) -> bool:
        """Whether ``serialize_message`` may return trailing bytes for ``msgtype`` (cached)."""
        inexact = self._inexact.get(msgtype)
        if inexact is None:
            inexact = self._inexact[msgtype] = _strings_in_sequences(self.typestore, msgtype)
        return inexact

    def _open_file(self) -> _File:
        name = f'{self.path.name}_{len(self._done)}.mcap'
        try:
            mcap = McapFile(self.path / name)
        except OSError as err:
            raise BagStorageError(f'{self.path}: cannot create {name}: {err.strerror}; '
                                  'recording stopped') from err
        self._file = _File(name, mcap)
        return self._file

    def _file_info(self, f: _File) -> FileInfo:
        m = f.mcap
        topics = {m.channel_topics[c]: m.channel_schema[c] for c in m.counts}
        counts = {m.channel_topics[c]: k for c, k in m.counts.items()}
        n = sum(counts.values())
        return FileInfo(m.path, topics, counts, m.start if n else 0, m.end if n else 0,
                        qos={t: self._qos[t] for t in topics if self._qos.get(t)})

    def _flush_file(self, metadata: bool = True) -> None:
        """Write the pending chunk and summary, then metadata.yaml.

        ``metadata=False`` (a chunk flushed early because it is full): metadata.yaml is
        rewritten only if it is ``flush_seconds`` old or no longer lists every file and topic
        (camera frames fill a chunk per frame; rewriting the YAML for each took a quarter of
        the writer's CPU). Its counts then lag the file by less than ``flush_seconds``, which
        no reader minds: they read the messages through the file's own index.
        """
        now = self._clock()
        self._last_flush = now
        f = self._file
        if f is None:
            return
        self._check_free('recording stopped')
        flushed = f.mcap.flush()
        if not (flushed or (metadata and self._metadata_behind)):
            return
        described = (len(self._done), f.name, len(f.mcap.channels))
        if (not metadata and described == self._described
                and now - self._last_metadata < self.flush_seconds):
            self._metadata_behind = True
            return
        try:
            write_metadata(self.path, [*self._done, self._file_info(f)], self.typestore)
        except BagStorageError:
            if flushed:
                f.mcap.revert()  # the file back as metadata.yaml still describes it
            raise
        self._described, self._last_metadata = described, now
        self._metadata_behind = False

    def _roll_over(self) -> None:
        """Close the current file (flushed) and start the next one at the next message."""
        f = self._file
        if f is None:
            return
        self._flush_file()
        f.mcap.close()
        self._file = None
        self._fast.clear()
        if f.mcap.chunks:
            self._done.append(self._file_info(f))

    def flush(self, metadata: bool = True) -> None:
        """Write what is pending: the file is complete and listed in ``metadata.yaml``.

        ``metadata=False``: see ``_flush_file``.
        """
        if self.closed:
            return
        try:
            self._flush_file(metadata)
        except OSError as err:
            name = self._file.name if self._file else 'the bag'
            raise self._fail(BagStorageError(
                f'{self.path}: cannot write {name}: {err.strerror or err}; recording stopped, '
                'the bag holds what was flushed before')) from err
        except BagStorageError as err:
            raise self._fail(err) from err

    def maybe_flush(self) -> None:
        """Flush when the last flush is ``flush_seconds`` old (call it when idle).

        Idle or not, the free space is checked at that period too: a disk that another
        program fills stops the recording at the margin, with the bag as last flushed.
        """
        if self.closed or self._clock() - self._last_flush < self.flush_seconds:
            return
        self.flush()
        if not self.closed:
            try:
                self._check_free('recording stopped')
            except BagStorageError as err:
                raise self._fail(err) from err

    def close(self) -> None:
        """Flush and close; the bag is complete (after a failure: as last flushed).

        A bag that got no message holds its latched ones (``/tf_static``) at their own log
        times, or nothing; either way it gets its ``metadata.yaml``.
        """
        if self.closed:
            return
        if self._file is None and not self._done and any(k for _, k in self._latched.values()):
            try:
                self._check_free('recording stopped')
                self._repeat_latched(self._open_file(), None)
            except OSError as err:
                raise self._fail(BagStorageError(
                    f'{self.path}: cannot write: {err.strerror or err}; recording stopped'
                    )) from err
            except BagStorageError as err:
                raise self._fail(err) from err
        self.flush()
        self._fast.clear()
        if self._file is not None:
            self._file.mcap.close()
        elif not self._done:
            try:
                write_metadata(self.path, [], self.typestore)
            except BagStorageError as err:
                raise self._fail(err) from err
        self.closed = True


@dataclass(frozen=True)
class BagCounts:
    """What a bag's ``metadata.yaml`` says it holds."""

    messages: int
    topics: int  # topics with at least one message


def read_counts(path: str | Path) -> BagCounts | None:
    """Read the message and topic counts of the rosbag2 bag at ``path`` (None: unreadable)."""
    try:
        with open(Path(path) / 'metadata.yaml', encoding='utf-8') as f:
            info = yaml.safe_load(f)['rosbag2_bagfile_information']
        listed = [t for t in info['topics_with_message_count'] if t['message_count']]
        return BagCounts(int(info['message_count']), len(listed))
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        return None


def write_metadata(path: Path, files: list[FileInfo], typestore: Any) -> None:
    """Replace ``path/metadata.yaml`` (atomically) to list ``files`` and their topics.

    Files without messages are left out (a split that found nothing more to write).
    """
    listed = [f for f in files if f.message_count]
    topics: dict[str, str] = {}
    counts: dict[str, int] = {}
    qos: dict[str, str] = {}
    for f in listed:
        for name, msgtype in f.topics.items():
            topics.setdefault(name, msgtype)
            counts[name] = counts.get(name, 0) + f.counts.get(name, 0)
            if f.qos.get(name):
                qos.setdefault(name, f.qos[name])
    start = min((f.start for f in listed), default=0)
    end = max((f.end for f in listed), default=0)
    info = {
        'version': ROSBAG2_VERSION,
        'storage_identifier': 'mcap',
        'relative_file_paths': [f.path.name for f in listed],
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(counts.values()),
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': name, 'type': topics[name], 'serialization_format': 'cdr',
                'offered_qos_profiles': qos.get(name, ''),
                'type_description_hash': _hash(typestore, topics[name])},
             'message_count': counts[name]}
            for name in sorted(topics)],
        'compression_format': '',
        'compression_mode': '',
        'files': [
            {'path': f.path.name,
             'starting_time': {'nanoseconds_since_epoch': f.start},
             'duration': {'nanoseconds': f.end - f.start},
             'message_count': f.message_count}
            for f in listed],
        'custom_data': None,
        'ros_distro': 'jazzy',
    }
    # Written beside it and moved over it: a reader (or a kill) sees the old file or the
    # new one, never a part; a failed write leaves the old one.
    tmp = path / 'metadata.yaml.tmp'
    try:
        tmp.write_text(yaml.dump({'rosbag2_bagfile_information': info}, Dumper=_DUMPER,
                                 default_flow_style=False, sort_keys=False))
        os.replace(tmp, path / 'metadata.yaml')
    except OSError as err:
        raise BagStorageError(f'{path}: cannot write metadata.yaml: {err.strerror}; '
                              'recording stopped, the previous version is kept') from err


#: libyaml's emitter when PyYAML has it (several times faster than the pure-Python one, and
#: the file is rewritten at every flush: docs/benchmarks.md).
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)
_HASHES: dict[str, str] = {}


def _hash(typestore: Any, msgtype: str) -> str:
    h = _HASHES.get(msgtype)
    if h is None:
        try:
            h = typestore.hash_rihs01(msgtype)
        except Exception:  # noqa: BLE001 - a type the store cannot hash: no hash, as rosbag2
            h = ''
        _HASHES[msgtype] = h
    return h


@dataclass(frozen=True)
class Repaired:
    """What ``repair_bag`` did to one file."""

    name: str
    messages: int
    repaired: bool        # its tail was torn and rewritten
    dropped_bytes: int    # torn bytes cut after its last complete flush
    indexed: bool = False  # intact but without summary: the summary was written


def repair_bag(path: str | os.PathLike[str]) -> list[Repaired]:
    """Make a bag whose writer was killed complete as of its last flush.

    Every ``<bag>_N.mcap`` file gets a valid summary and footer (a torn tail after the last
    complete flush is cut), and ``metadata.yaml`` is rewritten from what the files hold.
    Intact files are not written to, except that one without summary (the writer was killed
    between two summaries: readable, but readers scan it) gets its summary. Raises
    ``RecorderError`` naming the bag when it is not one of this recorder's.
    """
    path = Path(path)
    if not path.is_dir():
        raise RecorderError(f'{path}: not a bag directory')
    pattern = re.compile(re.escape(path.name) + r'_(\d+)\.mcap')
    found = sorted((int(m.group(1)), p) for p in path.iterdir()
                   if (m := pattern.fullmatch(p.name)))
    if not found:
        raise RecorderError(f'{path}: no {path.name}_N.mcap files: not a bag of this recorder')
    infos = []
    out = []
    for _, p in found:
        try:
            fi = recover(p)
        except (McapError, OSError) as err:
            raise RecorderError(f'{p}: cannot repair: {err}') from err
        infos.append(fi)
        out.append(Repaired(p.name, fi.message_count, fi.repaired, fi.dropped_bytes,
                            fi.indexed))
    try:
        write_metadata(path, infos, get_typestore(Stores.ROS2_JAZZY))
    except BagStorageError as err:
        raise RecorderError(str(err)) from err
    return out


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
