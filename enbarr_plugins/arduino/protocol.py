"""The Arduino PWM board's link protocol, host side: ``firmware/enbarr_arduino/link.h`` in Python.

``link.h`` is the source of truth (the board runs it, and the emulator runs the board's own
``link.c`` compiled for the host); this module is what the driver (``arduino/link.py``) and
``enbarr check-device arduino`` (``arduino/check.py``) speak. ``test_arduino_firmware.py``
checks every number here against ``link.h`` parsed and against the values typed from it, and
every message layout against the host build of the firmware.

Frame (``transport/serial_link.py``): ``0xA5 | LEN | PAYLOAD | CRC-16/CCITT-FALSE``; PAYLOAD =
``TYPE | SEQ | BODY``, big-endian fields, duties in units of 0.01 %.
"""

from __future__ import annotations

from collections.abc import Sequence
import struct
from typing import NamedTuple

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.transport.serial_link import encode_frame

PROTOCOL_VERSION = 1
BOARD_ID = 0x4D45
CHANNELS = 6
HELLO_REQ, SET_DUTY, HEARTBEAT, CONFIG = 0x01, 0x02, 0x03, 0x04
HELLO, STATUS = 0x81, 0x82
RESULT_OK, RESULT_SEQ, RESULT_LENGTH, RESULT_RANGE, RESULT_TYPE = 0, 1, 2, 3, 4
RESULTS = {RESULT_OK: 'ok', RESULT_SEQ: 'sequence refused', RESULT_LENGTH: 'wrong length',
           RESULT_RANGE: 'value out of range', RESULT_TYPE: 'unknown type'}
FLAG_NEUTRAL, FLAG_CONFIGURED, FLAG_TRIPPED = 0x01, 0x02, 0x04
DEFAULT_TIMEOUT_MS = 250
DEFAULT_DUTY_MIN, DEFAULT_DUTY_MAX, DEFAULT_NEUTRAL = 430, 940, 685
UNITS_PER_PERCENT = 100  # duties travel in 0.01 %

_HELLO = struct.Struct('>BHBHHB')
_STATUS = struct.Struct('>BBBHHHHH')


class Hello(NamedTuple):
    """The board's identity (HELLO)."""

    seq: int
    version: int
    board_id: int
    channels: int
    timeout_ms: int
    boot_count: int
    reset_cause: int

    def describe(self) -> str:
        """Say what was read, for people."""
        return (f'protocol {self.version}, board id 0x{self.board_id:04X}, {self.channels} '
                f'channels, watchdog {self.timeout_ms} ms, boot {self.boot_count}, reset cause '
                f'0x{self.reset_cause:02X}')

    def problem(self) -> str | None:
        """Why this is not the board the driver speaks to, or None."""
        if (self.version, self.board_id, self.channels) != (PROTOCOL_VERSION, BOARD_ID,
                                                            CHANNELS):
            return (f'not an Enbarr PWM board: read {self.describe()}; expected protocol '
                    f'{PROTOCOL_VERSION}, board id 0x{BOARD_ID:04X}, {CHANNELS} channels '
                    '(flash firmware/enbarr_arduino, docs/hardware.md)')
        return None


class Status(NamedTuple):
    """The board's answer to one host frame (STATUS)."""

    seq: int
    acked: int
    result: int
    flags: int
    watchdog_trips: int
    crc_errors: int
    seq_errors: int
    refused: int
    truncated: int

    @property
    def neutral(self) -> bool:
        """Whether every output is at its neutral duty."""
        return bool(self.flags & FLAG_NEUTRAL)


class ProtocolError(DeviceError):
    """A well-framed payload that is not a board message."""


def message(kind: int, seq: int, body: bytes = b'') -> bytes:
    """Return the frame of one message (type ``kind``, sequence ``seq``)."""
    return encode_frame(bytes([kind, seq & 0xFF]) + body)


def to_units(percent: float) -> int:
    """Duty [%] in the protocol's 0.01 % units."""
    return int(round(percent * UNITS_PER_PERCENT))


def duty_body(units: Sequence[int]) -> bytes:
    """Body of SET_DUTY: one u16 per channel [0.01 %]."""
    return struct.pack(f'>{CHANNELS}H', *units)


def config_body(duty_min: int, duty_max: int, timeout_ms: int,
                neutral: Sequence[int]) -> bytes:
    """Body of CONFIG: limits and neutral duties [0.01 %], watchdog timeout [ms]."""
    return struct.pack(f'>3H{CHANNELS}H', duty_min, duty_max, timeout_ms, *neutral)


def parse(payload: bytes) -> Hello | Status:
    """Decode one board message; ``ProtocolError`` for an unknown type or a wrong length."""
    if len(payload) < 2:
        raise ProtocolError(f'payload of {len(payload)} bytes')
    kind, seq, body = payload[0], payload[1], payload[2:]
    if kind == HELLO and len(body) == _HELLO.size:
        return Hello(seq, *_HELLO.unpack(body))
    if kind == STATUS and len(body) == _STATUS.size:
        return Status(seq, *_STATUS.unpack(body))
    raise ProtocolError(f'type 0x{kind:02X} with {len(body)} body bytes')


def config_problem(duty_min: int, duty_max: int, timeout_ms: int,
                   neutral: Sequence[int]) -> str | None:
    """Why the board would refuse this CONFIG (link.h's rule), naming the field; or None.

    A duty of 0 has no pulse on the board (its timer compare value would wrap above TOP and
    hold the output high), so the minimum, and with it every duty, is at least one unit.
    """
    if duty_min < 1:
        return (f'duty_min: {duty_min} units of 0.01 %: the board outputs no duty below '
                '0.01 % (a duty of 0 would hold its PWM pins high)')
    if not duty_min < duty_max <= 100 * UNITS_PER_PERCENT:
        return f'duty_max: {duty_max} units must be above duty_min ({duty_min}) and at most 10000'
    if not 20 <= timeout_ms <= 0xFFFF:
        return f'timeout_ms: {timeout_ms} ms must be within 20 .. 65535'
    if len(neutral) != CHANNELS or not all(duty_min <= n <= duty_max for n in neutral):
        return (f'neutral: {list(neutral)} must be {CHANNELS} duties within duty_min .. '
                f'duty_max ({duty_min} .. {duty_max} units of 0.01 %)')
    return None


def newer(seq: int, last: int) -> bool:
    """Whether sequence number ``seq`` is 1..127 ahead of ``last`` (mod 256)."""
    return 1 <= (seq - last) % 256 <= 127
