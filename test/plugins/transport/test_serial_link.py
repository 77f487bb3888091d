"""Framed serial link: CRC-16/CCITT-FALSE, resynchronisation, and a real pty as the port."""

from __future__ import annotations

import errno
import os
import time

import pytest

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.transport import serial_link
from enbarr_plugins.transport.serial_link import (
    FrameDecoder, SerialLink, START, crc16_ccitt_false, encode_frame, open_serial)


def test_crc_matches_the_published_check_value():
    # CRC-16/CCITT-FALSE (CRC-16/IBM-3740 in Greg Cook's catalogue): check = 0x29B1.
    assert crc16_ccitt_false(b'123456789') == 0x29B1
    assert crc16_ccitt_false(b'') == 0xFFFF
    assert crc16_ccitt_false(b'56789', crc16_ccitt_false(b'1234')) == 0x29B1


def test_frame_layout():
    frame = encode_frame(b'\x01\x02')
    assert frame[:2] == bytes([START, 2]) and frame[2:4] == b'\x01\x02'
    assert int.from_bytes(frame[4:], 'big') == crc16_ccitt_false(b'\x02\x01\x02')
    with pytest.raises(ValueError, match='payload'):
        encode_frame(bytes(256))


def test_frames_split_across_reads_are_joined():
    decoder = FrameDecoder()
    stream = encode_frame(b'abc') + encode_frame(b'') + encode_frame(bytes([START] * 3))
    out = []
    for i in range(len(stream)):
        out += decoder.feed(stream[i:i + 1])
    assert out == [b'abc', b'', bytes([START] * 3)]
    assert decoder.counters() == {'frames': 3, 'garbage': 0, 'crc_errors': 0, 'too_long': 0,
                                  'truncated': 0}


def test_garbage_before_a_frame_is_skipped_and_counted():
    decoder = FrameDecoder()
    assert decoder.feed(b'\x00\x11\x22' + encode_frame(b'x')) == [b'x']
    assert decoder.garbage == 3 and decoder.frames == 1


def test_a_crc_error_resynchronises_on_the_next_frame():
    decoder = FrameDecoder()
    bad = bytearray(encode_frame(b'hello'))
    bad[3] ^= 0xFF
    assert decoder.feed(bytes(bad) + encode_frame(b'ok')) == [b'ok']
    assert decoder.crc_errors == 1 and decoder.frames == 1


def test_a_frame_inside_a_corrupted_one_is_found():
    # A frame whose length byte was corrupted to a large value swallows the next frame; the
    # decoder must find that frame again after the CRC fails.
    decoder = FrameDecoder()
    good = encode_frame(b'inner')
    corrupt = bytes([START, len(good) + 2]) + good + b'\x00\x00\x00\x00'
    assert decoder.feed(corrupt) == [b'inner']
    assert decoder.crc_errors == 1


def test_a_length_above_the_limit_is_refused():
    decoder = FrameDecoder(max_payload=8)
    assert decoder.feed(bytes([START, 200]) + encode_frame(b'ok')) == [b'ok']
    assert decoder.too_long == 1


def test_a_truncated_frame_is_dropped_on_flush():
    decoder = FrameDecoder()
    assert decoder.feed(encode_frame(b'cut off')[:5]) == []
    assert decoder.pending == 5
    assert decoder.flush_partial()
    assert decoder.truncated == 1 and decoder.pending == 0
    assert not decoder.flush_partial()
    assert decoder.feed(encode_frame(b'next')) == [b'next']


def test_flush_keeps_a_later_start_byte():
    decoder = FrameDecoder()
    head = encode_frame(b'next')[:3]
    decoder.feed(encode_frame(b'a longer frame, cut')[:4] + head)
    decoder.flush_partial()
    assert decoder.pending == len(head)
    assert decoder.feed(encode_frame(b'next')[3:]) == [b'next']


@pytest.fixture
def pty():
    """A pseudo-terminal: the test writes at ``master``, the link opens the slave by name."""
    master, slave = os.openpty()
    name = os.ttyname(slave)
    try:
        yield master, name
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


def read_until(link: SerialLink, n: int, timeout: float = 5.0) -> list[bytes]:
    out: list[bytes] = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        out += link.read_frames()
    return out


def test_frames_over_a_pty(pty):
    master, name = pty
    link = SerialLink.open(name, timeout=0.05)
    try:
        os.write(master, b'\xff' + encode_frame(b'one') + encode_frame(b'two'))
        assert read_until(link, 2) == [b'one', b'two']
        assert link.decoder.garbage == 1
        link.write_frame(b'cmd')
        assert os.read(master, 64) == encode_frame(b'cmd')
        assert link.sent == 1
    finally:
        link.close()


def test_silence_mid_frame_counts_a_truncation_over_a_pty(pty):
    master, name = pty
    link = SerialLink.open(name, timeout=0.05)
    try:
        os.write(master, encode_frame(b'partial')[:4])
        start = time.monotonic()
        deadline = start + 5.0
        while link.decoder.truncated == 0 and time.monotonic() < deadline:
            assert link.read_frames() == []
        assert link.decoder.truncated == 1
        os.write(master, encode_frame(b'whole'))
        assert read_until(link, 1) == [b'whole']
    finally:
        link.close()


def test_read_waits_no_longer_than_the_timeout(pty):
    _, name = pty
    link = SerialLink.open(name, timeout=0.05)
    try:
        start = time.monotonic()
        assert link.read_frames() == []
        assert time.monotonic() - start < 1.0  # bounded by the port's timeout, not forever
    finally:
        link.close()


def test_opening_a_missing_port_names_it():
    with pytest.raises(DeviceError, match='/dev/enbarr-no-such-port: cannot open'):
        open_serial('/dev/enbarr-no-such-port')


def test_a_closed_port_is_a_device_error(pty):
    _, name = pty
    link = SerialLink.open(name, timeout=0.05)
    link.serial.close()
    with pytest.raises(DeviceError, match=f'{name}: read failed'):
        link.read_frames()
    with pytest.raises(DeviceError, match=f'{name}: write failed'):
        link.write_frame(b'x')


# -- a vanished USB serial node: steer to /dev/serial/by-id ---------------------------------

class _Unplugged:
    """A port whose device was unplugged, failing the way pyserial does (an errno inside)."""

    def __init__(self, code: int) -> None:
        self.code = code
        self.in_waiting = 0

    def _fail(self) -> None:
        import serial
        try:
            raise OSError(self.code, os.strerror(self.code))
        except OSError as err:  # pyserial raises its own error inside the handler
            raise serial.SerialException(f'read failed: {err}')  # noqa: B904 - as pyserial

    def read(self, n: int) -> bytes:
        self._fail()
        return b''

    def write(self, data: bytes) -> int:
        self._fail()
        return 0


@pytest.fixture
def by_id(tmp_path, monkeypatch):
    d = tmp_path / 'by-id'
    d.mkdir()
    (d / 'usb-Arduino__www.arduino.cc__0042_7543331373935161D021-if00').touch()
    monkeypatch.setattr(serial_link, 'BY_ID_DIR', d)
    return d


@pytest.mark.parametrize('code', [errno.EIO, errno.ENODEV])
def test_a_vanished_usb_port_suggests_its_by_id_link(by_id, monkeypatch, code):
    monkeypatch.setattr(serial_link, '_node_exists', lambda path: True)  # still listed
    link = SerialLink(_Unplugged(code), '/dev/ttyUSB0')
    for action in (link.read_frames, lambda: link.write_frame(b'x')):
        with pytest.raises(DeviceError) as info:
            action()
        text = str(info.value)
        assert text.startswith('/dev/ttyUSB0: ') and '/dev/ttyUSB0 is gone' in text, text
        assert f'{by_id}/usb-<vendor>_<model>_<serial>-if00' in text
        assert 'present now: usb-Arduino__www.arduino.cc__0042_7543331373935161D021-if00' in text


def test_opening_a_usb_port_that_is_not_there_suggests_by_id(by_id):
    with pytest.raises(DeviceError, match=r'/dev/ttyACM97: cannot open .*/dev/ttyACM97 is gone'
                       r'.*another /dev/ttyUSBn or /dev/ttyACMn.*docs/hardware.md'):
        open_serial('/dev/ttyACM97')


def test_no_by_id_hint_for_other_errors_and_other_names(by_id, monkeypatch):
    monkeypatch.setattr(serial_link, '_node_exists', lambda path: True)
    denied = OSError(errno.EACCES, 'Permission denied')
    assert serial_link.vanished_port_hint('/dev/ttyUSB0', denied) == ''  # there, not ours
    gone = OSError(errno.ENODEV, 'No such device')
    assert serial_link.vanished_port_hint('/dev/ttyUSB0', gone) != ''
    for stable in (f'{by_id}/usb-x-if00', '/dev/pts/3', '/dev/ttyS0', '/dev/ttyUSB'):
        assert serial_link.vanished_port_hint(stable, gone) == '', stable
    monkeypatch.setattr(serial_link, '_node_exists', lambda path: False)
    assert serial_link.vanished_port_hint('/dev/ttyACM1') != ''  # the node itself is gone


def test_a_closed_pty_gets_no_by_id_hint(pty):
    _, name = pty
    link = SerialLink.open(name, timeout=0.05)
    link.serial.close()
    with pytest.raises(DeviceError) as info:
        link.read_frames()
    assert 'by-id' not in str(info.value)


def test_a_missing_by_id_link_lists_the_links_present(by_id):
    # The profile's placeholder, or a board with another serial number.
    with pytest.raises(DeviceError) as info:
        open_serial(f'{by_id}/usb-Arduino__www.arduino.cc__0042_SERIAL-if00')
    text = str(info.value)
    assert 'no such link' in text and ('links present now: '
                                       'usb-Arduino__www.arduino.cc__0042_7543331373935161D021'
                                       '-if00') in text, text
