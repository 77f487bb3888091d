"""The obstacle encoding: round trip, field layout as a generic reader sees it, and refusals."""

from __future__ import annotations

import math
import struct

import pytest
from sensor_msgs.msg import PointCloud2, PointField

from enbarr_interfaces import obstacles as ob

pytestmark = pytest.mark.unit

# sensor_msgs/msg/PointField.msg: UINT32 = 6, FLOAT64 = 8 (typed from the message definition).
UINT32, FLOAT64 = 6, 8

BUOY = ob.Obstacle(7, ob.CIRCLE, 1.5, -2.0, 0.3, vx=0.2, vy=-0.1,
                   position_cov=(0.01, 0.002, 0.02), velocity_cov=(0.04, 0.0, 0.05),
                   stamp_ns=1_700_000_123_456_789_012)
WALL = ob.Obstacle(9, ob.SEGMENT, -20.0, 3.225, 0.0, x2=20.0, y2=3.225,
                   stamp_ns=2_000_000_001)


def test_round_trip_keeps_every_field_exactly() -> None:
    msg = ob.to_cloud([BUOY, WALL], 5_000_000_007, 'odom')
    assert msg.header.frame_id == 'odom'
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (5, 7)
    assert ob.from_cloud(msg) == [BUOY, WALL]


def test_layout_as_a_generic_point_cloud_reader_sees_it() -> None:
    msg = ob.to_cloud([BUOY], 0, 'odom')
    fields = {f.name: f for f in msg.fields}
    assert [f.datatype for f in msg.fields[:4]] == [UINT32] * 4
    assert all(f.datatype == FLOAT64 for f in msg.fields[4:])
    assert msg.width == 1 and msg.height == 1 and msg.point_step == len(msg.data)
    raw = bytes(msg.data)

    def f8(name: str) -> float:
        return struct.unpack_from('<d', raw, fields[name].offset)[0]

    def u4(name: str) -> int:
        return struct.unpack_from('<I', raw, fields[name].offset)[0]

    assert (u4('id'), u4('kind')) == (7, 0)
    assert (u4('stamp_sec'), u4('stamp_nanosec')) == (1_700_000_123, 456_789_012)
    assert (f8('x'), f8('y'), f8('x2'), f8('y2'), f8('radius')) == (1.5, -2.0, 1.5, -2.0, 0.3)
    assert (f8('vx'), f8('vy'), f8('cov_xy'), f8('cov_vyvy')) == (0.2, -0.1, 0.002, 0.05)


def test_a_message_from_elsewhere_decodes_as_one_written_here() -> None:
    """Fields that are not our own objects (a message off DDS) take the checked path."""
    for classes in (False, True):
        here = ob.to_cloud([BUOY, WALL], 3, 'odom', classes=classes)
        there = ob.to_cloud([BUOY, WALL], 3, 'odom', classes=classes)
        there.fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype,
                                   count=f.count) for f in there.fields]
        assert ob._own_rows(here) is not None and ob._own_rows(there) is None
        assert ob.from_cloud(here) == ob.from_cloud(there) == [BUOY, WALL]
        assert bytes(here.data) == ob.to_array([BUOY, WALL], classes).tobytes()


def test_fields_are_found_by_name_not_position() -> None:
    msg = ob.to_cloud([BUOY, WALL], 0, 'odom')
    msg.fields = list(reversed(msg.fields))
    assert ob.from_cloud(msg) == [BUOY, WALL]


def test_empty_message_decodes_to_no_obstacles() -> None:
    assert ob.from_cloud(ob.to_cloud([], 0, 'odom')) == []


@pytest.mark.parametrize('break_it, words', [
    (lambda m: setattr(m, 'fields', [f for f in m.fields if f.name != 'radius']),
     'missing field(s) radius'),
    (lambda m: setattr(m, 'data', bytes(m.data)[:-1]), 'bytes of data for 2 points'),
    (lambda m: setattr(m, 'is_bigendian', True), 'big-endian'),
    (lambda m: m.fields.__setitem__(1, PointField(name='kind', offset=m.fields[1].offset,
                                                  datatype=42, count=1)),
     "field 'kind' has datatype 42"),
])
def test_a_malformed_cloud_names_what_is_wrong(break_it, words) -> None:
    msg = ob.to_cloud([BUOY, WALL], 0, 'odom')
    break_it(msg)
    with pytest.raises(ob.ObstacleEncodingError, match=words.replace('(', r'\(')
                       .replace(')', r'\)')):
        ob.from_cloud(msg)


def test_unknown_kind_is_refused() -> None:
    msg = ob.to_cloud([BUOY], 0, 'odom')
    data = bytearray(msg.data)
    kind_at = next(f.offset for f in msg.fields if f.name == 'kind')
    data[kind_at:kind_at + 4] = struct.pack('<I', 5)
    msg.data = bytes(data)
    with pytest.raises(ob.ObstacleEncodingError, match='kind 5'):
        ob.from_cloud(msg)


def test_distance_to_a_circle_and_to_a_segment() -> None:
    assert BUOY.distance(1.5, 0.0) == pytest.approx(2.0 - 0.3)
    assert BUOY.distance(1.5, -2.0) == pytest.approx(-0.3)       # at the centre: inside
    assert WALL.distance(3.0, 0.0) == pytest.approx(3.225)        # perpendicular foot
    assert WALL.distance(23.0, 7.225) == pytest.approx(5.0)       # past the end: the end
    assert ob.closest_on_segment(1.0, 1.0, 0.0, 0.0, 0.0, 0.0) == (0.0, 0.0)
    assert math.isclose(WALL.distance(-20.0, 3.225), 0.0)


def test_cloud_type_is_sensor_msgs_point_cloud2() -> None:
    assert isinstance(ob.to_cloud([], 0, 'odom'), PointCloud2)


# sensor_msgs/msg/PointField.msg: INT32 = 5 (typed from the message definition).
INT32 = 5
CLASSED = ob.Obstacle(3, ob.CIRCLE, 2.0, 1.0, 0.15, vx=0.1, stamp_ns=9, class_id=2,
                      class_score=0.75)


def test_class_fields_round_trip_and_are_named_and_typed() -> None:
    msg = ob.to_cloud([CLASSED, WALL], 0, 'odom')
    assert ob.from_cloud(msg) == [CLASSED, WALL]
    fields = {f.name: f for f in msg.fields}
    assert fields['class_id'].datatype == INT32 and fields['class_score'].datatype == FLOAT64
    raw = bytes(msg.data)
    second = msg.point_step
    assert struct.unpack_from('<i', raw, fields['class_id'].offset)[0] == 2
    assert struct.unpack_from('<i', raw, second + fields['class_id'].offset)[0] == -1
    assert struct.unpack_from('<d', raw, fields['class_score'].offset)[0] == 0.75


def test_without_any_class_the_message_is_the_old_layout() -> None:
    msg = ob.to_cloud([BUOY, WALL], 0, 'odom')
    assert [f.name for f in msg.fields] == [name for name, *_ in ob.FIELDS]
    assert 'class_id' not in {f.name for f in msg.fields}
    # asked for, the fields are written also when nothing has a class
    forced = ob.to_cloud([BUOY], 0, 'odom', classes=True)
    assert ob.from_cloud(forced)[0].class_id == ob.NO_CLASS


def test_an_old_message_without_class_fields_decodes_unclassified() -> None:
    # A message as a writer that predates the class fields builds it: FIELDS only.
    msg = ob.to_cloud([BUOY], 0, 'odom')
    msg.fields = [f for f in msg.fields if f.name not in ('class_id', 'class_score')]
    (got,) = ob.from_cloud(msg)
    assert got == BUOY and got.class_id == -1 and got.class_score == 0.0


def test_an_old_reader_reads_a_classed_message() -> None:
    # A reader that knows only FIELDS (by name) finds them all in a message with classes.
    msg = ob.to_cloud([CLASSED], 0, 'odom')
    rows = ob.read_fields(msg, [name for name, *_ in ob.FIELDS], 'obstacles',
                          ob.ObstacleEncodingError)
    assert (rows['id'][0], rows['x'][0], rows['radius'][0]) == (3, 2.0, 0.15)
