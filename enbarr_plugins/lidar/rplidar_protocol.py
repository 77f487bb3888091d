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
  so does ``ScanDecoder``.

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

class ScanDecoder:
    """Cuts a SCAN stream into samples, resynchronising like the SDK (see module doc).

    One check more than the SDK: after a loss of synchronisation a candidate sample is taken
    only when the header of the sample after it is plausible too, so that a misaligned byte
    run rarely passes for a sample (1 in 16 instead of 1 in 4 per position).

    ``feed(data)`` returns arrays (start flag, quality, angle [deg], distance [mm]) of the
    samples completed. ``skipped`` counts bytes dropped, ``sync_losses`` the runs of them
    (one per loss of synchronisation), ``samples`` the good samples.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.samples = 0
        self.skipped = 0
        self.sync_losses = 0
        self._in_loss = False

    def reset(self) -> None:
        """Forget a partial sample (a new stream starts); the counters stay."""
        self._buf.clear()
        self._in_loss = False

    def feed(self, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Take ``data``; return (start, quality, angle_deg, distance_mm) arrays."""
        buf = self._buf
        buf += data
        out = bytearray()
        i, n = 0, len(buf)
        while i + SAMPLE_SIZE <= n:
            if not self._in_loss:
                # in step: check every whole sample at once, take those before the first bad
                k = (n - i) // SAMPLE_SIZE
                h = np.frombuffer(buf, np.uint8, k * SAMPLE_SIZE, i).reshape(k, SAMPLE_SIZE)
                ok = ((h[:, 0] ^ (h[:, 0] >> 1)) & h[:, 1] & 1).astype(bool)
                del h  # a view: the buffer cannot be resized while it lives
                j = k if ok.all() else int(np.argmin(ok))
                out += buf[i:i + j * SAMPLE_SIZE]
                i += j * SAMPLE_SIZE
                if j == k:
                    break
                self.sync_losses += 1
                self._in_loss = True
            if _plausible(buf, i):
                # after a loss, a candidate counts only when the next sample's header is
                # plausible too (the single check passes by chance 1 time in 4)
                if i + 2 * SAMPLE_SIZE > n:
                    break  # wait for more bytes
                if _plausible(buf, i + SAMPLE_SIZE):
                    self._in_loss = False
                    continue
            self.skipped += 1
            i += 1
        del buf[:i]
        self.samples += len(out) // SAMPLE_SIZE
        return decode_samples(bytes(out))


def _plausible(buf: bytearray, i: int) -> bool:
    """Whether a sample may start at ``buf[i]``: S != !S and C == 1."""
    b0 = buf[i]
    return bool((b0 ^ (b0 >> 1)) & 1 and buf[i + 1] & 1)


_SAMPLE_DTYPE = np.dtype([('b0', 'u1'), ('angle', '<u2'), ('dist', '<u2')])


def decode_samples(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Decode whole, valid samples: (start, quality, angle_deg, distance_mm) arrays."""
    a = np.frombuffer(data, dtype=_SAMPLE_DTYPE)
    return ((a['b0'] & 1).astype(bool), (a['b0'] >> 2).astype(np.int64),
            (a['angle'] >> 1) / 64.0, a['dist'] / 4.0)


NO_SAMPLES = decode_samples(b'')
