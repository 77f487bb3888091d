"""One MCAP file that is complete after every flush, and its repair after a kill.

The file is ``magic, Header, data..., DataEnd, summary, footer, magic``. Messages collect in
a chunk in memory; ``flush`` writes that chunk and its message indexes at the end of the data
section, followed by a fresh DataEnd, summary (schemas, channels, every chunk index,
statistics, summary offsets) and footer, in one ``pwrite`` over the previous DataEnd and
summary. After it returns the file is a complete, indexed MCAP that ``rosbags`` and the
``mcap`` reader open. A write that fails (``ENOSPC``) is rolled back by writing the previous
tail again and truncating to it.

The summary grows with every chunk (camera frames fill a chunk each: after ten minutes it holds
thousands of chunk indexes, megabytes rewritten at every frame; docs/benchmarks.md). A flush
therefore rewrites a summary of more than ``SUMMARY_ALWAYS`` bytes only while that costs at most
``1/SUMMARY_RATIO`` of the data written since it was last written; otherwise the tail is DataEnd
and a footer without summary (``summary_start`` 0), which is still a complete MCAP: ``rosbags``,
the ``mcap`` reader and ``ros2 bag`` (``AllowFallbackScan``) then read the data section from the
start. ``close`` always writes the summary. When a new tail is shorter than the one it covers, the
file is truncated right after the write.

A process killed inside that ``pwrite`` can leave a torn tail (a short write stops at a page
boundary). ``recover`` reads the data section record by record, keeps every chunk whose
message indexes are complete (everything up to the last finished flush), drops the rest and
writes a fresh summary and footer; an intact file is left as it is, except that one ending
with a footer without summary (a kill between summaries) gets its summary written. A kill at
any other instant leaves the file as of its last flush.

A message of at least ``BIG`` bytes (a camera frame) is not copied into the chunk: the chunk
keeps a reference to it and ``pwritev`` writes it in place (the caller does not change it
afterwards: a serialized message is immutable).

Records (MCAP spec, https://mcap.dev/spec): little endian; a record is ``opcode u8,
length u64, content``; strings are ``u32 length + UTF-8``. Chunks are uncompressed, CRCs 0
(not computed), as the spec allows. Schemas and channels are written inside the chunk where
first used (so the data section alone describes itself, as rosbags writes them) and again in
the summary.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import mmap
import os
from pathlib import Path
import struct
from typing import Any

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS = 0x06, 0x07, 0x08, 0x0B
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F
FOOTER_SIZE = 1 + 8 + 20
DATA_END = struct.pack('<BQI', OP_DATA_END, 4, 0)
#: DataEnd and a footer that points at no summary (readers scan the data section).
BARE_TAIL = DATA_END + struct.pack('<BQQQI', OP_FOOTER, 20, 0, 0, 0) + MAGIC
#: A summary up to this size is rewritten at every flush; a larger one while its size is at
#: most 1/SUMMARY_RATIO of the data written since the last one (see the module docstring).
SUMMARY_ALWAYS = 64 * 1024
SUMMARY_RATIO = 10
#: A message of at least this many bytes is kept by reference in its chunk, not copied.
BIG = 64 * 1024
_MESSAGE_HEAD = struct.Struct('<BQHIQQ')
_REC_HEAD = struct.Struct('<BQ')


def _str(s: str) -> bytes:
    b = s.encode()
    return struct.pack('<I', len(b)) + b


def _rec(op: int, content: bytes) -> bytes:
    return _REC_HEAD.pack(op, len(content)) + content


def summary_tail(data_end: int, schema_recs: bytes | bytearray, n_schemas: int,
                 channel_recs: bytes | bytearray, n_channels: int,
                 chunk_indexes: bytes | bytearray, counts: dict[int, int], chunks: int,
                 start: int, end: int) -> bytes:
    """DataEnd, summary, summary offsets and footer for a data section ending at ``data_end``.

    The summary repeats the schema and channel records, lists every chunk index and the
    statistics (``counts``: messages per channel id; ``start``/``end``: their log times).
    """
    summary_start = data_end + len(DATA_END)
    groups = []
    parts = []
    at = summary_start
    for op, recs in ((OP_SCHEMA, schema_recs), (OP_CHANNEL, channel_recs),
                     (OP_CHUNK_INDEX, chunk_indexes)):
        if recs:
            groups.append((op, at, len(recs)))
            parts.append(recs)
            at += len(recs)
    n = sum(counts.values())
    stats = _rec(OP_STATISTICS, struct.pack(
        '<QHIIIIQQI', n, n_schemas, n_channels, 0, 0, chunks,
        start if n else 0, end if n else 0, 10 * len(counts))
        + b''.join(struct.pack('<HQ', k, v) for k, v in sorted(counts.items())))
    groups.append((OP_STATISTICS, at, len(stats)))
    parts.append(stats)
    at += len(stats)
    offsets = b''.join(_rec(OP_SUMMARY_OFFSET, struct.pack('<BQQ', *g)) for g in groups)
    footer = _rec(OP_FOOTER, struct.pack('<QQI', summary_start, at, 0)) + MAGIC
    return DATA_END + b''.join(parts) + offsets + footer


class McapError(Exception):
    """A file that is not an MCAP this module can recover (named with the reason)."""


@dataclass
class _Chunk:
    records: bytearray = field(default_factory=bytearray)  # the records after ``parts``
    entries: list[tuple[int, int, int]] = field(default_factory=list)  # (channel, t, offset)
    parts: list[Any] = field(default_factory=list)  # earlier records, big messages whole
    size: int = 0                                    # bytes in ``parts``

    def __len__(self) -> int:
        return self.size + len(self.records)


class McapFile:
    """Write one MCAP file; see the module docstring. Not thread safe (one writer thread)."""

    def __init__(self, path: str | os.PathLike[str], library: str = 'enbarr') -> None:
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        head = MAGIC + _rec(OP_HEADER, _str('ros2') + _str(library))
        try:
            self._pwrite(head, 0)
        except OSError:
            os.close(self._fd)
            raise
        self.data_end = len(head)       # where the next chunk goes
        self._tail = b''                # what the file holds after data_end now
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}   # topic -> channel id
        self.channel_topics: dict[int, str] = {}
        self.channel_schema: dict[int, str] = {}
        self._schema_recs = bytearray()
        self._channel_recs = bytearray()
        self._chunk_indexes = bytearray()
        self.counts: dict[int, int] = {}     # flushed messages per channel
        self.chunks = 0
        self.start = 2 ** 63 - 1             # flushed messages' log time span [ns]
        self.end = 0
        self._chunk = _Chunk()
        self.closed = False
        self._prev: tuple | None = None      # state before the last flush (revert)
        self._unsummarized = 0               # data bytes written since the last summary

    # -- writing --------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Messages not flushed yet."""
        return len(self._chunk.entries)

    @property
    def size(self) -> int:
        """Bytes the file will hold once the pending chunk is flushed (about)."""
        return self.data_end + len(self._chunk) + len(self._tail)

    def add_schema(self, name: str, encoding: str, data: str) -> int:
        """Add schema ``name`` (once); its id."""
        sid = self.schemas.get(name)
        if sid is None:
            sid = self.schemas[name] = len(self.schemas) + 1
            rec = _rec(OP_SCHEMA, struct.pack('<H', sid) + _str(name) + _str(encoding)
                       + _str(data))
            self._chunk.records += rec
            self._schema_recs += rec
        return sid

    def add_channel(self, topic: str, schema: str, encoding: str,
                    metadata: dict[str, str]) -> int:
        """Add a channel on ``topic`` of a schema added before (once); its id."""
        cid = self.channels.get(topic)
        if cid is None:
            cid = self.channels[topic] = len(self.channels) + 1
            meta = b''.join(_str(k) + _str(v) for k, v in metadata.items())
            rec = _rec(OP_CHANNEL, struct.pack('<HH', cid, self.schemas[schema]) + _str(topic)
                       + _str(encoding) + struct.pack('<I', len(meta)) + meta)
            self._chunk.records += rec
            self._channel_recs += rec
            self.channel_topics[cid] = topic
            self.channel_schema[cid] = schema
            self.counts[cid] = 0
        return cid

    def write(self, cid: int, t: int, data: bytes) -> None:
        """Add one message (log and publish time ``t`` [ns]) to the chunk in memory."""
        c = self._chunk
        rec = c.records
        n = len(data)
        c.entries.append((cid, t, c.size + len(rec)))
        rec += _MESSAGE_HEAD.pack(OP_MESSAGE, 22 + n, cid, 0, t, t)
        if n < BIG:
            rec += data
        else:  # by reference: no copy of a camera frame (see the module docstring)
            c.parts += (rec, data)
            c.size += len(rec) + n
            c.records = bytearray()

    @property
    def summarized(self) -> bool:
        """Whether the file's tail holds a summary (an index of every chunk)."""
        return self._tail != BARE_TAIL

    def flush(self, summary: bool = False) -> bool:
        """Write the pending chunk and a new tail; False if nothing pending.

        The tail holds a summary when ``summary`` or when it is cheap enough (see the module
        docstring). The chunk and the tail go out in one ``pwritev``.
        """
        c = self._chunk
        if not c.entries:
            if summary and self.chunks and not self.summarized:
                self._write_tail(self._summary(self.data_end, self._chunk_indexes,
                                               self.counts, self.chunks, self.start,
                                               self.end))
            return False
        index: dict[int, list[int]] = {}  # channel -> [t, offset, t, offset, ...]
        for cid, t, off in c.entries:
            entry = index.get(cid)
            if entry is None:
                entry = index[cid] = []
            entry += (t, off)
        times = [e[1] for e in c.entries]
        c_start, c_end = min(times), max(times)
        records = [*c.parts, c.records]  # written as they are (pwritev): no copy
        size = len(c)
        head = (struct.pack('<QQQI', c_start, c_end, size, 0) + _str('')
                + struct.pack('<Q', size))
        head = _REC_HEAD.pack(OP_CHUNK, len(head) + size) + head
        chunk_len = len(head) + size
        pos = self.data_end + chunk_len
        idx_recs = []
        offsets = []
        counts = dict(self.counts)
        for cid in sorted(index):
            entries = index[cid]
            counts[cid] += len(entries) // 2
            body = struct.pack(f'<HI{len(entries)}Q', cid, len(entries) * 8, *entries)
            offsets.append(struct.pack('<HQ', cid, pos))
            rec = _rec(OP_MESSAGE_INDEX, body)
            idx_recs.append(rec)
            pos += len(rec)
        msg_index = b''.join(idx_recs)
        chunk_index = _rec(OP_CHUNK_INDEX, struct.pack(
            '<QQQQI', c_start, c_end, self.data_end, chunk_len, 10 * len(offsets))
            + b''.join(offsets) + struct.pack('<Q', len(msg_index)) + _str('')
            + struct.pack('<QQ', size, size))
        chunk_indexes = self._chunk_indexes
        chunk_indexes += chunk_index  # in place: revert cuts it back to its length
        start, end = min(self.start, c_start), max(self.end, c_end)
        unsummarized = self._unsummarized + pos - self.data_end
        summary_len = len(self._schema_recs) + len(self._channel_recs) + len(chunk_indexes)
        if (summary or summary_len <= SUMMARY_ALWAYS
                or unsummarized >= SUMMARY_RATIO * summary_len):
            tail = self._summary(pos, chunk_indexes, counts, self.chunks + 1, start, end)
            unsummarized = 0
        else:
            tail = BARE_TAIL
        parts = [head, *records, msg_index, tail]
        try:
            self._pwritev(parts, self.data_end)
            self._truncate_after(pos + len(tail))
        except OSError:
            del chunk_indexes[len(chunk_indexes) - len(chunk_index):]
            self._rollback()
            raise
        self._prev = (self.data_end, self._tail, len(chunk_indexes) - len(chunk_index),
                      self.counts, self.chunks, self.start, self.end, self._unsummarized)
        self.data_end = pos
        self._tail = tail
        self._unsummarized = unsummarized
        self.counts = counts
        self.chunks += 1
        self.start, self.end = start, end
        self._chunk = _Chunk()
        return True

    def _summary(self, data_end: int, chunk_indexes: bytes | bytearray, counts: dict[int, int],
                 chunks: int, start: int, end: int) -> bytes:
        """DataEnd, summary, summary offsets and footer for a data section ending at data_end."""
        return summary_tail(data_end, self._schema_recs, len(self.schemas), self._channel_recs,
                            len(self.channels), chunk_indexes, counts, chunks, start, end)

    def revert(self) -> None:
        """Undo the last flush (its chunk is lost): when what lists the file failed."""
        if self._prev is None:
            return
        (self.data_end, self._tail, indexes_len, self.counts, self.chunks,
         self.start, self.end, self._unsummarized) = self._prev
        del self._chunk_indexes[indexes_len:]
        self._prev = None
        self._rollback()

    def _write_tail(self, tail: bytes) -> None:
        """Replace the tail after the data section (no chunk), e.g. the summary at close."""
        try:
            self._pwrite(tail, self.data_end)
            self._truncate_after(self.data_end + len(tail))
        except OSError:
            self._rollback()
            raise
        self._tail = tail
        self._unsummarized = 0
        self._prev = None

    def _truncate_after(self, end: int) -> None:
        """Cut what an older, longer tail left after ``end`` (the footer must end the file)."""
        if end < self.data_end + len(self._tail):
            os.ftruncate(self._fd, end)

    def _pwritev(self, parts: list[Any], at: int) -> None:
        total = sum(len(p) for p in parts)
        n = os.pwritev(self._fd, parts, at)
        if n < total:  # a short write (a signal, a full disk): the rest, or the OSError
            self._pwrite(memoryview(b''.join(parts))[n:], at + n)

    def _pwrite(self, data: bytes | memoryview, at: int) -> None:
        view = memoryview(data)
        while view:
            n = os.pwrite(self._fd, view, at)
            view, at = view[n:], at + n

    def _rollback(self) -> None:
        """Put the previous tail back after a failed write (best effort)."""
        try:
            self._pwrite(self._tail, self.data_end)
            os.ftruncate(self._fd, self.data_end + len(self._tail))
        except OSError:
            pass  # the caller reports the failure; recover() repairs what is left

    def close(self) -> None:
        """Flush and close (idempotent); the file stays complete."""
        if self.closed:
            return
        try:
            self.flush(summary=True)
        finally:
            self.closed = True
            os.close(self._fd)

    def abandon(self) -> None:
        """Close without writing what is pending (after a failure)."""
        if not self.closed:
            self.closed = True
            os.close(self._fd)


# -- reading back and repair -------------------------------------------------------------------

@dataclass
class FileInfo:
    """What a complete MCAP file of this writer holds (from a scan of its data section)."""

    path: Path
    topics: dict[str, str]          # topic -> message type (schema name)
    counts: dict[str, int]          # topic -> messages
    start: int                      # first log time [ns] (0 without messages)
    end: int
    repaired: bool = False          # the tail was torn and rewritten
    dropped_bytes: int = 0          # torn bytes after the last complete flush
    indexed: bool = False           # intact without summary: the summary was written
    qos: dict[str, str] = field(default_factory=dict)  # topic -> offered_qos_profiles

    @property
    def message_count(self) -> int:
        """Messages in the file."""
        return sum(self.counts.values())


def recover(path: str | os.PathLike[str]) -> FileInfo:
    """Make ``path`` a complete MCAP holding everything up to its last finished flush.

    An intact file is not written to, unless it has no summary (``indexed``): then it gets
    one. Raises ``McapError`` for a file that does not even
    start as an MCAP of the ros2 profile.
    """
    path = Path(path)
    with open(path, 'rb') as f:
        if os.fstat(f.fileno()).st_size < len(MAGIC) + 9:
            raise McapError(f'{path}: not an MCAP file (too short)')
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _recover(path, data)


def _recover(path: Path, data: mmap.mmap) -> FileInfo:
    if data[:8] != MAGIC:
        raise McapError(f'{path}: not an MCAP file (no magic)')
    op, n = _REC_HEAD.unpack_from(data, 8)
    if op != OP_HEADER or 17 + n > len(data):
        raise McapError(f'{path}: not an MCAP file (no header record)')
    pos = good = 17 + n
    schemas: dict[int, tuple[str, bytes]] = {}     # id -> (name, record)
    channels: dict[int, tuple[str, int, bytes]] = {}   # id -> (topic, schema id, record)
    chunk_indexes = bytearray()
    counts: dict[int, int] = {}
    nchunks, start, end = 0, 2 ** 63 - 1, 0
    footer = 'torn'
    pending: tuple | None = None   # a chunk waiting for its message indexes
    size = len(data)
    while pos + 9 <= size:
        op, n = _REC_HEAD.unpack_from(data, pos)
        body = pos + 9
        if body + n > size:
            break  # torn record
        nxt = body + n
        if op == OP_CHUNK:
            if pending is not None:
                break  # the previous chunk lacks message indexes: torn after it
            try:
                pending = _scan_chunk(data, pos, body, nxt, schemas, channels)
            except (struct.error, McapError):
                break
            pending_idx: list[bytes] = []
        elif op == OP_MESSAGE_INDEX and pending is not None:
            (cid,) = struct.unpack_from('<H', data, body)
            pending_idx.append(struct.pack('<HQ', cid, pos))
            cstart, clen, cstart_t, cend_t, per_channel, rec_len = pending
            if len(pending_idx) == len(per_channel):
                idx_len = nxt - (cstart + clen)
                chunk_indexes += _rec(OP_CHUNK_INDEX, struct.pack(
                    '<QQQQI', cstart_t, cend_t, cstart, clen, 10 * len(pending_idx))
                    + b''.join(pending_idx) + struct.pack('<Q', idx_len) + _str('')
                    + struct.pack('<QQ', rec_len, rec_len))
                for cid_, k in per_channel.items():
                    counts[cid_] = counts.get(cid_, 0) + k
                nchunks += 1
                start, end = min(start, cstart_t), max(end, cend_t)
                pending = None
                good = nxt
        elif op == OP_DATA_END:
            if pending is None:
                footer = _footer(data, nxt)
            break
        else:
            if pending is not None:
                break
            good = nxt
        pos = nxt
    fi = FileInfo(path, {}, {}, 0, 0)
    for cid, (topic, sid, rec) in channels.items():
        fi.topics[topic] = schemas[sid][0]
        fi.counts[topic] = counts.get(cid, 0)
        qos = channel_metadata(rec).get('offered_qos_profiles')
        if qos:
            fi.qos[topic] = qos
    fi.start, fi.end = (start, end) if nchunks else (0, 0)
    if footer == 'summary':
        return fi
    # Rebuild the tail at ``good``; schemas/channels only from complete chunks count, but
    # listing all that were seen is harmless (a channel without messages).
    tail = summary_tail(good, b''.join(r for _, r in schemas.values()), len(schemas),
                        b''.join(r for _, _, r in channels.values()), len(channels),
                        chunk_indexes, {cid: counts.get(cid, 0) for cid in channels},
                        nchunks, start, end)
    fd = os.open(path, os.O_WRONLY)
    try:
        os.pwrite(fd, tail, good)
        os.ftruncate(fd, good + len(tail))
    finally:
        os.close(fd)
    if footer == 'bare':
        fi.indexed = True
    else:
        fi.repaired = True
        fi.dropped_bytes = max(0, size - good - len(DATA_END))
    return fi


def channel_metadata(record: bytes) -> dict[str, str]:
    """Return the metadata map of a Channel record (opcode and length included)."""
    try:
        at = 9 + 4  # record head, channel id and schema id
        for _ in range(2):  # topic, message encoding
            (k,) = struct.unpack_from('<I', record, at)
            at += 4 + k
        (size,) = struct.unpack_from('<I', record, at)
        at += 4
        stop = at + size
        out: dict[str, str] = {}
        while at < stop:
            (k,) = struct.unpack_from('<I', record, at)
            key = bytes(record[at + 4:at + 4 + k]).decode()
            at += 4 + k
            (k,) = struct.unpack_from('<I', record, at)
            out[key] = bytes(record[at + 4:at + 4 + k]).decode()
            at += 4 + k
        return out
    except (struct.error, UnicodeDecodeError):
        return {}  # a damaged map: the channel is still usable without it


def _footer(data: mmap.mmap, data_end_next: int) -> str:
    """Tell what ends the file after a DataEnd record: 'summary', 'bare' (none), 'torn'."""
    if len(data) < FOOTER_SIZE + 8 or data[len(data) - 8:] != MAGIC:
        return 'torn'
    op, n, summary_start, _, _ = struct.unpack_from('<BQQQI', data, len(data) - 8 - FOOTER_SIZE)
    if op != OP_FOOTER or n != 20:
        return 'torn'
    if summary_start == 0:  # no summary: the footer must follow DataEnd
        return 'bare' if len(data) == data_end_next + FOOTER_SIZE + 8 else 'torn'
    return 'summary' if summary_start == data_end_next else 'torn'


def _scan_chunk(data: mmap.mmap, cstart: int, body: int, nxt: int,
                schemas: dict[int, tuple[str, bytes]],
                channels: dict[int, tuple[str, int, bytes]]) -> tuple:
    t0, t1, usize, _ = struct.unpack_from('<QQQI', data, body)
    (clen,) = struct.unpack_from('<I', data, body + 28)
    if clen:
        raise McapError('compressed chunk')
    (rlen,) = struct.unpack_from('<Q', data, body + 32)
    p = body + 40
    stop = p + rlen
    if stop != nxt or rlen != usize:
        raise McapError('chunk length')
    per_channel: dict[int, int] = {}
    while p < stop:
        op, n = _REC_HEAD.unpack_from(data, p)
        b = p + 9
        if op == OP_SCHEMA:
            (sid,) = struct.unpack_from('<H', data, b)
            (k,) = struct.unpack_from('<I', data, b + 2)
            schemas[sid] = (data[b + 6:b + 6 + k].decode(), data[p:b + n])
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from('<HH', data, b)
            (k,) = struct.unpack_from('<I', data, b + 4)
            channels[cid] = (data[b + 8:b + 8 + k].decode(), sid, data[p:b + n])
        elif op == OP_MESSAGE:
            (cid,) = struct.unpack_from('<H', data, b)
            per_channel[cid] = per_channel.get(cid, 0) + 1
        p = b + n
    return cstart, nxt - cstart, t0, t1, per_channel, rlen
