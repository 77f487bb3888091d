"""Slamtec RPLidar A1 over a serial port (USB adapter, 115200 8N1): ``scan`` per revolution.

The bytes are ``rplidar_protocol``'s (Slamtec's "RPLIDAR Interface Protocol and Application
Notes", checked against the vendor SDK); the revolution and its rays are ``scan``'s. This
module runs the exchange on a serial port and is the node.

Motor: on the A1 USB adapter the motor runs while DTR is *not* asserted (the SDK's
``setMotorSpeed``: speed 0 -> ``setDTR(true)``, otherwise ``setDTR(false)``; pyserial
asserts DTR on open, so the motor is off until the driver clears it).

Frames: the scan is published in the lidar's own frame (``frame_id``, ``laser`` by default),
as a real driver publishes it; where the lidar sits on the vessel is the frame tree's
business (the profile's ``laser`` frame), and consumers transform the scan. The frame's x
points along the lidar's 0 deg mark and its z up from the lidar's base, so the lidar's
clockwise angles become counter-clockwise bearings (REP-103); mounted upside down, the frame
is rolled by pi. The returns of one revolution are binned by bearing into ``bins`` rays of a
fixed increment from -pi (``scan.bin_revolution``; special values as REP-117 defines them:
-inf too close, +inf no return, NaN no sample). The scan's stamp is the node-clock time
at which the revolution's first sample (the 0 deg mark) arrived (the read's time less one
sample period per sample read after it); ``scan_time`` the measured revolution;
``time_increment`` is 0 (the rays are binned, and the revolution starts mid-array at 0 rad
and runs clockwise, which ``time_increment`` cannot say).

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
import os
import re
import time
from typing import Any

import numpy as np

from enbarr_core.framework.driver import SensorDriver, WARN
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins import emulation
from enbarr_plugins.lidar.common import laser_scan
from enbarr_plugins.lidar.rplidar_protocol import (
    A1_MAJOR, ANS_TYPE_DEVHEALTH, ANS_TYPE_DEVINFO, ANS_TYPE_MEASUREMENT, BAUDRATE,
    CMD_GET_HEALTH, CMD_GET_INFO, CMD_RESET, CMD_SCAN, CMD_STOP, Descriptor, decode_descriptor,
    DESCRIPTOR_SIZE, DeviceInfo, Health, HEALTH_SIZE, INFO_SIZE, MODE_MULTI, MODE_SINGLE,
    NO_SAMPLES, RANGE_MAX, RANGE_MIN, request, SAMPLE_PERIOD_NS, SAMPLE_SIZE, ScanDecoder,
    STATUS_ERROR, STATUS_WARNING, SYNC, ANS_SYNC)
from enbarr_plugins.lidar.scan import bin_revolution, RevolutionAssembler
from enbarr_plugins.transport.reader import DeviceThread
from enbarr_plugins.transport.serial_link import open_serial

#: Extra wait for the first sample after SCAN [s]: the motor, started with SCAN, must reach
#: its speed first (the SDK's examples start the motor and scan at once, then wait for data).
MOTOR_SPINUP = 2.0
#: The reader sleeps this long between reads [s] and then takes what arrived (100 samples
#: at 2000 samples/s; the stamps are corrected by the sample period, so only the scan's
#: publication waits): fewer, larger reads cost less CPU (docs/benchmarks.md).
POLL_PERIOD = 0.05
#: Waits the protocol document asks for after STOP and RESET [s] (1 ms, 2 ms); longer here,
#: the A1 reboots after RESET.
STOP_WAIT = 0.002
RESET_WAIT = 0.5


# -- the start-up exchange (shared by the node's reader thread and the check) --------------
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


#: Names the kernel gives USB serial adapters in the order they appear.
_ENUMERATED = re.compile(r'/dev/tty(USB|ACM)\d+')


def stable_name_advice(port: str) -> str:
    """Advice to add when ``port`` vanished: '' unless it is an enumerated USB serial name.

    A re-plugged adapter (the A1's CP2102) may come back under another ``/dev/ttyUSBn``;
    udev's ``/dev/serial/by-id/`` name stays the same.
    """
    enumerated = _ENUMERATED.fullmatch(port)
    if not enumerated:
        return ''
    return (f' (a re-plugged USB adapter may come back as another /dev/tty'
            f'{enumerated.group(1)}n: give the '
            'port by its stable name, ls -l /dev/serial/by-id/, e.g. /dev/serial/by-id/'
            'usb-Silicon_Labs_CP2102_USB_to_UART_Bridge_Controller_0001-if00-port0)')


# -- the node ------------------------------------------------------------------------------
SPECS = [
    ParamSpec('port', '/dev/ttyUSB0', "Serial port of the lidar's USB adapter, best by its "
              'stable /dev/serial/by-id/ name; or emulated[:NAME]', read_only=True),
    ParamSpec('frame_id', topics.LASER_FRAME, "The lidar's own frame, in which the scan is "
              'published (x along its 0 deg mark, z up from its base); the frame tree places '
              'it on the vessel', read_only=True),
    ParamSpec('bins', 360, 'Rays per revolution in the published scan (fixed increment '
              '2 pi / bins)', '', 36, 7200, read_only=True),
    ParamSpec('min_quality', 0, 'Returns of lower quality are taken as erroneous (NaN where '
              'nothing else fell in the ray)', '', 0, 63),
    ParamSpec('response_timeout', 0.5, 'Longest wait for the answer to a request', 's', 0.01,
              10.0),
    ParamSpec('stall_timeout', 1.0, 'No valid scan sample for this long is a fault (reconnect)',
              's', 0.05, 60.0),
]


@dataclass(frozen=True)
class RplidarSettings:
    """Settings of ``RplidarNode`` (see ``SPECS``)."""

    port: str
    frame_id: str
    bins: int
    min_quality: int
    response_timeout: float  # [s]
    stall_timeout: float     # [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> RplidarSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if not v['port'].strip():
            raise ValueError('port: empty; a serial port such as /dev/ttyUSB0, or emulated')
        frame_id = v['frame_id'].strip()
        if not frame_id or frame_id.startswith('/') or ' ' in frame_id:
            raise ValueError(f"frame_id: a frame name such as 'laser' (no leading '/', no "
                             f"spaces), got {v['frame_id']!r}")
        return cls(v['port'], frame_id, int(v['bins']), int(v['min_quality']),
                   v['response_timeout'], v['stall_timeout'])


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
        self._reader = DeviceThread(f'{self.get_name()}_reader')
        self._pub = self.create_topic_publisher(topics.SCAN)

    def _apply(self, settings: RplidarSettings) -> None:
        self.settings = settings

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the port (looked up again each time) and start the reader thread."""
        port = self.settings.port
        path = resolve_port(port)
        self.device = port if path == port else f'{port} ({path})'
        try:
            self._serial = open_serial(path, BAUDRATE, timeout=0.05)
        except DeviceError as err:
            if os.path.exists(path):
                raise
            raise DeviceError(f'{err}{stable_name_advice(path)}') from err
        self.decoder.reset()
        self.assembler.reset()
        self.state = 'starting'
        self._reader.start(self.device, self._run, self._serial)

    def close_device(self) -> None:
        """Stop the reader, then STOP and motor off (best effort) and close the port."""
        self._reader.stop(2.0)
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
        if self.connected:
            err = self._reader.failure()
            if err is not None:
                self.device_fault(err)

    def _run(self, ser: Any) -> None:
        """Run the start-up exchange, then the stream (the reader thread)."""
        name = self.device
        s = self.settings
        self.info, self.health, resets = handshake(ser, name, s.response_timeout)
        self.resets += resets
        if resets:
            self.get_logger().warn(f'{name}: health error cleared by RESET')
        elif self.health.status == STATUS_WARNING:
            self.get_logger().warn(f'{name}: {self.health.describe()}')
        self.motor_line = start_scan(ser, name, s.response_timeout)
        if not self.motor_line:
            self.get_logger().warn(f'{name}: no DTR line (a pty?): the motor is not switched '
                                   'by this driver')
        self.get_logger().info(f'{name}: {self.info.describe()}, {self.health.describe()}: '
                               'scanning')
        self.state = 'scanning'
        self._stream(ser, name)

    def _stream(self, ser: Any, name: str) -> None:
        last = time.monotonic() + MOTOR_SPINUP  # the first sample waits for the motor
        clock = self.get_clock()
        period_ns = SAMPLE_PERIOD_NS
        while not self._reader.wait(POLL_PERIOD):  # let samples gather: one read per period
            try:
                data = ser.read(max(1, ser.in_waiting))
            except Exception as err:  # noqa: BLE001 - SerialException, OSError (unplugged)
                raise DeviceError(f'{name}: read failed (unplugged?): {err}'
                                  f'{stable_name_advice(self.settings.port)}') from err
            now = time.monotonic()
            start, quality, angle, dist = self.decoder.feed(data) if data else NO_SAMPLES
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
            if self.settings.min_quality:  # too weak to trust: erroneous (REP-117: NaN)
                dist = np.where(quality >= self.settings.min_quality, dist, np.nan)
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
        ranges = bin_revolution(rev.angle_deg, rev.distance_mm, s.bins, RANGE_MIN, RANGE_MAX)
        self._pub.publish(laser_scan(rev.stamp_ns, s.frame_id, ranges, rev.duration,
                                     RANGE_MIN, RANGE_MAX))
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
                'missed_starts': self.assembler.missed_starts,
                'invalid_samples': self.assembler.invalid}
