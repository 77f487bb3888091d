"""Slamtec RPLidar A1 over a serial port (USB adapter, 115200 8N1): ``scan`` per revolution.

Protocol (Slamtec, "RPLIDAR Interface Protocol and Application Notes"; checked against the
vendor SDK, github.com/Slamtec/rplidar_sdk: ``sdk/include/sl_lidar_cmd.h``,
``sdk/include/sl_lidar_protocol.h``, ``sdk/src/sl_lidarprotocol_codec.cpp``,
``sdk/src/sl_lidar_driver.cpp``, ``sdk/src/dataunpacker/unpacker/handler_normalnode.cpp``):

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
  [deg * 64], distance_q2 = u16(bytes 3..4) [mm * 4], 0 = no return. The SDK's unpacker
  resynchronises by dropping a byte whenever S == !S or C == 0; so does ``ScanDecoder``.
- Motor: on the A1 USB adapter the motor runs while DTR is *not* asserted
  (``setMotorSpeed``: speed 0 -> ``setDTR(true)``, otherwise ``setDTR(false)``; pyserial
  asserts DTR on open, so the motor is off until the driver clears it).

A1 figures (Slamtec, "RPLIDAR A1 ... Introduction and Datasheet", model A1M8, measurement
performance table): distance range 0.15-12 m, scan rate 1-10 Hz (5.5 Hz typical, 360 samples
a scan, 1 deg resolution), sample duration 0.5 ms (2000 samples/s; up to 8000 in the express
modes this driver does not use); angles grow clockwise seen from above (a left-handed frame).

Frames: the lidar reports angles clockwise from its own 0 deg mark; ``mount`` (x, y [m], yaw
[rad] of the 0 deg mark in ``base_link``) and ``flip`` (mounted upside down: the rotation
looks counter-clockwise from above) put each return in ``base_link`` (FLU), and the returns
of one revolution are binned by their bearing from the ``base_link`` origin into ``bins``
rays of a fixed increment (the nearest return wins, ``inf`` where none). The scan's stamp is the
node-clock time at which the revolution's first sample arrived (the read's time less one
sample period per sample read after it); ``scan_time`` the measured revolution;
``time_increment`` is 0 (rays re-binned in the vessel frame have no order).

Threads: ``open_device`` opens the port and starts a reader thread, which runs the start-up
exchange (STOP, GET_INFO with the identity check, GET_HEALTH with one RESET on an error
status, motor on, SCAN) and then streams. Every wait is bounded (``response_timeout``,
``stall_timeout``); a failure ends the thread with a ``DeviceError`` naming the port and
what was read, which the supervision timer hands to ``device_fault`` (close, backoff,
reconnect: STOP and SCAN again, the port looked up again, so a re-plugged device or a new
emulator pty is found). Opening the port proves nothing (a dead or wrong device opens too):
the lidar is back, and the retry delay starts over, on its first whole revolution; bytes
that make no valid sample for ``stall_timeout`` are a stall like silence. Scans are
published from the reader thread; the executor only runs the supervision timer.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import errno
import math
import struct
import threading
import time
from typing import Any, NamedTuple

import numpy as np
from sensor_msgs.msg import LaserScan

from enbarr_core.framework.driver import SensorDriver, WARN
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.transport.serial_link import open_serial

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
#: Extra wait for the first sample after SCAN [s]: the motor, started with SCAN, must reach
#: its speed first (the SDK's examples start the motor and scan at once, then wait for data).
MOTOR_SPINUP = 2.0
#: The reader sleeps this long between reads [s] and then takes what arrived (100 samples
#: at 2000 samples/s; the stamps are corrected by the sample period, so only the scan's
#: publication waits): here a read per 20 ms cost 2.4 % of a core, per 50 ms 1.2 %.
POLL_PERIOD = 0.05
#: Waits the protocol document asks for after STOP and RESET [s] (1 ms, 2 ms); longer here,
#: the A1 reboots after RESET.
STOP_WAIT = 0.002
RESET_WAIT = 0.5


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


def encode_descriptor(length: int, mode: int, dtype: int) -> bytes:
    """Encode the 7 bytes of a response descriptor."""
    return bytes((SYNC, ANS_SYNC)) + struct.pack('<IB', (length & 0x3FFFFFFF) | (mode << 30),
                                                  dtype)


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


def encode_sample(start: bool, quality: int, angle_deg: float, distance_mm: float) -> bytes:
    """Encode the 5 bytes of one SCAN sample."""
    s = 1 if start else 0
    angle_q6 = int(round(angle_deg * 64.0)) & 0x7FFF
    dist_q2 = min(0xFFFF, max(0, int(round(distance_mm * 4.0))))
    return struct.pack('<BHH', (quality & 0x3F) << 2 | (s ^ 1) << 1 | s,
                       angle_q6 << 1 | 1, dist_q2)


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


_NO_SAMPLES = decode_samples(b'')


# -- the start-up exchange (shared by the node's reader thread and check_device) -------------
def _write(ser: Any, port: str, data: bytes, what: str) -> None:
    try:
        ser.write(data)
    except Exception as err:  # noqa: BLE001 - SerialException, SerialTimeoutException, OSError
        raise DeviceError(f'{port}: cannot send {what}: {err}') from err


def _read_exact(ser: Any, port: str, n: int, deadline: float, what: str) -> bytes:
    got = bytearray()
    while len(got) < n:
        if time.monotonic() > deadline:
            raise DeviceError(f'{port}: no answer to {what} (read {len(got)} of {n} bytes: '
                              f'{got.hex(" ") or "nothing"})')
        try:
            got += ser.read(n - len(got))
        except Exception as err:  # noqa: BLE001 - SerialException, OSError (unplugged)
            raise DeviceError(f'{port}: read failed during {what}: {err}') from err
    return bytes(got)


def read_descriptor(ser: Any, port: str, deadline: float, what: str) -> Descriptor:
    """Wait for ``A5 5A`` (bytes before it are skipped, as the SDK does) and the descriptor."""
    prev = -1
    while True:
        b = _read_exact(ser, port, 1, deadline, what)[0]
        if prev == SYNC and b == ANS_SYNC:
            break
        prev = b
    rest = _read_exact(ser, port, DESCRIPTOR_SIZE - 2, deadline, what)
    return decode_descriptor(bytes((SYNC, ANS_SYNC)) + rest)


def command(ser: Any, port: str, cmd: int, size: int, dtype: int, timeout: float,
            name: str) -> bytes:
    """Send ``cmd``; check its descriptor (single response of ``size`` bytes of ``dtype``)."""
    _write(ser, port, request(cmd), name)
    deadline = time.monotonic() + timeout
    d = read_descriptor(ser, port, deadline, name)
    if d != Descriptor(size, MODE_SINGLE, dtype):
        raise DeviceError(f'{port}: {name}: unexpected response descriptor {d} (expected '
                          f'{Descriptor(size, MODE_SINGLE, dtype)})')
    return _read_exact(ser, port, size, deadline, name)


def stop(ser: Any, port: str) -> None:
    """STOP, wait, and drop what was still on its way (scan samples)."""
    _write(ser, port, request(CMD_STOP), 'STOP')
    time.sleep(STOP_WAIT)
    try:
        ser.reset_input_buffer()
    except Exception as err:  # noqa: BLE001
        raise DeviceError(f'{port}: cannot flush the input: {err}') from err


def handshake(ser: Any, port: str, timeout: float) -> tuple[DeviceInfo, Health, int]:
    """STOP, GET_INFO (an A1 or ``DeviceError``), GET_HEALTH (one RESET on an error status).

    Returns the identity, the health and how many RESETs were sent (0 or 1).
    """
    stop(ser, port)
    info = DeviceInfo.decode(command(ser, port, CMD_GET_INFO, INFO_SIZE, ANS_TYPE_DEVINFO,
                                     timeout, 'GET_INFO'))
    if info.model >> 4 != A1_MAJOR:
        raise DeviceError(f'{port}: GET_INFO read model 0x{info.model:02X} '
                          f'({info.model_name}), not an RPLidar A1 (0x1X): wrong device on '
                          'this port?')
    health = Health.decode(command(ser, port, CMD_GET_HEALTH, HEALTH_SIZE, ANS_TYPE_DEVHEALTH,
                                   timeout, 'GET_HEALTH'))
    resets = 0
    if health.status == STATUS_ERROR:
        resets = 1
        _write(ser, port, request(CMD_RESET), 'RESET')
        time.sleep(RESET_WAIT)
        stop(ser, port)
        health = Health.decode(command(ser, port, CMD_GET_HEALTH, HEALTH_SIZE,
                                       ANS_TYPE_DEVHEALTH, timeout, 'GET_HEALTH'))
        if health.status == STATUS_ERROR:
            raise DeviceError(f'{port}: {health.describe()} persists after RESET')
    return info, health, resets


def set_motor(ser: Any, port: str, on: bool) -> bool:
    """Motor on (DTR cleared) or off (DTR asserted): the A1 USB adapter's motor line.

    False when the port has no modem lines (a pty, as pyserial itself tolerates at open:
    ``EINVAL``/``ENOTTY``); other failures are a ``DeviceError``.
    """
    try:
        ser.dtr = not on
    except OSError as err:
        if err.errno in (errno.EINVAL, errno.ENOTTY):
            return False
        raise DeviceError(f'{port}: cannot set DTR (motor {"on" if on else "off"}): '
                          f'{err}') from err
    except Exception as err:  # noqa: BLE001 - SerialException
        raise DeviceError(f'{port}: cannot set DTR (motor {"on" if on else "off"}): '
                          f'{err}') from err
    return True


def start_scan(ser: Any, port: str, timeout: float) -> bool:
    """Motor on, SCAN, and check the stream's descriptor; return whether DTR could be set."""
    motor_line = set_motor(ser, port, True)
    _write(ser, port, request(CMD_SCAN), 'SCAN')
    d = read_descriptor(ser, port, time.monotonic() + timeout, 'SCAN')
    expected = Descriptor(SAMPLE_SIZE, MODE_MULTI, ANS_TYPE_MEASUREMENT)
    if d != expected:
        raise DeviceError(f'{port}: SCAN: unexpected response descriptor {d} (expected '
                          f'{expected})')
    return motor_line


def resolve_port(port: str) -> str:
    """Return the path to open: ``port``, or the pty of the emulator ``emulated`` names."""
    if emulation.is_emulated(port):
        return emulation.lookup('serial', port)
    return port


# -- geometry: one revolution into a LaserScan in base_link -----------------------------------
@dataclass(frozen=True)
class Mount:
    """Pose of the lidar's 0 deg mark in ``base_link``: x, y [m], yaw [rad].

    ``flip``: mounted upside down.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    flip: bool = False

    def world_angles(self, angle_deg: np.ndarray) -> np.ndarray:
        """Bearing in ``base_link`` [rad, CCW] of the lidar's clockwise angles [deg]."""
        theta = np.radians(angle_deg)
        return self.yaw + (theta if self.flip else -theta)


def bin_revolution(angle_deg: np.ndarray, distance_mm: np.ndarray, mount: Mount,
                   bins: int) -> np.ndarray:
    """Ranges [m] of ``bins`` rays from -pi, CCW, from the ``base_link`` origin (inf: none).

    Each return is placed in ``base_link`` with the mount pose, then given to the ray nearest
    its bearing; the nearest return of a ray wins.
    """
    r = np.asarray(distance_mm, dtype=float) * 1e-3
    valid = r > 0.0
    phi = mount.world_angles(np.asarray(angle_deg, dtype=float)[valid])
    r = r[valid]
    px = mount.x + r * np.cos(phi)
    py = mount.y + r * np.sin(phi)
    inc = 2.0 * math.pi / bins
    idx = np.rint((np.arctan2(py, px) + math.pi) / inc).astype(np.int64) % bins
    ranges = np.full(bins, np.inf)
    np.minimum.at(ranges, idx, np.hypot(px, py))
    return ranges


class RevolutionAssembler:
    """Collects samples between start flags; ``add`` returns finished revolutions.

    Samples before the first start flag are dropped (a partial revolution), as the SDK does.
    The protocol has no checksum, so a stream out of step can pass bogus samples with start
    flags: a start flag less than ``min_samples`` after the last one is ignored and counted
    (``false_starts``), samples at angles of 360 deg or more are dropped (``invalid``), and a
    revolution longer than ``max_samples`` (start flags lost) is dropped (``dropped``).
    """

    class Revolution(NamedTuple):
        """One revolution: its start stamp [ns], duration [s], angles [deg], distances."""

        stamp_ns: int
        duration: float
        angle_deg: np.ndarray
        distance_mm: np.ndarray

    def __init__(self, min_samples: int = 50, max_samples: int = 8000) -> None:
        self.min_samples = min_samples
        self.max_samples = max_samples
        self.dropped = 0
        self.false_starts = 0
        self.invalid = 0
        self._stamp: int | None = None
        self._angles: list[np.ndarray] = []
        self._dists: list[np.ndarray] = []
        self._count = 0

    def add(self, start: np.ndarray, angle_deg: np.ndarray, distance_mm: np.ndarray,
            stamp_ns: int, period_ns: int = 0) -> list[RevolutionAssembler.Revolution]:
        """Take the samples of one read; the last was read at ``stamp_ns``.

        Sample k of m is taken ``(m - 1 - k) * period_ns`` earlier (the lidar's sample
        period), which dates a revolution's first sample within a read.
        """
        ok = angle_deg < 360.0
        if not ok.all():
            self.invalid += int((~ok).sum())
            start, angle_deg, distance_mm = start[ok], angle_deg[ok], distance_mm[ok]
        out = []
        pos = 0
        m = len(start)
        for k in np.flatnonzero(start):
            t = stamp_ns - (m - 1 - int(k)) * period_ns
            if self._stamp is not None:
                if self._count + (k - pos) < self.min_samples:
                    self.false_starts += 1
                    continue
                self._append(angle_deg[pos:k], distance_mm[pos:k])
                if self._stamp is not None:
                    out.append(self.Revolution(
                        self._stamp, max(0.0, (t - self._stamp) * 1e-9),
                        np.concatenate(self._angles), np.concatenate(self._dists)))
            self._stamp = t
            self._angles, self._dists, self._count = [], [], 0
            pos = int(k)
        if self._stamp is not None:
            self._append(angle_deg[pos:], distance_mm[pos:])
        return out

    def reset(self) -> None:
        """Forget the revolution in progress (a new stream starts); the counters stay."""
        self._stamp = None
        self._angles, self._dists, self._count = [], [], 0

    def _append(self, a: np.ndarray, d: np.ndarray) -> None:
        if not len(a):
            return
        self._angles.append(a)
        self._dists.append(d)
        self._count += len(a)
        if self._count > self.max_samples:
            self.dropped += 1
            self._stamp = None
            self._angles, self._dists, self._count = [], [], 0


# -- the node ------------------------------------------------------------------------------
SPECS = [
    ParamSpec('port', '/dev/ttyUSB0', "Serial port of the lidar's USB adapter, or emulated[:NAME]",
              read_only=True),
    ParamSpec('mount.x', 0.0, "Lidar centre ahead of base_link's origin", 'm', -20.0, 20.0),
    ParamSpec('mount.y', 0.0, "Lidar centre left of base_link's origin", 'm', -20.0, 20.0),
    ParamSpec('mount.yaw', 0.0, "Direction of the lidar's 0 deg mark, CCW from base_link +x",
              'rad', -math.pi, math.pi),
    ParamSpec('flip', False, 'Mounted upside down (the rotation then looks CCW from above)'),
    ParamSpec('bins', 360, 'Rays per revolution in the published scan (fixed increment '
              '2 pi / bins)', '', 36, 7200, read_only=True),
    ParamSpec('min_quality', 0, 'Returns of lower quality are ignored', '', 0, 63),
    ParamSpec('response_timeout', 0.5, 'Longest wait for the answer to a request', 's', 0.01,
              10.0),
    ParamSpec('stall_timeout', 1.0, 'No valid scan sample for this long is a fault (reconnect)',
              's', 0.05, 60.0),
]


@dataclass(frozen=True)
class RplidarSettings:
    """Settings of ``RplidarNode`` (see ``SPECS``)."""

    port: str
    mount: Mount
    bins: int
    min_quality: int
    response_timeout: float  # [s]
    stall_timeout: float     # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> RplidarSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if not v['port'].strip():
            raise ValueError('port: empty; a serial port such as /dev/ttyUSB0, or emulated')
        return cls(v['port'], Mount(v['mount.x'], v['mount.y'], v['mount.yaw'],
                                    bool(v['flip'])),
                   int(v['bins']), int(v['min_quality']), v['response_timeout'],
                   v['stall_timeout'])


class RplidarNode(SensorDriver):
    """See the module docstring."""

    #: Opening the port only starts the reader: the lidar is back on its first revolution.
    confirmed_by_open = False

    def __init__(self, node_name: str = 'rplidar', **kwargs: Any) -> None:
        super().__init__(node_name, sample_timeout=1.0, **kwargs)
        self.settings: RplidarSettings
        self.bind_settings(SPECS, RplidarSettings.from_params, self._apply)
        self.device = self.settings.port
        self.info: DeviceInfo | None = None
        self.health: Health | None = None
        self.resets = 0
        self.revolutions = 0
        self.state = 'closed'
        self.motor_line = True
        self.decoder = ScanDecoder()
        self.assembler = RevolutionAssembler()
        self._losses_reported = 0
        self._serial: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: DeviceError | None = None
        self._pub = self.create_topic_publisher(topics.SCAN)

    def _apply(self, settings: RplidarSettings) -> None:
        self.settings = settings

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the port (looked up again each time) and start the reader thread."""
        port = self.settings.port
        path = resolve_port(port)
        self.device = port if path == port else f'{port} ({path})'
        self._serial = open_serial(path, BAUDRATE, timeout=0.05)
        self._error = None
        self._stop.clear()
        self.decoder.reset()
        self.assembler.reset()
        self.state = 'starting'
        self._thread = threading.Thread(target=self._run, args=(self._serial,),
                                        name=f'{self.get_name()}_reader', daemon=True)
        self._thread.start()

    def close_device(self) -> None:
        """Stop the reader, then STOP and motor off (best effort) and close the port."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(2.0)
        ser, self._serial = self._serial, None
        self.state = 'closed'
        if ser is None:
            return
        try:
            ser.write(request(CMD_STOP))
            set_motor(ser, self.device, False)
        except Exception:  # noqa: BLE001 - the device may be gone
            pass
        try:
            ser.close()
        except Exception:  # noqa: BLE001
            pass

    def supervise(self) -> None:
        """Hand a failure of the reader thread to ``device_fault`` (executor thread)."""
        err = self._error
        if err is not None and self.connected:
            self._error = None
            self.device_fault(err)

    def _run(self, ser: Any) -> None:
        name = self.device
        try:
            s = self.settings
            self.info, self.health, resets = handshake(ser, name, s.response_timeout)
            self.resets += resets
            if resets:
                self.get_logger().warn(f'{name}: health error cleared by RESET')
            elif self.health.status == STATUS_WARNING:
                self.get_logger().warn(f'{name}: {self.health.describe()}')
            self.motor_line = start_scan(ser, name, s.response_timeout)
            if not self.motor_line:
                self.get_logger().warn(f'{name}: no DTR line (a pty?): the motor is not '
                                       'switched by this driver')
            self.get_logger().info(f'{name}: {self.info.describe()}, '
                                   f'{self.health.describe()}: scanning')
            self.state = 'scanning'
            self._stream(ser, name)
        except DeviceError as err:
            if not self._stop.is_set():
                self._error = err
        except Exception as err:  # noqa: BLE001 - a bug must still reach /diagnostics
            if not self._stop.is_set():
                self._error = DeviceError(f'{name}: reader failed: {err!r}')

    def _stream(self, ser: Any, name: str) -> None:
        last = time.monotonic() + MOTOR_SPINUP  # the first sample waits for the motor
        clock = self.get_clock()
        period_ns = SAMPLE_PERIOD_NS
        while not self._stop.is_set():
            self._stop.wait(POLL_PERIOD)  # let samples gather: one read per period
            try:
                data = ser.read(max(1, ser.in_waiting))
            except Exception as err:  # noqa: BLE001 - SerialException, OSError (unplugged)
                raise DeviceError(f'{name}: read failed (unplugged?): {err}') from err
            now = time.monotonic()
            start, quality, angle, dist = self.decoder.feed(data) if data else _NO_SAMPLES
            if not len(start):
                # bytes that never make a sample (noise, a wrong device) are no sign of life
                stall = self.settings.stall_timeout
                if now - last > stall:
                    raise DeviceError(
                        f'{name}: no scan data for {stall:.3g} s (stalled)' if not data
                        else f'{name}: no valid scan sample for {stall:.3g} s '
                        f'({self.decoder.skipped} bytes skipped: noise on the line?)')
                continue
            last = now
            stamp_ns = clock.now().nanoseconds
            if self.settings.min_quality:
                dist = np.where(quality >= self.settings.min_quality, dist, 0.0)
            for rev in self.assembler.add(start, angle, dist, stamp_ns, period_ns):
                self.device_confirmed()  # a whole revolution: the lidar is back
                self._publish(rev)
                n = len(rev.angle_deg)
                if n and rev.duration > 0.0:  # the lidar's sample period, measured
                    period_ns = min(5_000_000, max(100_000, round(rev.duration * 1e9 / n)))

    def _publish(self, rev: RevolutionAssembler.Revolution) -> None:
        if not self.started:  # a source: silent before start and after stop
            return
        s = self.settings
        msg = LaserScan()
        convert.ns_to_stamp(rev.stamp_ns, msg.header.stamp)
        msg.header.frame_id = topics.SCAN.frame
        inc = 2.0 * math.pi / s.bins
        msg.angle_min = -math.pi
        msg.angle_increment = inc
        msg.angle_max = -math.pi + (s.bins - 1) * inc
        msg.time_increment = 0.0
        msg.scan_time = rev.duration
        offset = math.hypot(s.mount.x, s.mount.y)
        msg.range_min = max(0.0, RANGE_MIN - offset)
        msg.range_max = RANGE_MAX + offset
        msg.ranges = bin_revolution(rev.angle_deg, rev.distance_mm, s.mount, s.bins).tolist()
        self._pub.publish(msg)
        self.revolutions += 1
        self.sample_received()

    # -- diagnostics -------------------------------------------------------------------------
    def status(self) -> tuple[int, str]:
        """ERROR while faulted, WARN while samples are late or sync was lost, else OK."""
        level, message = super().status()
        losses = self.decoder.sync_losses
        new, self._losses_reported = losses - self._losses_reported, losses
        if level < WARN and new > 0:
            return WARN, f'sync lost {new} times in the last report period (resynchronised)'
        return level, message

    def status_values(self) -> dict[str, Any]:
        """Identity, health and the stream's counters."""
        info, health = self.info, self.health
        return {**super().status_values(), 'state': self.state,
                'model': info.model_name if info else '',
                'firmware': f'{info.firmware[0]}.{info.firmware[1]:02d}' if info else '',
                'serial_number': info.serial if info else '',
                'health': health.describe() if health else '', 'resets': self.resets,
                'motor_line': self.motor_line,
                'revolutions': self.revolutions, 'scan_samples': self.decoder.samples,
                'sync_losses': self.decoder.sync_losses,
                'skipped_bytes': self.decoder.skipped,
                'dropped_revolutions': self.assembler.dropped,
                'false_starts': self.assembler.false_starts,
                'invalid_samples': self.assembler.invalid}


def check_device(target: Any) -> list[str]:
    """``enbarr check-device rplidar --port PORT``: identity, health, one revolution."""
    port = target.port or '/dev/ttyUSB0'
    emulator = None
    if emulation.is_emulated(port):
        from enbarr_plugins.lidar.rplidar_emulator import RplidarEmulator
        emulator = RplidarEmulator()
        emulator.start()
        path = emulator.path
    else:
        path = port
    try:
        ser = open_serial(path, BAUDRATE, timeout=0.05)
        try:
            info, health, resets = handshake(ser, port, target.timeout)
            start_scan(ser, port, target.timeout)
            decoder, assembler = ScanDecoder(), RevolutionAssembler()
            deadline = time.monotonic() + target.timeout
            revs: list[RevolutionAssembler.Revolution] = []
            while not revs:
                if time.monotonic() > deadline:
                    raise DeviceError(f'{port}: no full revolution within {target.timeout} s '
                                      f'({decoder.samples} samples, {decoder.sync_losses} '
                                      'sync losses)')
                start, _, angle, dist = decoder.feed(ser.read(max(1, ser.in_waiting)))
                revs = assembler.add(start, angle, dist, time.monotonic_ns())
            stop(ser, port)
            set_motor(ser, port, False)
        finally:
            ser.close()
    finally:
        if emulator is not None:
            emulator.stop()
    rev = revs[0]
    hits = rev.distance_mm > 0
    lines = [f'{port}: {info.describe()}', f'{port}: {health.describe()}'
             + (' (after RESET)' if resets else '')]
    line = (f'{port}: one revolution: {len(rev.angle_deg)} samples in {rev.duration:.3f} s, '
            f'{int(hits.sum())} returns')
    if hits.any():
        k = int(np.argmin(np.where(hits, rev.distance_mm, np.inf)))
        line += (f', nearest {rev.distance_mm[k] / 1000.0:.2f} m at '
                 f'{rev.angle_deg[k]:.1f} deg')
    return lines + [line]
