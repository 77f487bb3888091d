"""The RPLidar protocol against the numbers of Slamtec's documents, typed here by hand.

Sources: Slamtec, "RPLIDAR Interface Protocol and Application Notes" (A1 & A2, rev 1.1), the
vendor SDK (github.com/Slamtec/rplidar_sdk: sdk/include/sl_lidar_cmd.h,
sdk/include/sl_lidar_protocol.h, sdk/src/dataunpacker/unpacker/handler_normalnode.cpp) and
"RPLIDAR A1 Introduction and Datasheet" (model A1M8). Both the driver's protocol module and
the emulator's own copy are held to them: neither may borrow the other's.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from enbarr_plugins.lidar import rplidar_emulator as emulator
from enbarr_plugins.lidar import rplidar_protocol as protocol
from enbarr_plugins.lidar.rplidar_protocol import (
    decode_descriptor, Descriptor, DeviceInfo, Health, RANGE_MAX, RANGE_MIN, request,
    ScanDecoder)
from enbarr_plugins.lidar.scan import bin_revolution, RevolutionAssembler
from enbarr_core.world.model import Circle, Obstacle, Walls, World

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
    # the decoder takes a sample once it and the samples after it fit together
    after = b''.join(emulator.encode_sample(False, 47, 90.0 + k, 1000.0) for k in range(1, 4))
    start, quality, angle, dist = ScanDecoder().feed(sample + after)
    assert start.tolist() == [True] and quality.tolist() == [47]
    assert angle.tolist() == [90.0] and dist.tolist() == [1000.0]


def test_the_decoder_resynchronises_after_garbage_corruption_and_truncation():
    good = [emulator.encode_sample(k == 0, 30, 1.0 * k, 500.0 + k) for k in range(60)]
    broken = bytes((good[20][0] & 0xFC,)) + good[20][1:]   # S == !S
    stream = (b'\x00\x00\x01' + b''.join(good[:20]) + broken + b''.join(good[21:40])
              + good[40][:3] + b''.join(good[41:]))        # a truncated sample
    dec = ScanDecoder()
    out = [dec.feed(stream[i:i + 7]) for i in range(0, len(stream), 7)]  # any split
    dist = np.concatenate([o[3] for o in out]).tolist()
    assert dec.sync_losses == 2 and dec.skipped >= 3
    # nothing invented: every distance taken is a sample's own, in order; the truncated one
    # (its header intact, its distance the next sample's first bytes) is not taken
    assert dist == sorted(dist) and set(dist) <= {500.0 + k for k in range(60)}
    assert 540.0 not in dist
    # in step again after each fault: the samples away from the faults are all there (the
    # last three wait for the samples after them)
    assert {500.0 + k for k in (*range(17), *range(24, 37), *range(45, 57))} <= set(dist)


def test_an_in_step_sample_with_the_check_bit_cleared_is_not_taken():
    """C (byte 1, bit 0) is always 1 in a sample: one with C == 0 is no sample, even when the
    stream is in step and its start-flag pair is right."""
    good = [emulator.encode_sample(k == 0, 30, 1.0 * k, 1000.0 + 10 * k) for k in range(40)]
    bad = good[20][:1] + bytes((good[20][1] & 0xFE,)) + good[20][2:]
    assert bad[0] & 0b11 == 0b10 and not bad[1] & 1   # S, !S fine; C cleared
    dec = ScanDecoder()
    _, _, _, dist = dec.feed(b''.join(good[:20]) + bad + b''.join(good[21:]))
    assert 1200.0 not in dist.tolist() and dec.sync_losses == 1


def test_samples_whose_angle_does_not_advance_are_no_stream():
    """Byte runs out of step often read as a constant angle (a quality byte and a distance
    byte that hardly change): their headers pass, their angles do not turn."""
    still = [emulator.encode_sample(False, 15, 124.0, 2000.0) for _ in range(20)]
    back = [emulator.encode_sample(False, 15, 124.0 - k, 2000.0) for k in range(20)]
    leap = [emulator.encode_sample(False, 15, 30.0 * k, 2000.0) for k in range(12)]
    for run in (still, back, leap):
        dec = ScanDecoder()
        assert dec.feed(b''.join(run))[2].tolist() == [] and dec.skipped > 0
    # nor in step: a good run, then angles that stand still
    good = [emulator.encode_sample(False, 15, 100.0 + k, 2000.0) for k in range(10)]
    stuck = [emulator.encode_sample(False, 15, 110.0, 2000.0) for _ in range(10)]
    dec = ScanDecoder()
    # 110 deg fits once, then stands still: it and the two held before it are dropped
    assert dec.feed(b''.join(good + stuck))[2].tolist() == [100.0 + k for k in range(8)]


# -- corruption swept over every position of a revolution -----------------------------------
PER_REV = 364        # samples a revolution at 5.5 Hz and 2000 samples/s, as the emulator sends
READ = 500           # bytes a read: 50 ms of the stream


def clear_check_bit(sample: bytes) -> bytes:
    return sample[:1] + bytes((sample[1] & 0xFE,)) + sample[2:]


def break_start_pair(sample: bytes) -> bytes:
    return bytes((sample[0] & 0xFC,)) + sample[1:]       # S == !S == 0


def truncate(sample: bytes) -> bytes:
    return sample[:3]                                    # bytes lost on the line


@functools.cache
def clean_revolutions() -> tuple[tuple[bytes, ...], ...]:
    """Revolutions of the emulator's samples: a vessel in the MC-lab basin, a buoy ahead."""
    basin = Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225), (-20.0, 3.225)), closed=True)
    emu = emulator.RplidarEmulator(world=World([Obstacle('basin', basin),
                                                Obstacle('buoy', Circle((1.5, 0.8), 0.3))]))
    emu.set_pose(0.0, 0.2, 0.3)
    step = 360.0 / PER_REV
    revolutions = []
    for r in range(PER_REV + 4):
        angles = (np.arange(PER_REV) * step + (r * 0.37) % step) % 360.0
        dist = emu.ranges_mm(angles)
        revolutions.append(tuple(
            emulator.encode_sample(k == 0, 47 if dist[k] > 0 else 0, float(angles[k]),
                                   float(dist[k])) for k in range(PER_REV)))
    return tuple(revolutions)


def swept_stream(corrupt, run: int) -> tuple[list[list[bytes]], bytes]:
    """The clean revolutions with, in revolution 2 + p, the samples p .. p + run - 1
    corrupted, for every position p; returns the samples sent intact and the stream."""
    revolutions, stream = [], bytearray()
    for r, clean in enumerate(clean_revolutions()):
        sent = []
        for k, sample in enumerate(clean):
            if 0 <= r - 2 <= k < r - 2 + run:
                sample = corrupt(sample)
            else:
                sent.append(sample)
            stream += sample
        revolutions.append(sent)
    return revolutions, bytes(stream)


def as_tuples(samples: list[bytes]) -> list[tuple[float, float]]:
    """(angle [deg], distance [mm]) of samples, decoded here from the document's layout."""
    return [(((s[1] | s[2] << 8) >> 1) / 64.0, (s[3] | s[4] << 8) / 4.0) for s in samples]


def phantoms(taken: list, sent: list) -> list:
    """The samples of ``taken`` that are not ``sent`` ones in the order sent."""
    out, j = [], 0
    for t in taken:
        try:
            j = sent.index(t, j, j + 2 * PER_REV) + 1
        except ValueError:
            out.append(t)
    return out


@pytest.mark.parametrize('corrupt, run', [(clear_check_bit, 1), (clear_check_bit, 3),
                                          (break_start_pair, 1), (truncate, 1)],
                         ids=['check bit', 'three check bits', 'start pair', 'truncated'])
def test_corruption_anywhere_in_a_revolution_lets_no_phantom_through(corrupt, run):
    revolutions, stream = swept_stream(corrupt, run)
    decoder, assembler = ScanDecoder(), RevolutionAssembler()
    taken, scans = [], []
    for i in range(0, len(stream), READ):
        start, _, angle, dist = decoder.feed(stream[i:i + READ])
        taken += zip(angle.tolist(), dist.tolist())
        scans += assembler.add(start, angle, dist, 0)
    # every sample taken is one that was sent intact, in the order sent
    assert phantoms(taken, [t for rev in revolutions for t in as_tuples(rev)]) == []
    assert len(taken) > 0.95 * sum(map(len, revolutions))  # few good samples lost
    # one scan per revolution (the last is not finished), angles increasing
    assert len(scans) == len(revolutions) - 1
    for scan, truth in zip(scans, revolutions):
        assert (np.diff(scan.angle_deg) > 0).all()
        ranges = bin_revolution(scan.angle_deg, scan.distance_mm, 360, RANGE_MIN, RANGE_MAX)
        finite = ranges[np.isfinite(ranges)]
        assert ((finite >= RANGE_MIN) & (finite <= RANGE_MAX)).all()
        assert not (ranges == -np.inf).any()   # nothing came that close
        assert set(finite.tolist()) <= {d * 1e-3 for _, d in as_tuples(truth)}
