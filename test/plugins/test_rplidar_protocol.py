"""The RPLidar protocol against the numbers of Slamtec's documents, typed here by hand.

Sources: Slamtec, "RPLIDAR Interface Protocol and Application Notes" (A1 & A2, rev 1.1), the
vendor SDK (github.com/Slamtec/rplidar_sdk: sdk/include/sl_lidar_cmd.h,
sdk/include/sl_lidar_protocol.h, sdk/src/dataunpacker/unpacker/handler_normalnode.cpp) and
"RPLIDAR A1 Introduction and Datasheet" (model A1M8). Both the driver's protocol module and
the emulator's own copy are held to them: neither may borrow the other's.
"""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_plugins.lidar import rplidar_emulator as emulator
from enbarr_plugins.lidar import rplidar_protocol as protocol
from enbarr_plugins.lidar.rplidar_protocol import (
    decode_descriptor, Descriptor, DeviceInfo, Health, request, ScanDecoder)

#: (name, value, where the number is written), typed from the sources above.
DOCUMENTED = [
    ('SYNC', 0xA5, 'sl_lidar_protocol.h SL_LIDAR_CMD_SYNC_BYTE / SL_LIDAR_ANS_SYNC_BYTE1'),
    ('ANS_SYNC', 0x5A, 'sl_lidar_protocol.h SL_LIDAR_ANS_SYNC_BYTE2'),
    ('CMDFLAG_HAS_PAYLOAD', 0x80, 'sl_lidar_protocol.h SL_LIDAR_CMDFLAG_HAS_PAYLOAD'),
    ('CMD_STOP', 0x25, 'sl_lidar_cmd.h SL_LIDAR_CMD_STOP; protocol doc: A5 25'),
    ('CMD_SCAN', 0x20, 'sl_lidar_cmd.h SL_LIDAR_CMD_SCAN; protocol doc: A5 20'),
    ('CMD_FORCE_SCAN', 0x21, 'sl_lidar_cmd.h SL_LIDAR_CMD_FORCE_SCAN; protocol doc: A5 21'),
    ('CMD_RESET', 0x40, 'sl_lidar_cmd.h SL_LIDAR_CMD_RESET; protocol doc: A5 40'),
    ('CMD_GET_INFO', 0x50, 'sl_lidar_cmd.h SL_LIDAR_CMD_GET_DEVICE_INFO; protocol doc: A5 50'),
    ('CMD_GET_HEALTH', 0x52, 'sl_lidar_cmd.h SL_LIDAR_CMD_GET_DEVICE_HEALTH; doc: A5 52'),
    ('ANS_TYPE_DEVINFO', 0x04, 'sl_lidar_cmd.h SL_LIDAR_ANS_TYPE_DEVINFO'),
    ('ANS_TYPE_DEVHEALTH', 0x06, 'sl_lidar_cmd.h SL_LIDAR_ANS_TYPE_DEVHEALTH'),
    ('ANS_TYPE_MEASUREMENT', 0x81, 'sl_lidar_cmd.h SL_LIDAR_ANS_TYPE_MEASUREMENT'),
    ('MODE_SINGLE', 0, 'protocol doc, send mode 0x0: single request - single response'),
    ('MODE_MULTI', 1, 'protocol doc, send mode 0x1: single request - multiple response'),
    ('DESCRIPTOR_SIZE', 7, 'sl_lidar_ans_header_t: 2 sync bytes, u32, u8 type'),
    ('SAMPLE_SIZE', 5, 'sl_lidar_response_measurement_node_t; descriptor A5 5A 05 00 00 40 81'),
    ('INFO_SIZE', 20, 'sl_lidar_response_device_info_t: u8, u16, u8, 16 bytes'),
    ('HEALTH_SIZE', 3, 'sl_lidar_response_device_health_t: u8, u16'),
    ('STATUS_OK', 0, 'sl_lidar_cmd.h SL_LIDAR_STATUS_OK'),
    ('STATUS_WARNING', 1, 'sl_lidar_cmd.h SL_LIDAR_STATUS_WARNING'),
    ('STATUS_ERROR', 2, 'sl_lidar_cmd.h SL_LIDAR_STATUS_ERROR'),
    ('A1_MAJOR', 1, "model >> 4 of the A1 series (SDK: 'A%dM%d', model >> 4, model & 0xF)"),
    ('RANGE_MIN', 0.15, 'A1M8 datasheet, measurement performance: distance range 0.15-12 m'),
    ('RANGE_MAX', 12.0, 'A1M8 datasheet, measurement performance: distance range 0.15-12 m'),
    ('BAUDRATE', 115200, 'A1M8 datasheet and protocol doc: 115200 bps, 8N1'),
    ('SAMPLE_PERIOD_NS', 500_000, 'A1M8 datasheet: sample duration 0.5 ms'),
]


@pytest.mark.parametrize('module', [protocol, emulator], ids=['protocol', 'emulator'])
def test_constants_are_the_documents(module):
    held = [(name, value) for name, value, _ in DOCUMENTED if hasattr(module, name)]
    assert [(name, getattr(module, name)) for name, _ in held] == held
    # the constants every side needs are there to be checked
    needed = {'SYNC', 'ANS_SYNC', 'CMD_STOP', 'CMD_SCAN', 'CMD_RESET', 'CMD_GET_INFO',
              'CMD_GET_HEALTH', 'ANS_TYPE_DEVINFO', 'ANS_TYPE_DEVHEALTH',
              'ANS_TYPE_MEASUREMENT', 'RANGE_MIN', 'RANGE_MAX'}
    assert needed <= {name for name, _ in held}


def test_requests_and_descriptors_are_the_documented_bytes():
    assert request(0x50) == bytes.fromhex('a5 50')  # GET_INFO: no payload, no checksum
    assert request(0x25) == bytes.fromhex('a5 25')
    # EXPRESS_SCAN with 5 zero bytes: checksum = A5 ^ 82 ^ 05 ^ 0 ... = 0x22
    assert request(0x82, bytes(5)) == bytes.fromhex('a5 82 05 00 00 00 00 00 22')
    # the protocol doc's SCAN descriptor: A5 5A 05 00 00 40 81 (5 bytes, multiple, 0x81)
    assert emulator.encode_descriptor(5, 1, 0x81) == bytes.fromhex('a5 5a 05 00 00 40 81')
    assert emulator.encode_descriptor(20, 0, 0x04) == bytes.fromhex('a5 5a 14 00 00 00 04')
    assert decode_descriptor(bytes.fromhex('a5 5a 05 00 00 40 81')) == Descriptor(5, 1, 0x81)
    assert decode_descriptor(bytes.fromhex('a5 5a 03 00 00 00 06')) == Descriptor(3, 0, 6)
    with pytest.raises(ValueError, match='not a response descriptor'):
        decode_descriptor(bytes.fromhex('a5 a5 03 00 00 00 06'))


def test_identity_and_health_decode_as_the_structs_say():
    # model 0x18 (A1M8), firmware 1.29 (u16 0x011D little-endian), hardware 7, serial
    info = DeviceInfo.decode(bytes.fromhex('18 1d 01 07') + bytes(range(16)))
    assert (info.model, info.firmware, info.hardware) == (0x18, (1, 29), 7)
    assert info.model_name == 'A1M8' and info.serial == bytes(range(16)).hex().upper()
    assert Health.decode(bytes.fromhex('02 34 12')) == Health(2, 0x1234)


def test_a_scan_sample_decodes_as_the_document_says():
    # start, quality 47, 90 deg (q6 5760), 1000 mm (q2 4000): BD 01 2D A0 0F
    sample = bytes.fromhex('bd 01 2d a0 0f')
    assert emulator.encode_sample(True, 47, 90.0, 1000.0) == sample
    start, quality, angle, dist = ScanDecoder().feed(sample)
    assert start.tolist() == [True] and quality.tolist() == [47]
    assert angle.tolist() == [90.0] and dist.tolist() == [1000.0]


def test_the_decoder_resynchronises_after_garbage_corruption_and_truncation():
    good = [emulator.encode_sample(k == 0, 30, 10.0 * k, 500.0 + k) for k in range(20)]
    broken = bytes((good[5][0] & 0xFC,)) + good[5][1:]   # S == !S
    stream = (b'\x00\x00' + b''.join(good[:5]) + broken + b''.join(good[6:10])
              + good[10][:3] + b''.join(good[11:]))        # a truncated sample
    dec = ScanDecoder()
    out = [dec.feed(stream[i:i + 7]) for i in range(0, len(stream), 7)]  # any split
    dist = np.concatenate([o[3] for o in out])
    assert dec.sync_losses >= 3 and dec.skipped >= 2
    # every good sample is found again after each loss; the truncated sample's header is
    # intact, so it takes two bytes of the next one (the protocol has no checksum): one
    # bogus distance, one sample lost, then in step again
    d = dist.tolist()
    assert d[:9] == [500.0 + k for k in (*range(5), *range(6, 10))]
    assert d[10:] == [500.0 + k for k in range(12, 20)]


def test_an_in_step_sample_with_the_check_bit_cleared_is_not_taken():
    """C (byte 1, bit 0) is always 1 in a sample: one with C == 0 is no sample, even when the
    stream is in step and its start-flag pair is right."""
    good = [emulator.encode_sample(k == 0, 30, 1.0 * k, 1000.0 + 10 * k) for k in range(40)]
    bad = good[20][:1] + bytes((good[20][1] & 0xFE,)) + good[20][2:]
    assert bad[0] & 0b11 == 0b10 and not bad[1] & 1   # S, !S fine; C cleared
    dec = ScanDecoder()
    _, _, _, dist = dec.feed(b''.join(good[:20]) + bad + b''.join(good[21:]))
    assert 1200.0 not in dist.tolist() and dec.sync_losses == 1
