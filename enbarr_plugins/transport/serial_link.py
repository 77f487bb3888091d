"""A framed binary protocol over a serial port (an Arduino link, a microcontroller bridge).

``open_serial`` opens a pyserial ``Serial`` by port name with a read timeout; ``SerialLink``
sends and receives frames over it, and every failure is a ``DeviceError`` naming the port.

Frame on the wire::

    0xA5 | LEN | PAYLOAD (LEN bytes, 0..255) | CRC hi | CRC lo

The CRC is CRC-16/CCITT-FALSE (width 16, poly 0x1021, init 0xFFFF, not reflected, xorout 0;
check value 0x29B1 for ASCII ``123456789``; Greg Cook, "Catalogue of parametrised CRC
algorithms", https://reveng.sourceforge.io/crc-catalogue/16.htm, where it is listed as
CRC-16/IBM-3740) over LEN and PAYLOAD, sent big-endian.

``FrameDecoder`` finds frames in a byte stream and resynchronises after garbage (bytes before
a start byte), CRC errors (the start byte is dropped and the search goes on from the next
byte, so a frame that started inside a corrupted one is still found) and truncation (a frame
cut off by a silent line, ``flush_partial``); each is counted.

``vanished_port_hint`` is what every serial driver adds to an error on a port that went away:
the kernel numbers USB serial adapters (``/dev/ttyUSBn``, ``/dev/ttyACMn``) in the order they
appear, so a re-plugged device may come back under another number, while udev's
``/dev/serial/by-id/...`` link (``60-serial.rules``: ``usb-<ID_SERIAL>-if<interface>``) keeps
naming the same device.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
import re
from typing import Any

from enbarr_core.framework.errors import DeviceError

START = 0xA5
MAX_PAYLOAD = 255
_OVERHEAD = 4  # start, length, two CRC bytes


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (continue from ``crc`` to checksum in pieces)."""
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


def encode_frame(payload: bytes) -> bytes:
    """Encode one frame carrying ``payload`` (at most 255 bytes)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f'payload: at most {MAX_PAYLOAD} bytes, got {len(payload)}')
    body = bytes([len(payload)]) + bytes(payload)
    return bytes([START]) + body + crc16_ccitt_false(body).to_bytes(2, 'big')


class FrameDecoder:
    """Cuts a byte stream into payloads; see the module docstring for the counters' meaning.

    ``garbage``: bytes skipped while looking for a start byte (after a CRC error the skipped
    start byte counts too); ``crc_errors``: frames whose CRC did not match;
    ``too_long``: frames announcing more than ``max_payload`` bytes; ``truncated``: partial
    frames dropped by ``flush_partial``; ``frames``: good frames.
    """

    def __init__(self, max_payload: int = MAX_PAYLOAD) -> None:
        if not 0 <= max_payload <= MAX_PAYLOAD:
            raise ValueError(f'max_payload: must be 0..{MAX_PAYLOAD}, got {max_payload}')
        self.max_payload = max_payload
        self._buf = bytearray()
        self.frames = 0
        self.garbage = 0
        self.crc_errors = 0
        self.too_long = 0
        self.truncated = 0

    @property
    def pending(self) -> int:
        """Bytes held of a frame not complete yet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        """Take ``data``; return the payloads of the frames it completed, in order."""
        self._buf += data
        out: list[bytes] = []
        buf = self._buf
        while buf:
            start = buf.find(START)
            if start < 0:
                self.garbage += len(buf)
                buf.clear()
                break
            if start:
                self.garbage += start
                del buf[:start]
            if len(buf) < 2:
                break
            length = buf[1]
            if length > self.max_payload:
                self.too_long += 1
                self.garbage += 1
                del buf[:1]
                continue
            end = length + _OVERHEAD
            if len(buf) < end:
                break
            body = bytes(buf[1:end - 2])
            if crc16_ccitt_false(body) != int.from_bytes(buf[end - 2:end], 'big'):
                self.crc_errors += 1
                self.garbage += 1
                del buf[:1]  # resynchronise on the next start byte
                continue
            out.append(body[1:])
            self.frames += 1
            del buf[:end]
        return out

    def flush_partial(self) -> bool:
        """Drop a frame cut off by a silent line (call on a read timeout); True if one was.

        The dropped bytes are searched again for a later start byte first, so that a real
        frame is not lost behind a truncated one.
        """
        if not self._buf:
            return False
        rest = bytes(self._buf[1:])
        self._buf.clear()
        self.truncated += 1
        tail = rest.find(START)
        if tail >= 0:
            self._buf += rest[tail:]
        return True

    def counters(self) -> dict[str, int]:
        """Return the counters, for ``/diagnostics``."""
        return {'frames': self.frames, 'garbage': self.garbage, 'crc_errors': self.crc_errors,
                'too_long': self.too_long, 'truncated': self.truncated}


#: errno values a USB serial node fails with once the device is gone: ENOENT (opening a node
#: udev removed), ENODEV and EIO (reading or writing a descriptor whose device was unplugged).
VANISHED_ERRNOS = frozenset((errno.ENOENT, errno.ENODEV, errno.EIO))
#: Where udev links each USB serial device under a name made of its vendor, model and serial.
BY_ID_DIR = Path('/dev/serial/by-id')
_KERNEL_NUMBERED = re.compile(r'/dev/tty(USB|ACM)[0-9]+')


def _node_exists(path: str) -> bool:
    return os.path.exists(path)


def _errnos(err: BaseException | None) -> set[int]:
    """Return the errno of ``err`` and of the errors it was raised from (pyserial wraps)."""
    out: set[int] = set()
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        code = getattr(err, 'errno', None)
        if isinstance(code, int):
            out.add(code)
        err = err.__cause__ or err.__context__
    return out


def _present_by_id() -> str:
    try:
        present = sorted(p.name for p in BY_ID_DIR.iterdir())
    except OSError:
        return 'none'
    if not present:
        return 'none'
    return ', '.join(present[:4]) + (', ...' if len(present) > 4 else '')


def vanished_port_hint(port: str, err: BaseException | None = None) -> str:
    """Advice to append to an error on ``port`` when its device node is gone, or ``''``.

    For a kernel-numbered USB serial name (``/dev/ttyUSBn``, ``/dev/ttyACMn``) that is gone
    (``err``, or an error it was raised from, carries ENOENT, ENODEV or EIO, or the path no
    longer exists): a sentence that steers to the stable ``/dev/serial/by-id/...`` link. For
    a ``/dev/serial/by-id/...`` link that does not exist (the device is unplugged, or the
    name is a profile's placeholder): the links present now. Both name the links present.
    """
    if port.startswith(f'{BY_ID_DIR}/'):
        if _node_exists(port):
            return ''
        return (f' (no such link: the device is unplugged or has another serial number; '
                f'links present now: {_present_by_id()}; docs/hardware.md)')
    if not _KERNEL_NUMBERED.fullmatch(port):
        return ''
    if not (_errnos(err) & VANISHED_ERRNOS or not _node_exists(port)):
        return ''
    return (f' ({port} is gone: the kernel numbers USB serial devices as they appear, so a '
            're-plugged one may come back as another /dev/ttyUSBn or /dev/ttyACMn; name it by '
            f'its stable link {BY_ID_DIR}/usb-<vendor>_<model>_<serial>-if00 instead; links '
            f'present now: {_present_by_id()}; docs/hardware.md)')


def open_serial(port: str, baudrate: int = 115200, *, timeout: float = 0.1,
                write_timeout: float = 0.1) -> Any:
    """Open ``port`` (``/dev/ttyACM0``) as a pyserial ``Serial`` with bounded read/write waits."""
    import serial
    if not (timeout > 0.0 and write_timeout > 0.0):
        raise ValueError(f'timeout/write_timeout: must be > 0 s, got {timeout}, '
                         f'{write_timeout}')
    try:
        return serial.Serial(port, baudrate, timeout=timeout, write_timeout=write_timeout)
    except (serial.SerialException, OSError, ValueError) as err:
        raise DeviceError(f'{port}: cannot open at {baudrate} baud: {err}'
                          f'{vanished_port_hint(port, err)}') from err


class SerialLink:
    """Frames over an open ``Serial`` (or anything with ``read``, ``write``, ``in_waiting``).

    ``read_frames()`` blocks at most the port's read timeout: it reads what has arrived (at
    least one byte, or nothing when the timeout expires) and returns the completed payloads;
    when nothing came for a whole timeout, a partial frame is dropped and counted. ``port``
    names the link in errors.
    """

    def __init__(self, serial_port: Any, port: str | None = None, *,
                 max_payload: int = MAX_PAYLOAD) -> None:
        self.serial = serial_port
        self.port = port or getattr(serial_port, 'port', None) or 'serial'
        self.decoder = FrameDecoder(max_payload)
        self.sent = 0

    @classmethod
    def open(cls, port: str, baudrate: int = 115200, *, timeout: float = 0.1,
             max_payload: int = MAX_PAYLOAD) -> SerialLink:
        """Open ``port`` and wrap it."""
        return cls(open_serial(port, baudrate, timeout=timeout), port, max_payload=max_payload)

    def write_frame(self, payload: bytes) -> None:
        """Send one frame; ``DeviceError`` when the port fails or the write times out."""
        frame = encode_frame(payload)
        try:
            written = self.serial.write(frame)
        except Exception as err:  # noqa: BLE001 - SerialException, SerialTimeoutException, OSError
            raise DeviceError(f'{self.port}: write failed: {err}'
                              f'{vanished_port_hint(self.port, err)}') from err
        if written is not None and written != len(frame):
            raise DeviceError(f'{self.port}: wrote {written} of {len(frame)} bytes')
        self.sent += 1

    def read_frames(self) -> list[bytes]:
        """Payloads of the frames received by now (waits at most one read timeout)."""
        try:
            data = self.serial.read(max(1, self.serial.in_waiting))
        except Exception as err:  # noqa: BLE001 - SerialException, OSError (unplugged)
            raise DeviceError(f'{self.port}: read failed: {err}'
                              f'{vanished_port_hint(self.port, err)}') from err
        if not data:
            self.decoder.flush_partial()
            return []
        return self.decoder.feed(data)

    def close(self) -> None:
        """Close the port; never raises."""
        try:
            self.serial.close()
        except Exception:  # noqa: BLE001 - closing a dead port may raise anything
            pass
