"""The Slamtec RPLidar serial protocol as the A1 speaks it.

Requests, response descriptors, the identity and health answers, and the SCAN sample stream
cut into samples.

Written from Slamtec's "RPLIDAR Interface Protocol and Application Notes" (A1 & A2, rev 1.1)
and checked against the vendor SDK (github.com/Slamtec/rplidar_sdk:
``sdk/include/sl_lidar_cmd.h``, ``sdk/include/sl_lidar_protocol.h``,
``sdk/src/sl_lidarprotocol_codec.cpp``, ``sdk/src/sl_lidar_driver.cpp``,
``sdk/src/dataunpacker/unpacker/handler_normalnode.cpp``):

- request ``A5 CMD`` or, with a payload (``CMD & 0x80``), ``A5 CMD SIZE PAYLOAD CHECKSUM``,
  the checksum being the XOR of every byte before it, ``A5`` included (codec
  ``onEncodeData``). STOP ``0x25``, RESET ``0x40``, SCAN ``0x20``, GET_INFO ``0x50``,
  GET_HEALTH ``0x52``;
- response descriptor, 7 bytes: ``A5 5A``, a little-endian u32 whose low 30 bits are the
  length of one response and top 2 bits the send mode (0 single, 1 multiple: a stream), then
  the data type (``0x04`` info, ``0x06`` health, ``0x81`` scan samples);
- GET_INFO: model u8 (high nibble the major model: 1 = A1, e.g. ``0x18`` A1M8), firmware
  u16 (minor in the low byte, major in the high byte), hardware u8, serial number 16 bytes;
  GET_HEALTH: status u8 (0 good, 1 warning, 2 error), error code u16;
- SCAN sample, 5 bytes: byte 0 = quality (6 bits) << 2 | !S << 1 | S (S: first sample of a
  new revolution), byte 1 bit 0 = check bit C (always 1), angle_q6 = u16(bytes 1..2) >> 1
  [deg * 64, 0 to 360], distance_q2 = u16(bytes 3..4) [mm * 4], 0 when the measurement is
  invalid. The SDK's unpacker resynchronises by dropping a byte whenever S == !S or C == 0;
  ``ScanDecoder`` asks more of a sample (see there): the protocol has no checksum.

A1 figures (Slamtec, "RPLIDAR A1 ... Introduction and Datasheet", model A1M8, measurement
performance table): distance range 0.15-12 m, scan rate 1-10 Hz (5.5 Hz typical, 360 samples
a scan, 1 deg resolution), sample duration 0.5 ms (2000 samples/s; up to 8000 in the express
modes this driver does not use); angles grow clockwise seen from above (a left-handed frame).

The driver (``rplidar``) and the check (``check``) use this module; the emulator keeps its own
copy of the bytes, typed from the same document, so that a wrong constant here cannot hide
behind an emulator that shares it. No ROS here.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

SYNC = 0xA5
ANS_SYNC = 0x5A
CMD_STOP = 0x25
CMD_RESET = 0x40
CMD_SCAN = 0x20
CMD_GET_INFO = 0x50
CMD_GET_HEALTH = 0x52
CMDFLAG_HAS_PAYLOAD = 0x80
ANS_TYPE_DEVINFO = 0x04
ANS_TYPE_DEVHEALTH = 0x06
ANS_TYPE_MEASUREMENT = 0x81
MODE_SINGLE = 0
MODE_MULTI = 1
DESCRIPTOR_SIZE = 7
SAMPLE_SIZE = 5
INFO_SIZE = 20
HEALTH_SIZE = 3
STATUS_OK, STATUS_WARNING, STATUS_ERROR = 0, 1, 2
STATUS_NAMES = {STATUS_OK: 'good', STATUS_WARNING: 'warning', STATUS_ERROR: 'error'}
#: Major model number (``model >> 4``) of the A1 series.
A1_MAJOR = 1
#: A1 range [m] (datasheet).
RANGE_MIN = 0.15
RANGE_MAX = 12.0
BAUDRATE = 115200
#: A1 sample period with SCAN (2000 samples/s) [ns], until a revolution measures it.
SAMPLE_PERIOD_NS = 500_000


def request(cmd: int, payload: bytes = b'') -> bytes:
    """Encode a request: ``A5 CMD`` or ``A5 CMD SIZE PAYLOAD XOR`` (see the module doc)."""
    if not payload and not cmd & CMDFLAG_HAS_PAYLOAD:
        return bytes((SYNC, cmd))
    body = bytes((SYNC, cmd, len(payload))) + bytes(payload)
    checksum = 0
    for b in body:
        checksum ^= b
    return body + bytes((checksum,))


class Descriptor(NamedTuple):
    """A response descriptor: length of one response [bytes], send mode, data type."""

    length: int
    mode: int
    dtype: int



def decode_descriptor(data: bytes) -> Descriptor:
    """Parse 7 descriptor bytes; ``ValueError`` when the sync bytes are wrong."""
    if len(data) != DESCRIPTOR_SIZE or data[0] != SYNC or data[1] != ANS_SYNC:
        raise ValueError(f'not a response descriptor: {data.hex(" ")}')
    word, dtype = struct.unpack_from('<IB', data, 2)
    return Descriptor(word & 0x3FFFFFFF, word >> 30, dtype)


class DeviceInfo(NamedTuple):
    """GET_INFO answer."""

    model: int
    firmware: tuple[int, int]  # (major, minor)
    hardware: int
    serial: str  # 32 hex digits

    @classmethod
    def decode(cls, data: bytes) -> DeviceInfo:
        """Parse the 20-byte payload."""
        model, fw_minor, fw_major, hardware = struct.unpack_from('<4B', data)
        return cls(model, (fw_major, fw_minor), hardware, data[4:20].hex().upper())

    @property
    def model_name(self) -> str:
        """``A1M8`` style name (the SDK's ``GetModelNameStringByModelID``)."""
        return f'A{self.model >> 4}M{self.model & 0xF}'

    def describe(self) -> str:
        """One line for people."""
        return (f'RPLidar {self.model_name} (model 0x{self.model:02X}), firmware '
                f'{self.firmware[0]}.{self.firmware[1]:02d}, hardware {self.hardware}, '
                f'serial {self.serial}')


class Health(NamedTuple):
    """GET_HEALTH answer."""

    status: int
    error_code: int

    @classmethod
    def decode(cls, data: bytes) -> Health:
        """Parse the 3-byte payload."""
        status, code = struct.unpack_from('<BH', data)
        return cls(status, code)

    def describe(self) -> str:
        """One line for people."""
        return (f'health {STATUS_NAMES.get(self.status, self.status)} (error code '
                f'0x{self.error_code:04X})')


#: Angles are [0, 360) deg: angle_q6 below this [deg * 64].
FULL_TURN_Q6 = 360 * 64


class ScanDecoder:
    """Cuts a SCAN stream into samples and keeps only samples that fit the stream.

    The protocol has no checksum: a byte run out of step passes the SDK's checks (S != !S,
    C == 1) one time in four, and the bytes of a truncated sample shift every later one. So
    a sample counts only when it fits its neighbours: its header checks pass, its angle is
    below 360 deg, and the angle steps forward from the sample before by more than 0 and at
    most ``MAX_STEP_Q6`` (modulo 360 deg: the lidar turns one way, a little per sample).

    In step, whole samples are checked at once, and a sample is taken only once the
    ``RESYNC_SAMPLES - 1`` samples after it fit too. A sample that does not fit is a loss of
    synchronisation; the samples held back before it are dropped with it, as they may hold
    its bytes (a truncated sample keeps its header and takes the first bytes of the next; a
    run out of step can pass a check or two). Out of step, the decoder moves one byte at a
    time and takes the stream again only where ``RESYNC_SAMPLES`` consecutive samples fit
    and, when the loss was short, the first of them is where the lidar should be by then
    (the last angle taken plus the samples skipped times the measured step); in step, each
    of them is checked again. A new stream starts out of step.

    ``feed(data)`` returns arrays (start flag, quality, angle [deg], distance [mm]) of the
    samples taken. ``skipped`` counts bytes dropped, ``sync_losses`` the losses of
    synchronisation, ``samples`` the samples taken.
    """

    #: Consecutive consistent samples that take an out-of-step stream again.
    RESYNC_SAMPLES = 4
    #: Largest angle step between consecutive samples [deg * 64]: 10 deg, five times the
    #: A1's step at its fastest rotation (10 Hz, 2000 samples/s: 1.8 deg).
    MAX_STEP_Q6 = 10 * 64
    #: A loss shorter than this many samples resumes where the lidar should be by then.
    EXPECT_WITHIN = 100
    #: How far from there it may resume [deg * 64]: a step and a half, at least 2 deg.
    EXPECT_SLACK_Q6 = 2 * 64

    def __init__(self) -> None:
        self._buf = bytearray()
        self.samples = 0
        self.skipped = 0
        self.sync_losses = 0
        self._locked = False
        self._fresh = False            # just locked: the first sample has no predecessor
        self._offset = 0               # stream position of _buf[0] [bytes]
        self._last: int | None = None  # angle_q6 of the last sample taken
        self._last_at = 0              # its stream position [bytes]
        self._step = 0.0               # measured angle step [deg * 64 per sample], 0: none

    def reset(self) -> None:
        """Forget the stream (a new one starts, out of step); the counters stay."""
        self._buf.clear()
        self._locked = False
        self._offset = 0
        self._last = None
        self._step = 0.0

    def feed(self, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Take ``data``; return (start, quality, angle_deg, distance_mm) arrays."""
        buf = self._buf
        buf += data
        out = bytearray()
        i, n = 0, len(buf)
        while True:
            if self._locked:
                i, lost = self._take_in_step(i, n, out)
                if not lost:
                    break
            elif not self._resumes_at(i, n):
                # no consistent run here: step on, or wait for the bytes of a whole run
                if i + self.RESYNC_SAMPLES * SAMPLE_SIZE > n:
                    break
                self.skipped += 1
                i += 1
        del buf[:i]
        self._offset += i
        self.samples += len(out) // SAMPLE_SIZE
        return decode_samples(bytes(out))

    def _take_in_step(self, i: int, n: int, out: bytearray) -> tuple[int, bool]:
        """Check the whole samples from ``i``; take all but the last consistent one.

        Returns the new position and whether synchronisation was lost there.
        """
        k = (n - i) // SAMPLE_SIZE
        hold = self.RESYNC_SAMPLES - 1
        if k <= hold:
            return i, False
        h = np.frombuffer(self._buf, np.uint8, k * SAMPLE_SIZE, i).reshape(k, SAMPLE_SIZE)
        angle = (h[:, 1].astype(np.int64) | h[:, 2].astype(np.int64) << 8) >> 1
        header = ((h[:, 0] ^ (h[:, 0] >> 1)) & h[:, 1] & 1).astype(bool)
        del h  # a view: the buffer cannot be resized while it lives
        before = np.empty(k, np.int64)
        before[1:] = angle[:-1]
        # the first sample: its run was checked when the stream was taken, or it was
        # checked against the last sample taken when it was held back
        before[0] = angle[0] - 1 if self._fresh or self._last is None else self._last
        step = (angle - before) % FULL_TURN_Q6
        ok = header & (angle < FULL_TURN_Q6) & (step > 0) & (step <= self.MAX_STEP_Q6)
        j = k if ok.all() else int(np.argmin(ok))  # samples [0, j) are consistent
        take = max(0, j - hold)  # the last ones wait for their successors' checks
        if take:
            out += self._buf[i:i + take * SAMPLE_SIZE]
            measured = step[int(self._fresh):take]
            if len(measured):
                m = float(np.median(measured))
                self._step = m if not self._step else 0.9 * self._step + 0.1 * m
            self._fresh = False
            self._last = int(angle[take - 1])
            self._last_at = self._offset + i + (take - 1) * SAMPLE_SIZE
        held = i + take * SAMPLE_SIZE
        if j == k:
            return held, False
        # sample j does not fit; the held ones before it may hold its bytes (a truncated
        # sample keeps its header, and a run out of step can pass a check or two): drop
        # them, search from the byte after the first one's start
        self.sync_losses += 1
        self._locked = False
        self.skipped += 1
        return held + 1, True

    def _resumes_at(self, i: int, n: int) -> bool:
        """Whether the stream is taken again at ``i`` (then it is, in step from there)."""
        size, count = SAMPLE_SIZE, self.RESYNC_SAMPLES
        if i + count * size > n:
            return False
        buf = self._buf
        angles: list[int] = []
        for m in range(count):
            p = i + m * size
            b0, b1 = buf[p], buf[p + 1]
            angle = (b1 | buf[p + 2] << 8) >> 1
            if not ((b0 ^ (b0 >> 1)) & 1 and b1 & 1) or angle >= FULL_TURN_Q6:
                return False
            if angles and not 0 < (angle - angles[-1]) % FULL_TURN_Q6 <= self.MAX_STEP_Q6:
                return False
            angles.append(angle)
        if self._last is not None and self._step:
            gap = (self._offset + i - self._last_at) / size  # samples since the last taken
            if gap <= self.EXPECT_WITHIN:
                expected = self._last + gap * self._step
                half = FULL_TURN_Q6 / 2
                miss = abs((angles[0] - expected + half) % FULL_TURN_Q6 - half)
                if miss > max(self.EXPECT_SLACK_Q6, 1.5 * self._step):
                    return False
        self._locked = self._fresh = True
        return True


_SAMPLE_DTYPE = np.dtype([('b0', 'u1'), ('angle', '<u2'), ('dist', '<u2')])


def decode_samples(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Decode whole, valid samples: (start, quality, angle_deg, distance_mm) arrays."""
    a = np.frombuffer(data, dtype=_SAMPLE_DTYPE)
    return ((a['b0'] & 1).astype(bool), (a['b0'] >> 2).astype(np.int64),
            (a['angle'] >> 1) / 64.0, a['dist'] / 4.0)


NO_SAMPLES = decode_samples(b'')
