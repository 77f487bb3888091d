"""Unit tests of the Arduino board's firmware logic (link.c), run through ctypes, and its
AVR build (e2e: it runs make).
"""

from __future__ import annotations

from pathlib import Path
import re
import shutil
import struct
import subprocess

import pytest

from enbarr_plugins.arduino import emulator, firmware
from enbarr_plugins.arduino import protocol as proto
from enbarr_plugins.transport.serial_link import crc16_ccitt_false, encode_frame, FrameDecoder

APT = 'apt-get install -y --no-install-recommends gcc-avr avr-libc arduino-core-avr'
ROOT = Path(__file__).resolve().parents[2]
GOOD = [820, 940, 430, 685, 700, 600]  # duties [0.01 %]

# The protocol's numbers, typed from firmware/enbarr_arduino/link.h (its source of truth).
LINK_H = {
    'PROTOCOL_VERSION': 1, 'BOARD_ID': 0x4D45, 'CHANNELS': 6,
    'HELLO_REQ': 0x01, 'SET_DUTY': 0x02, 'HEARTBEAT': 0x03, 'CONFIG': 0x04,
    'HELLO': 0x81, 'STATUS': 0x82,
    'RESULT_OK': 0, 'RESULT_SEQ': 1, 'RESULT_LENGTH': 2, 'RESULT_RANGE': 3, 'RESULT_TYPE': 4,
    'FLAG_NEUTRAL': 0x01, 'FLAG_CONFIGURED': 0x02, 'FLAG_TRIPPED': 0x04,
    'DEFAULT_TIMEOUT_MS': 250, 'DEFAULT_DUTY_MIN': 430, 'DEFAULT_DUTY_MAX': 940,
    'DEFAULT_NEUTRAL': 685,
}


@pytest.fixture(scope='session', autouse=True)
def built() -> None:
    """Compile the firmware for the host once, before the unit tier forbids processes."""
    firmware.load()


class Wire:
    """A board and the host end of its line, on a fake millisecond clock."""

    def __init__(self) -> None:
        self.t = 1000
        self.board = firmware.Board(self.t)
        self.decoder = FrameDecoder()
        self.seq = 0
        self.replies: list[proto.Hello | proto.Status] = []
        self.read()

    def read(self) -> list[proto.Hello | proto.Status]:
        new = [proto.parse(p) for p in self.decoder.feed(self.board.tx())]
        self.replies += new
        return new

    def send(self, kind: int, body: bytes = b'', seq: int | None = None) -> list:
        if seq is None:
            self.seq = (self.seq + 1) & 0xFF
            seq = self.seq
        self.board.rx(proto.message(kind, seq, body), self.t)
        return self.read()

    def advance(self, ms: int) -> None:
        self.t += ms
        self.board.tick(self.t)

    def duty(self, units: list[int], seq: int | None = None) -> proto.Status:
        (status,) = self.send(proto.SET_DUTY, proto.duty_body(units), seq)
        return status


def test_crc_is_ccitt_false_and_agrees_with_the_host():
    assert firmware.crc16(b'123456789') == 0x29B1 == crc16_ccitt_false(b'123456789')
    data = bytes(range(256)) * 3
    assert firmware.crc16(data) == crc16_ccitt_false(data)
    assert firmware.crc16(data[100:], firmware.crc16(data[:100])) == crc16_ccitt_false(data)


def test_constants_agree_with_link_h():
    """The driver's numbers (protocol.py) and the emulator's (firmware.defines) against link.h
    parsed here and the values typed from it."""
    text = (ROOT / 'firmware/enbarr_arduino/link.h').read_text()
    defines = {m[1]: int(m[2], 0) for m in re.finditer(
        r'#define (ENB_\w+) +(0x[0-9A-Fa-f]+|\d+)u?\b', text)}
    for name, value in LINK_H.items():
        assert defines[f'ENB_{name}'] == value, f'link.h changed {name}: a new protocol version'
        assert getattr(proto, name) == value, name
        assert firmware.defines()[f'ENB_{name}'] == value, name
    assert proto.UNITS_PER_PERCENT == emulator.UNITS_PER_PERCENT == 100  # 0.01 % units
    enum = re.search(r'enum enb_counter_id \{(.*?)\}', text, re.S)[1]
    names = [m.lower() for m in re.findall(r'ENB_C_(\w+)', enum) if m != 'COUNT']
    assert tuple(names) == firmware.COUNTERS


def test_message_layouts_are_link_h():
    """Each body layout of link.h, typed: the driver's encoders and parser agree with it."""
    # host -> board: A5 | LEN | TYPE SEQ BODY | CRC; SET_DUTY 6 x u16, CONFIG 9 x u16.
    duty = proto.message(0x02, 0x107, proto.duty_body(GOOD))
    body = bytes([0x02, 0x07]) + struct.pack('>6H', *GOOD)
    assert duty == encode_frame(body) and duty[:2] == bytes([0xA5, 14])
    assert proto.config_body(500, 900, 100, [690] * 6) == struct.pack('>9H', 500, 900, 100,
                                                                      *[690] * 6)
    # board -> host: HELLO u8 version, u16 board id, u8 channels, u16 timeout_ms,
    # u16 boot count, u8 reset cause; STATUS u8 acked, u8 result, u8 flags, 5 x u16.
    hello = proto.parse(bytes([0x81, 9]) + struct.pack('>BHBHHB', 1, 0x4D45, 6, 250, 12, 2))
    assert hello == proto.Hello(9, 1, 0x4D45, 6, 250, 12, 2) and hello.problem() is None
    status = proto.parse(bytes([0x82, 10]) + struct.pack('>BBBHHHHH', 7, 3, 0x05, 1, 2, 3, 4,
                                                         5))
    assert status == proto.Status(10, 7, 3, 0x05, 1, 2, 3, 4, 5) and status.neutral
    for wrong in (bytes([0x81, 0]) + bytes(8), bytes([0x82, 0]) + bytes(14), bytes([0x83, 0])):
        with pytest.raises(proto.ProtocolError):
            proto.parse(wrong)


def test_power_on_is_neutral_and_says_hello():
    w = Wire()
    (hello,) = w.replies
    assert isinstance(hello, proto.Hello) and hello.seq == 0 and hello.problem() is None
    assert (hello.timeout_ms, hello.boot_count, hello.reset_cause) == (250, 1, 1)
    assert w.board.duties() == [685] * 6 and w.board.flags & proto.FLAG_NEUTRAL


def test_set_duty_is_applied_and_acknowledged():
    w = Wire()
    status = w.duty(GOOD)
    assert isinstance(status, proto.Status)
    assert (status.acked, status.result, status.seq) == (1, proto.RESULT_OK, 1)
    assert w.board.duties() == GOOD and not status.neutral
    assert w.duty([685] * 6).neutral


def test_out_of_range_duty_is_refused_whole():
    w = Wire()
    w.duty(GOOD)
    for bad in (429, 941, 0, 0xFFFF):
        status = w.duty([bad] + GOOD[1:])
        assert status.result == proto.RESULT_RANGE
    assert w.board.duties() == GOOD and w.board.counters()['refused'] == 4


def test_duplicate_and_old_sequence_numbers_are_refused_and_counted():
    w = Wire()
    w.duty(GOOD, seq=10)
    assert w.duty([700] * 6, seq=10).result == proto.RESULT_SEQ        # duplicate
    assert w.duty([700] * 6, seq=9).result == proto.RESULT_SEQ         # older
    assert w.duty([700] * 6, seq=10 + 128).result == proto.RESULT_SEQ  # too far: older
    assert w.board.duties() == GOOD and w.board.counters()['seq_errors'] == 3
    assert w.duty([700] * 6, seq=11).result == proto.RESULT_OK
    w.duty([710] * 6, seq=255 - 2)  # 11 -> 253 is 242 ahead: refused
    assert w.board.duties() == [700] * 6
    # Wrap-around: 250 -> 5 is 11 ahead.
    w.send(proto.HELLO_REQ, seq=250)
    assert w.duty(GOOD, seq=5).result == proto.RESULT_OK


def test_hello_request_restarts_the_session_neutral():
    w = Wire()
    w.duty(GOOD, seq=100)
    (hello,) = w.send(proto.HELLO_REQ, seq=3)
    assert isinstance(hello, proto.Hello)
    assert w.board.duties() == [685] * 6
    assert w.duty(GOOD, seq=4).result == proto.RESULT_OK  # 4 is after 3, not after 100


def test_watchdog_puts_outputs_neutral_when_frames_stop():
    w = Wire()
    w.duty(GOOD)
    for _ in range(10):  # heartbeats keep the duties
        w.advance(200)
        assert w.send(proto.HEARTBEAT)[0].result == proto.RESULT_OK
    assert w.board.duties() == GOOD
    w.advance(250)
    assert w.board.duties() == GOOD  # exactly the timeout: not yet
    w.advance(1)
    assert w.board.duties() == [685] * 6
    status = w.send(proto.HEARTBEAT)[0]
    assert status.watchdog_trips == 1 and status.flags & proto.FLAG_TRIPPED and status.neutral
    assert w.board.duties() == [685] * 6  # a heartbeat does not bring the duties back
    assert w.duty(GOOD).result == proto.RESULT_OK and w.board.duties() == GOOD


def test_refused_frames_do_not_feed_the_watchdog():
    w = Wire()
    w.duty(GOOD, seq=50)
    for _ in range(5):
        w.advance(100)
        w.send(proto.HEARTBEAT, seq=50)     # a replayed frame
        w.duty([100] * 6, seq=None)         # out of range
    assert w.board.duties() == [685] * 6 and w.board.counters()['watchdog_trips'] == 1


def test_watchdog_handles_millis_wrap_around():
    w = Wire()
    w.board.reset(0xFFFFFF00)
    w.t = 0xFFFFFF00
    w.read()
    w.duty(GOOD)
    w.t = 0xFFFFFF00 + 200  # past 2**32: the board's millis() wraps
    w.board.tick(w.t & 0xFFFFFFFF)
    assert w.board.duties() == GOOD
    w.board.tick((w.t + 100) & 0xFFFFFFFF)
    assert w.board.duties() == [685] * 6


def test_corrupted_frame_is_counted_and_the_next_one_found():
    w = Wire()
    frame = bytearray(proto.message(proto.SET_DUTY, 1, proto.duty_body(GOOD)))
    frame[5] ^= 0x01
    good = proto.message(proto.SET_DUTY, 2, proto.duty_body([700] * 6))
    w.board.rx(b'\x00\xff' + bytes(frame) + good, w.t)
    (status,) = w.read()
    assert status.acked == 2 and w.board.duties() == [700] * 6
    c = w.board.counters()
    assert c['crc_errors'] == 1 and c['frames'] == 1


def test_frame_starting_inside_a_corrupted_one_is_found():
    w = Wire()
    good = proto.message(proto.SET_DUTY, 1, proto.duty_body(GOOD))
    cut = good[:7]  # a frame cut off: the next frame's bytes complete its length
    w.board.rx(cut + good, w.t)
    w.advance(30)
    assert w.board.duties() == GOOD
    assert w.board.counters()['crc_errors'] >= 1


def test_truncated_frame_is_dropped_after_a_silent_gap():
    w = Wire()
    good = proto.message(proto.SET_DUTY, 1, proto.duty_body(GOOD))
    w.board.rx(good[:9], w.t)
    w.advance(21)
    assert w.board.counters()['truncated'] == 1
    w.board.rx(proto.message(proto.SET_DUTY, 2, proto.duty_body(GOOD)), w.t)
    assert w.board.duties() == GOOD and w.board.counters()['crc_errors'] == 0


def test_too_long_wrong_length_and_unknown_type_are_refused():
    w = Wire()
    w.board.rx(bytes([0xA5, 200]) + bytes(10), w.t)
    assert w.board.counters()['truncated'] == 1
    assert w.send(proto.SET_DUTY, proto.duty_body(GOOD)[:-2])[0].result == proto.RESULT_LENGTH
    assert w.send(0x42)[0].result == proto.RESULT_TYPE
    assert w.send(proto.HEARTBEAT, b'x')[0].result == proto.RESULT_LENGTH
    assert w.board.counters()['refused'] == 3 and w.board.duties() == [685] * 6


def test_config_sets_limits_neutral_and_timeout():
    w = Wire()
    neutral = [690, 680, 690, 680, 690, 680]
    body = proto.config_body(500, 900, 100, neutral)
    status = w.send(proto.CONFIG, body)[0]
    assert status.result == proto.RESULT_OK and status.flags & proto.FLAG_CONFIGURED
    assert w.board.duties() == neutral
    assert w.duty(GOOD).result == proto.RESULT_RANGE  # 940 and 430 are outside now
    assert w.duty([800] * 6).result == proto.RESULT_OK
    w.advance(101)
    assert w.board.duties() == neutral  # the configured timeout and neutral duties
    for bad in (proto.config_body(900, 500, 100, neutral),     # min above max
                proto.config_body(500, 900, 5, neutral),       # timeout too short
                proto.config_body(500, 900, 100, [400] * 6)):  # neutral outside the limits
        assert w.send(proto.CONFIG, bad)[0].result == proto.RESULT_RANGE


def test_counters_in_status_and_boards_are_independent():
    a, b = Wire(), Wire()
    a.duty(GOOD, seq=7)
    a.duty(GOOD, seq=7)
    assert b.duty([700] * 6).seq_errors == 0
    assert a.send(proto.HEARTBEAT, seq=8)[0].seq_errors == 1
    assert a.board.duties() == GOOD and b.board.duties() == [700] * 6


def test_reply_queue_overflow_drops_whole_frames():
    w = Wire()
    for i in range(20):  # no one reads the board's replies
        w.board.rx(proto.message(proto.HEARTBEAT, i + 1), w.t)
    data = w.board.tx()
    d = FrameDecoder()
    payloads = d.feed(data)
    assert payloads and sum(len(p) + 4 for p in payloads) == len(data)
    assert d.crc_errors == 0 and not d.pending
    assert w.board.counters()['tx_dropped'] > 0


def test_status_layout():
    w = Wire()
    w.duty(GOOD)
    raw = proto.message(proto.HEARTBEAT, 2)
    w.board.rx(raw, w.t)
    payload = FrameDecoder().feed(w.board.tx())[0]
    assert payload[0] == proto.STATUS and len(payload) == 15
    assert struct.unpack('>BBBBBHHHHH', payload)[2:5] == (2, 0, 0)


def test_no_compiler_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv('ENBARR_CACHE', str(tmp_path))
    monkeypatch.setenv('CC', 'no-such-cc')
    monkeypatch.setenv('PATH', str(tmp_path))
    with pytest.raises(firmware.FirmwareBuildError, match='no C compiler found.*apt-get'):
        firmware.build()


@pytest.mark.e2e
def test_firmware_builds_for_the_mega(tmp_path):
    if not shutil.which('avr-gcc') or not Path(
            '/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h').is_file():
        pytest.skip(f'AVR toolchain missing: {APT}')
    build = tmp_path / 'build'
    result = subprocess.run(['make', '-C', str(ROOT / 'firmware'), f'BUILD={build}'],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    hex_file = build / 'enbarr_arduino.hex'
    lines = hex_file.read_text().split()
    assert lines[-1] == ':00000001FF' and all(line.startswith(':') for line in lines)
    size = sum(int(line[1:3], 16) for line in lines)
    assert 1000 < size < 253952, size  # the Mega's flash without the bootloader


def test_config_with_a_zero_minimum_or_neutral_duty_is_refused():
    # On the board a duty d is OCR = d * 4 - 1 ticks: ticks(0) wraps to 0xFFFF, above
    # TOP = ICRn = 39999, so no compare match ever clears the output (ATmega2560 data sheet,
    # 16-bit Timer/Counter, fast PWM mode): a constant-high line to the ESCs and servos.
    # Frames typed from link.h: CONFIG = 0x04, body u16 min, u16 max, u16 timeout_ms,
    # 6 x u16 neutral; the answer STATUS = 0x82 with result RANGE = 3.
    w = Wire()
    for lo, neutral in ((0, [685] * 6), (0, [0] * 6), (0, [0, 685, 685, 685, 685, 685])):
        body = struct.pack('>9H', lo, 940, 250, *neutral)
        w.board.rx(proto.encode_frame(bytes([0x04, w.seq + 1]) + body), w.t)
        w.seq += 1
        (status,) = w.read()
        assert (status.acked, status.result) == (w.seq, 3), (lo, neutral, status)
        assert not status.flags & 0x02  # not CONFIGURED
    assert w.board.duties() == [685] * 6
    # The defaults still stand: a zero duty is refused.
    assert w.duty([0] + GOOD[1:]).result == 3 and w.board.duties() == [685] * 6
    # The smallest duty the board can output is one unit (0.01 %, OCR = 3).
    status = w.send(proto.CONFIG, struct.pack('>9H', 1, 940, 250, *[685] * 6))[0]
    assert status.result == 0 and w.duty([1] * 6).result == 0 and w.board.duties() == [1] * 6


@pytest.mark.e2e
def test_protocol_modules_import_without_rclpy():
    """The protocol and firmware modules are pure: a tool or a test can use them without ROS."""
    import sys
    code = ('import sys\nsys.modules["rclpy"] = None\n'
            'import enbarr_plugins.arduino.protocol, enbarr_plugins.arduino.firmware\n'
            'import enbarr_plugins.joystick.ds4_protocol\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=ROOT, timeout=60)
    assert result.returncode == 0, result.stderr
