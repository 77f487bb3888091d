"""The generated CDR encoders against rclpy's serialize_message, byte for byte.

Random field values (seeded), strings of several lengths (empty, 1..12 bytes, non-ASCII),
sequences of 0..4 elements, covariances. CDR leaves the alignment padding unspecified and
rmw_fastrtps leaves whatever its buffer held there, so padding bytes (found as the bytes
where an encoder that pads with 0xEE differs from the zero-padding one) are compared only in
position and number; every other byte must be equal, and the end must be the CDR end.
"""

from __future__ import annotations

import random

import numpy as np
import pytest
import rosidl_parser.definition as idl
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import get_typestore, Stores

from enbarr_core.recording import cdr
from enbarr_interfaces.topics import ALL_TOPICS

pytestmark = pytest.mark.unit

TYPES = sorted({spec.msg_type for spec in ALL_TOPICS}, key=lambda c: c.__name__)
STRINGS = ['', 'a', 'ab', 'abc', 'base_link', 'odom_é', 'x' * 12]
INTS = {'int8': 7, 'int16': 15, 'int32': 31, 'int64': 63}
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
UINTS = {'uint8': 8, 'uint16': 16, 'uint32': 32, 'uint64': 64}


def _value(t, rng: random.Random):
    if isinstance(t, idl.BasicType):
        name = t.typename
        if name in INTS:
            return rng.randrange(-2 ** INTS[name], 2 ** INTS[name])
        if name in UINTS:
            return rng.randrange(0, 2 ** UINTS[name])
        if name == 'octet':
            return bytes([rng.randrange(256)])
        if name == 'boolean':
            return rng.random() < 0.5
        if name == 'float':
            return float(np.float32(rng.uniform(-1e3, 1e3)))
        return rng.uniform(-1e6, 1e6)
    if isinstance(t, idl.AbstractGenericString):
        return rng.choice(STRINGS)
    if isinstance(t, idl.NamespacedType):
        return _fill(cdr._message_class(t)(), rng)
    if isinstance(t, idl.Array):
        return [_value(t.value_type, rng) for _ in range(t.size)]
    if isinstance(t, idl.AbstractSequence):
        return [_value(t.value_type, rng) for _ in range(rng.randrange(5))]
    raise AssertionError(t)


def _fill(msg, rng: random.Random):
    for slot, t in zip(msg.__slots__, msg.SLOT_TYPES):
        setattr(msg, slot.lstrip('_'), _value(t, rng))
    return msg


def _check(msg) -> None:
    cls = type(msg)
    mine = cdr.encoder(cls)(msg)
    marked = cdr.padding_marking_encoder(cls)(msg)
    theirs = serialize_message(msg)
    assert len(marked) == len(mine)
    pad = [i for i in range(len(mine)) if mine[i] != marked[i]]
    assert all(mine[i] == 0 and marked[i] == 0xEE for i in pad)
    # rmw_fastrtps may return trailing bytes for string sequences (an estimated size); never
    # fewer than the CDR.
    assert len(theirs) >= len(mine), cls.__name__
    strip = bytearray(theirs[:len(mine)])
    for i in pad:
        strip[i] = 0
    assert bytes(strip) == mine, cls.__name__
    # The end is the CDR end: rosbags' strict decoder reads exactly len(mine) bytes.
    ts = TYPESTORE
    name = f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'
    msgdef = ts.get_msgdef(name)
    _, end = msgdef.deserialize_cdr_le(memoryview(mine)[4:], 0, msgdef.cls, ts)
    assert 4 + end == len(mine)
    assert deserialize_message(mine, cls) == msg


@pytest.mark.parametrize('cls', TYPES, ids=lambda c: c.__name__)
def test_encoder_matches_serialize_message(cls) -> None:
    assert cdr.encoder(cls) is not None
    rng = random.Random(f'cdr-{cls.__name__}')
    _check(cls())  # defaults: empty strings and sequences
    for _ in range(60):
        _check(_fill(cls(), rng))


def test_every_string_length_around_each_alignment() -> None:
    from sensor_msgs.msg import Imu, JointState
    from nav_msgs.msg import Odometry
    for n in range(0, 18):
        for cls in (Imu, Odometry, JointState):
            m = _fill(cls(), random.Random(n))
            m.header.frame_id = 'f' * n
            if cls is Odometry:
                m.child_frame_id = 'c' * (17 - n)
            if cls is JointState:
                m.name = ['n' * k for k in range(n % 5)]
                m.position = [] if n % 2 else [1.0] * (n % 4)
            _check(m)


def test_a_type_with_a_wide_string_falls_back() -> None:
    class Wide:
        __slots__ = ('_x', '_text')
        SLOT_TYPES = (idl.BasicType('double'), idl.UnboundedWString())
    assert cdr.encoder(Wide) is None
