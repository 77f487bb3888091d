"""An RPLidar A1 on a pseudo-terminal: the real byte protocol, ranges ray-cast in the world.

``RplidarEmulator`` serves the master side of a pty (``os.openpty``, raw) on its own thread;
a driver opens the slave path with pyserial exactly like ``/dev/ttyUSB0``. It answers STOP,
RESET, SCAN, GET_INFO and GET_HEALTH with the descriptors and payloads of the Slamtec
protocol document (see ``enbarr_plugins.lidar.rplidar_protocol`` for the layout and its
sources; this module keeps its own copy of the bytes): an A1M8 (model ``0x18``), firmware
1.29, hardware 7; SCAN streams 5-byte samples at ``sample_rate`` (2000 samples/s, the A1's
legacy SCAN rate) and ``rotation_hz`` (5.5 Hz, so about 364 samples a revolution), the start
flag on the first sample of each revolution.

Ranges are ray-cast from the lidar's pose (the vessel pose ``set_pose`` gives, usually from
``sim/odometry``, and the mounting pose ``mount``/``flip``, the profile's ``laser`` frame)
in a ``World`` (``enbarr_core.world``: the node's is the profile's ``world`` section, at the
world time of the node clock, so moving obstacles move), exactly, without the A1's range
error. No return (distance 0, quality 0) beyond 12 m or nearer than 0.15 m.

Faults for tests and demonstrations: ``unplug()``/``replug()`` (the pty closes; a new one,
under the same registered name, opens), ``corrupt(n)`` (the next n samples with S == !S),
``truncate(n)`` (the next n samples cut to 3 bytes), ``stall(True)`` (silent: no answer, no
sample), ``noise(True)`` (random bytes instead of samples), ``model`` (GET_INFO reports
another model, e.g. ``0x61`` an S-series), ``health`` (GET_HEALTH reports an error; a RESET
clears it unless ``health_sticky``).

A pty carries no modem lines: the emulator cannot see DTR, so its motor always "runs"; the
driver's DTR calls are tested on its pyserial object instead.

``RplidarEmulatorNode`` wraps it for profiles (``emulator_node.DeviceEmulatorNode``): when
started it opens the pty and registers it as the ``serial`` emulator ``name`` (``port:
emulated`` or ``emulated:NAME`` in the driver); it follows ``sim/odometry`` and reports what
it received and sent on ``/diagnostics``. A profile without a ``world`` leaves the A1 in empty
space: every sample is a no-return.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math
import os
import select
import struct
import threading
import time
import tty
from typing import Any

import numpy as np

from enbarr_core.framework.params import ParamSpec
from enbarr_core.world.model import EMPTY_WORLD, World
from enbarr_plugins.emulator_node import commands_line, DeviceEmulatorNode

# The emulator's own copy of the bytes, typed from Slamtec's "RPLIDAR Interface Protocol and
# Application Notes" (A1 & A2, rev 1.1) and the SDK's sl_lidar_cmd.h / sl_lidar_protocol.h,
# not imported from the driver's protocol module: a wrong constant there must meet a device
# that speaks the document. test_rplidar_protocol pins both to the document's numbers.
SYNC = 0xA5                 # request and descriptor start byte
ANS_SYNC = 0x5A             # second descriptor byte
CMDFLAG_HAS_PAYLOAD = 0x80  # requests with SIZE, PAYLOAD and CHECKSUM
CMD_STOP = 0x25
CMD_SCAN = 0x20
CMD_FORCE_SCAN = 0x21       # answered like SCAN
CMD_RESET = 0x40
CMD_GET_INFO = 0x50
CMD_GET_HEALTH = 0x52
ANS_TYPE_DEVINFO = 0x04
ANS_TYPE_DEVHEALTH = 0x06
ANS_TYPE_MEASUREMENT = 0x81
MODE_SINGLE, MODE_MULTI = 0, 1  # send mode, the descriptor's top two bits
STATUS_OK, STATUS_ERROR = 0, 2
#: A1M8 range [m] (Slamtec, "RPLIDAR A1 Introduction and Datasheet"): no return outside it.
RANGE_MIN, RANGE_MAX = 0.15, 12.0


def encode_descriptor(length: int, mode: int, dtype: int) -> bytes:
    """Encode a response descriptor: A5 5A, u32 length | mode << 30, data type (7 bytes)."""
    return bytes((SYNC, ANS_SYNC)) + struct.pack('<IB', (length & 0x3FFFFFFF) | (mode << 30),
                                                  dtype)


def encode_sample(start: bool, quality: int, angle_deg: float, distance_mm: float) -> bytes:
    """Encode one SCAN sample (5 bytes).

    quality << 2 | !S << 1 | S, then angle_q6 << 1 | C (the check bit C always 1), then
    distance_q2, little-endian.
    """
    s = 1 if start else 0
    angle_q6 = int(round(angle_deg * 64.0)) & 0x7FFF
    dist_q2 = min(0xFFFF, max(0, int(round(distance_mm * 4.0))))
    return struct.pack('<BHH', (quality & 0x3F) << 2 | (s ^ 1) << 1 | s,
                       angle_q6 << 1 | 1, dist_q2)


@dataclass(frozen=True)
class Mount:
    """Where the emulated lidar sits on the vessel: its 0 deg mark's pose in ``base_link``.

    x, y [m], yaw [rad]; ``flip``: mounted upside down (the rotation then looks
    counter-clockwise from above). The same pose as the profile's ``laser`` frame: the
    emulator measures the world from there, the driver publishes in ``laser``.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    flip: bool = False

    def world_angles(self, angle_deg: np.ndarray) -> np.ndarray:
        """Bearing in ``base_link`` [rad, CCW] of the lidar's clockwise angles [deg]."""
        theta = np.radians(angle_deg)
        return self.yaw + (theta if self.flip else -theta)


class RplidarEmulator:
    """See the module docstring.

    ``world``: what the A1 sees, placed at ``world_time()`` [s] (called from the serving
    thread). ``on_path(path)`` is called after every (re)plug, ``on_gone(path)`` when the pty
    closes (a stale path must not be opened again: the kernel gives its number to the next
    pty, possibly another program's).
    """

    def __init__(self, *, world: World = EMPTY_WORLD,
                 world_time: Callable[[], float] = lambda: 0.0, mount: Mount = Mount(),
                 rotation_hz: float = 5.5, sample_rate: float = 2000.0, model: int = 0x18,
                 firmware: tuple[int, int] = (1, 29), hardware: int = 7,
                 serial_number: bytes = bytes(range(0xA0, 0xB0)),
                 on_path: Callable[[str], None] | None = None,
                 on_gone: Callable[[str], None] | None = None) -> None:
        self.world = world
        self.world_time = world_time
        self.mount = mount
        self.rotation_hz = rotation_hz
        self.sample_rate = sample_rate
        self.model = model
        self.firmware = firmware
        self.hardware = hardware
        self.serial_number = serial_number
        self.health = (STATUS_OK, 0)
        self.health_sticky = False
        self.on_path = on_path
        self.on_gone = on_gone
        self.pose = (0.0, 0.0, 0.0)  # vessel x, y [m], psi [rad] in odom
        self.path: str | None = None
        # counters
        self.commands: dict[str, int] = {}
        self.bad_requests = 0
        self.bytes_in = 0
        self.bytes_out = 0
        self.samples_sent = 0
        self.overflows = 0
        # faults
        self._corrupt = 0
        self._truncate = 0
        self._stalled = False
        self._noise = False
        self._rng = np.random.default_rng(0)
        self._lock = threading.Lock()
        self._master = self._slave = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._scanning = False
        self._scan_t0 = 0.0
        self._scan_index = 0
        self._rx = bytearray()

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> str:
        """Open a new pty and serve it; return its path."""
        if self._thread is not None:
            return self.path or ''
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._rx.clear()
        self._scanning = False
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name='rplidar_emulator',
                                        daemon=True)
        self._thread.start()
        if self.on_path is not None:
            self.on_path(self.path)
        return self.path

    def stop(self) -> None:
        """Stop serving and close the pty (the driver's reads then fail)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(2.0)
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1
        self._scanning = False
        path, self.path = self.path, None
        if path and self.on_gone is not None:
            self.on_gone(path)  # the device node disappears, as /dev/ttyUSB0 does

    def unplug(self) -> None:
        """Pull the USB cable: the pty disappears."""
        self.stop()

    def replug(self) -> str:
        """Plugged in again: a new pty (a new path under the same registered name)."""
        return self.start()

    # -- faults --------------------------------------------------------------------------------
    def corrupt(self, n: int) -> None:
        """Break the start-flag pair (S == !S) of the next ``n`` samples."""
        with self._lock:
            self._corrupt += n

    def truncate(self, n: int) -> None:
        """Send only the first 3 bytes of the next ``n`` samples."""
        with self._lock:
            self._truncate += n

    def stall(self, on: bool) -> None:
        """Go silent (no answers, no samples) or speak again."""
        self._stalled = on

    def noise(self, on: bool) -> None:
        """Stream random bytes instead of samples while scanning (or samples again)."""
        self._noise = on

    def set_pose(self, x: float, y: float, psi: float) -> None:
        """Set the vessel's pose in odom [m, m, rad] (from the simulator)."""
        self.pose = (x, y, psi)

    # -- serving -------------------------------------------------------------------------------
    def _serve(self) -> None:
        period = 0.01
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], period)
                if ready:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        data = b''
                    if data:
                        self.bytes_in += len(data)
                        self._rx += data
                        self._handle_requests()
                if self._scanning and not self._stalled:
                    self._stream()
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(period)  # no reader on the slave side yet (EIO): keep serving

    def _send(self, data: bytes) -> None:
        if self._stalled or not data:
            return
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        if n < len(data):
            self.overflows += 1  # nobody reads: bytes lost, as on a real line
        self.bytes_out += n

    def _count(self, name: str) -> None:
        self.commands[name] = self.commands.get(name, 0) + 1

    def _handle_requests(self) -> None:
        rx = self._rx
        while rx:
            start = rx.find(SYNC)
            if start < 0:
                self.bad_requests += 1
                rx.clear()
                return
            if start:
                self.bad_requests += 1
                del rx[:start]
            if len(rx) < 2:
                return
            cmd = rx[1]
            if cmd & CMDFLAG_HAS_PAYLOAD:
                if len(rx) < 3 or len(rx) < 4 + rx[2]:
                    return
                size = rx[2]
                frame = bytes(rx[:4 + size])
                checksum = 0
                for b in frame[:-1]:
                    checksum ^= b
                del rx[:4 + size]
                if checksum != frame[-1]:
                    self.bad_requests += 1
                    continue
                self._count(f'0x{cmd:02X}')  # express scan and friends: not an A1 SCAN
                continue
            del rx[:2]
            if not self._stalled:
                self._command(cmd)

    def _command(self, cmd: int) -> None:
        if cmd == CMD_STOP:
            self._count('STOP')
            self._scanning = False
        elif cmd == CMD_RESET:
            self._count('RESET')
            self._scanning = False
            if self.health[0] == STATUS_ERROR and not self.health_sticky:
                self.health = (STATUS_OK, 0)
        elif cmd in (CMD_SCAN, CMD_FORCE_SCAN):
            self._count('SCAN')
            self._send(encode_descriptor(5, MODE_MULTI, ANS_TYPE_MEASUREMENT))
            self._scanning = True
            self._scan_t0 = time.monotonic()
            self._scan_index = 0
        elif cmd == CMD_GET_INFO:
            self._count('GET_INFO')
            self._send(encode_descriptor(20, MODE_SINGLE, ANS_TYPE_DEVINFO) + struct.pack(
                '<4B', self.model, self.firmware[1], self.firmware[0], self.hardware)
                + self.serial_number[:16].ljust(16, b'\0'))
        elif cmd == CMD_GET_HEALTH:
            self._count('GET_HEALTH')
            self._send(encode_descriptor(3, MODE_SINGLE, ANS_TYPE_DEVHEALTH)
                       + struct.pack('<BH', *self.health))
        else:
            self._count(f'0x{cmd:02X}')

    def ranges_mm(self, angle_deg: np.ndarray) -> np.ndarray:
        """Distances [mm] the lidar measures at its clockwise angles (0: no return)."""
        x, y, psi = self.pose
        m = self.mount
        c, s = math.cos(psi), math.sin(psi)
        ox, oy = x + c * m.x - s * m.y, y + s * m.x + c * m.y
        r = self.world.raycast((ox, oy), psi + m.world_angles(angle_deg), self.world_time())
        return np.where((r >= RANGE_MIN) & (r <= RANGE_MAX), r * 1000.0, 0.0)

    def _stream(self) -> None:
        due = int((time.monotonic() - self._scan_t0) * self.sample_rate)
        n = min(due - self._scan_index, 400)
        if n <= 0:
            return
        if self._noise:
            self._scan_index += n
            self._send(self._rng.integers(0, 256, 5 * n, dtype=np.uint8).tobytes())
            return
        per_rev = max(1, round(self.sample_rate / self.rotation_hz))
        j = np.arange(self._scan_index, self._scan_index + n)
        rev, i = j // per_rev, j % per_rev
        step = 360.0 / per_rev
        angles = (i * step + (rev * 0.37) % step) % 360.0  # angles drift between revolutions
        dist = self.ranges_mm(angles)
        out = bytearray()
        with self._lock:
            for k in range(n):
                sample = encode_sample(bool(i[k] == 0), 47 if dist[k] > 0 else 0,
                                       float(angles[k]), float(dist[k]))
                if self._corrupt:
                    self._corrupt -= 1
                    sample = bytes((sample[0] & 0xFC,)) + sample[1:]
                elif self._truncate:
                    self._truncate -= 1
                    sample = sample[:3]
                out += sample
        self._scan_index += n
        self.samples_sent += n
        self._send(bytes(out))


# -- the node ------------------------------------------------------------------------------
SPECS = [
    ParamSpec('name', 'default', "Emulator name: the driver's port emulated:NAME",
              read_only=True),
    ParamSpec('mount.x', 0.0, "Lidar centre ahead of base_link's origin (the laser frame's x)",
              'm', -20.0, 20.0),
    ParamSpec('mount.y', 0.0, "Lidar centre left of base_link's origin (the laser frame's y)",
              'm', -20.0, 20.0),
    ParamSpec('mount.yaw', 0.0, "Direction of the lidar's 0 deg mark, CCW from base_link +x "
              "(the laser frame's yaw)", 'rad', -math.pi, math.pi),
    ParamSpec('flip', False, 'Mounted upside down (the laser frame rolled by pi)'),
    ParamSpec('rotation_hz', 5.5, 'Rotation rate (A1: about 5.5 Hz)', 'Hz', 1.0, 15.0,
              read_only=True),
    ParamSpec('sample_rate', 2000.0, 'Samples per second (A1 SCAN: 2000)', '1/s', 100.0,
              8000.0, read_only=True),
    ParamSpec('model', 0x18, 'GET_INFO model byte (0x18: A1M8)', '', 0, 255),
]


@dataclass(frozen=True)
class RplidarEmulatorSettings:
    """Settings of ``RplidarEmulatorNode`` (see ``SPECS``)."""

    name: str
    mount: Mount
    rotation_hz: float
    sample_rate: float
    model: int

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> RplidarEmulatorSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        return cls(v['name'], Mount(v['mount.x'], v['mount.y'], v['mount.yaw'], bool(v['flip'])),
                   v['rotation_hz'], v['sample_rate'], int(v['model']))


class RplidarEmulatorNode(DeviceEmulatorNode):
    """See the module docstring."""

    kind = 'serial'
    device = 'RPLidar A1'

    def __init__(self, node_name: str = 'rplidar_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, RplidarEmulatorSettings.from_params, **kwargs)

    def make_emulator(self, s: RplidarEmulatorSettings, plugged: Callable[[str], None],
                      unplugged: Callable[[str], None]) -> RplidarEmulator:
        """Build the A1 on a pty, plugged in (its path offered) on ``start``."""
        return RplidarEmulator(world=self.world, world_time=self.world_time, mount=s.mount,
                               rotation_hz=s.rotation_hz,
                               sample_rate=s.sample_rate, model=s.model, on_path=plugged,
                               on_gone=unplugged)

    def apply(self, s: RplidarEmulatorSettings) -> None:
        """Mount and model change live."""
        self.emulator.mount, self.emulator.model = s.mount, s.model

    def report(self) -> tuple[str, dict[str, Any]]:
        """Report the pty and what went through it."""
        e = self.emulator
        return (f'serving {e.path}' if e.path else 'not plugged in', {
            'path': e.path or '', 'commands': commands_line(e.commands),
            'bad_requests': e.bad_requests, 'bytes_in': e.bytes_in, 'bytes_out': e.bytes_out,
            'samples_sent': e.samples_sent, 'overflows': e.overflows})
