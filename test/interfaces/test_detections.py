"""The detections encoding (a PointCloud2 with named fields) and the image conversions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage, Image, PointField

from enbarr_interfaces import convert
from enbarr_interfaces.detections import DetectionEncodingError, from_cloud, to_cloud
from enbarr_interfaces.image_msgs import (
    bgr_to_image, compressed_to_bgr, image_to_bgr, ImageEncodingError)

pytestmark = pytest.mark.unit

ROWS = [(2, 0.75, 10.0, 20.0, 30.5, 40.25), (0, 0.5, 0.0, 0.0, 1.0, 1.0)]


def test_detections_round_trip_with_stamp_and_frame() -> None:
    msg = to_cloud(ROWS, 1_700_000_000_123_456_789, 'camera_optical_frame')
    assert convert.stamp_to_ns(msg.header.stamp) == 1_700_000_000_123_456_789
    assert msg.header.frame_id == 'camera_optical_frame'
    assert (msg.height, msg.width, msg.point_step) == (1, 2, 24)
    assert from_cloud(msg).tolist() == ROWS


def test_the_wire_layout_is_the_documented_one() -> None:
    # docs/interfaces.md "Detections": class_id UINT32 then five FLOAT32, little-endian
    msg = to_cloud(ROWS[:1], 0, 'cam')
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('class_id', 0, 6, 1), ('score', 4, 7, 1), ('x_min', 8, 7, 1), ('y_min', 12, 7, 1),
        ('x_max', 16, 7, 1), ('y_max', 20, 7, 1)]
    assert bytes(msg.data)[:8] == bytes([2, 0, 0, 0, 0, 0, 0x40, 0x3f])   # 2, 0.75f


def test_an_empty_frame_is_an_empty_cloud() -> None:
    msg = to_cloud([], 5, 'cam')
    assert msg.width == 0 and len(msg.data) == 0 and from_cloud(msg).shape == (0,)


def test_fields_are_found_by_name_whatever_their_order_and_type() -> None:
    msg = to_cloud(ROWS, 0, 'cam')
    msg.fields = list(reversed(msg.fields))             # order is not the contract
    assert from_cloud(msg).tolist() == ROWS
    msg.fields = [f for f in msg.fields if f.name != 'score']
    with pytest.raises(DetectionEncodingError, match='missing field.*score'):
        from_cloud(msg)
    msg = to_cloud(ROWS, 0, 'cam')
    msg.fields[1] = PointField(name='score', offset=4, datatype=99, count=1)   # not shared
    with pytest.raises(DetectionEncodingError, match="field 'score' has datatype 99"):
        from_cloud(msg)
    msg = to_cloud(ROWS, 0, 'cam')
    msg.fields[5] = PointField(name='y_max', offset=22, datatype=7, count=1)   # 22 + 4 > 24
    with pytest.raises(DetectionEncodingError,
                       match="field 'y_max' at offset 22 does not fit a point of 24 bytes"):
        from_cloud(msg)
    msg = to_cloud(ROWS, 0, 'cam')
    msg.data = bytes(msg.data)[:30]
    with pytest.raises(DetectionEncodingError, match='30 bytes of data for 2 points of 24'):
        from_cloud(msg)
    assert PointField.FLOAT32 == 7 and PointField.UINT32 == 6   # sensor_msgs/PointField.msg


def test_images_are_read_in_their_encoding_and_row_step() -> None:
    bgr = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    msg = bgr_to_image(bgr)
    assert (msg.encoding, msg.step) == ('bgr8', 9)
    assert np.array_equal(image_to_bgr(msg), bgr) and image_to_bgr(msg).flags.writeable
    rgb = Image(height=2, width=3, encoding='rgb8', step=12,   # 3 bytes of row padding
                data=np.pad(bgr[..., ::-1].reshape(2, 9), ((0, 0), (0, 3))).tobytes())
    assert np.array_equal(image_to_bgr(rgb), bgr)
    mono = Image(height=1, width=2, encoding='mono8', step=2, data=bytes([7, 9]))
    assert image_to_bgr(mono).tolist() == [[[7, 7, 7], [9, 9, 9]]]
    with pytest.raises(ImageEncodingError, match="encoding '32FC1' is not read"):
        image_to_bgr(Image(height=1, width=1, encoding='32FC1', step=4, data=bytes(4)))
    with pytest.raises(ImageEncodingError, match='3 x 2 bgr8: step 9, 10 bytes do not hold'):
        image_to_bgr(Image(height=2, width=3, encoding='bgr8', step=9, data=bytes(10)))


def test_compressed_images_decode_and_garbage_is_an_error() -> None:
    bgr = np.zeros((8, 8, 3), np.uint8)
    bgr[:, :4] = (0, 0, 255)
    ok, png = cv2.imencode('.png', bgr)
    assert ok
    assert np.array_equal(compressed_to_bgr(CompressedImage(format='png', data=png.tobytes())),
                          bgr)
    with pytest.raises(ImageEncodingError, match=r"\('jpeg', 3 bytes\) cannot be decoded"):
        compressed_to_bgr(CompressedImage(format='jpeg', data=b'abc'))
