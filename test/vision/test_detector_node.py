"""Node tests: the detector in an in-process executor. Images (raw and JPEG) of a drawn scene
go in; detections (decoded with ``enbarr_interfaces.detections``), the annotated image and
diagnostics come out. Bad parameters refuse the node naming the parameter; a back end that
fails on a frame is counted on /diagnostics.
"""

from __future__ import annotations

import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CompressedImage, Image
from support.nodes import add, param_client, probe, set_param, TIMEOUT
from support.onnx_graphs import yolo_graph

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.vision.detection import Detection, iou
from enbarr_core.vision.detector_node import DetectorNode
from enbarr_core.vision.synthetic import scene, water
from enbarr_interfaces import convert, topics
from enbarr_interfaces.detections import from_cloud

STAMP_NS = 1_234_567_891_011


def image_msg(pixels: np.ndarray, stamp_ns: int, encoding: str = 'bgr8') -> Image:
    msg = Image()
    convert.ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = 'camera_optical_frame'
    msg.height, msg.width = pixels.shape[:2]
    msg.encoding = encoding
    msg.step = pixels.shape[1] * (pixels.shape[2] if pixels.ndim == 3 else 1)
    msg.data = pixels.tobytes()
    return msg


class Harness:
    def __init__(self, context, executor, spin, **params) -> None:
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.node = add(executor, DetectorNode(context=context, parameter_overrides=overrides))
        self.executor, self.spin = executor, spin
        p = probe(context, executor)
        self.raw_pub = p.create_publisher(Image, topics.CAMERA_IMAGE.name,
                                          topics.CAMERA_IMAGE.qos)
        self.jpeg_pub = p.create_publisher(CompressedImage, topics.CAMERA_COMPRESSED.name,
                                           topics.CAMERA_COMPRESSED.qos)
        self.clouds, self.images, self.diagnostics = [], [], []
        p.create_subscription(topics.DETECTIONS.msg_type, topics.DETECTIONS.name,
                              self.clouds.append, topics.DETECTIONS.qos)
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                              self.diagnostics.append, topics.DIAGNOSTICS.qos)
        self.p = p
        pub = self.jpeg_pub if params.get('input') == 'compressed' else self.raw_pub
        assert spin(executor, lambda: pub.get_subscription_count() > 0, TIMEOUT)

    def watch_images(self) -> None:
        self.p.create_subscription(topics.DETECTION_IMAGE.msg_type, topics.DETECTION_IMAGE.name,
                                   self.images.append, topics.DETECTION_IMAGE.qos)
        assert self.spin(self.executor, lambda: self.node._image_pub.get_subscription_count()
                         > 0, TIMEOUT)

    def send(self, msg, answer: bool = True):
        before, frames = len(self.clouds), self.node.frames
        (self.jpeg_pub if isinstance(msg, CompressedImage) else self.raw_pub).publish(msg)
        assert self.spin(self.executor, lambda: self.node.frames > frames, TIMEOUT)
        if answer:
            assert self.spin(self.executor, lambda: len(self.clouds) > before, TIMEOUT)
            return self.clouds[-1]
        return None

    def status(self, predicate) -> DiagnosticStatus:
        def found():
            return [s for a in self.diagnostics for s in a.status
                    if s.hardware_id == 'detector' and predicate(s)]
        assert self.spin(self.executor, lambda: bool(found()), TIMEOUT)
        return found()[-1]


def boxes(cloud) -> list[Detection]:
    return [Detection(int(r['class_id']), float(r['score']), float(r['x_min']),
                      float(r['y_min']), float(r['x_max']), float(r['y_max']))
            for r in from_cloud(cloud)]


def assert_matches(found: list[Detection], truth) -> None:
    assert len(found) == len(truth)
    for t in truth:
        tb = Detection(t.class_id, 1.0, t.x_min, t.y_min, t.x_max, t.y_max)
        assert any(d.class_id == t.class_id and iou(d, tb) > 0.8 for d in found), t


def test_an_image_comes_back_as_detections_with_its_stamp_and_frame(context, executor, spin):
    h = Harness(context, executor, spin)
    h.watch_images()
    img, truth = scene(np.random.default_rng(5), buoys=3)
    cloud = h.send(image_msg(img, STAMP_NS))
    assert convert.stamp_to_ns(cloud.header.stamp) == STAMP_NS
    assert cloud.header.frame_id == 'camera_optical_frame'
    assert_matches(boxes(cloud), truth)
    assert spin(executor, lambda: len(h.images) >= 1, TIMEOUT)
    drawn = h.images[-1]
    assert convert.stamp_to_ns(drawn.header.stamp) == STAMP_NS and drawn.encoding == 'bgr8'
    pixels = np.frombuffer(bytes(drawn.data), np.uint8).reshape(480, 640, 3)
    assert not np.array_equal(pixels, img)          # the boxes are drawn on it


def test_an_image_without_buoys_is_answered_empty(context, executor, spin):
    h = Harness(context, executor, spin)
    cloud = h.send(image_msg(water(640, 480, np.random.default_rng(1)), STAMP_NS + 1))
    assert boxes(cloud) == [] and convert.stamp_to_ns(cloud.header.stamp) == STAMP_NS + 1


def test_rgb8_images_are_read_in_their_channel_order(context, executor, spin):
    h = Harness(context, executor, spin)
    img, truth = scene(np.random.default_rng(6), buoys=2)
    cloud = h.send(image_msg(np.ascontiguousarray(img[..., ::-1]), STAMP_NS, 'rgb8'))
    assert_matches(boxes(cloud), truth)


def test_the_compressed_stream_is_read_when_asked(context, executor, spin):
    h = Harness(context, executor, spin, input='compressed')
    img, truth = scene(np.random.default_rng(7), buoys=2)
    ok, jpeg = cv2.imencode('.jpg', img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    msg = CompressedImage()
    convert.ns_to_stamp(STAMP_NS, msg.header.stamp)
    msg.header.frame_id = 'camera_optical_frame'
    msg.format = 'jpeg'
    msg.data = jpeg.tobytes()
    cloud = h.send(msg)
    assert convert.stamp_to_ns(cloud.header.stamp) == STAMP_NS
    assert_matches(boxes(cloud), truth)
    broken = CompressedImage(format='jpeg', data=b'\xff\xd8 not really')
    h.send(broken, answer=False)
    assert h.node.bad_images == 1
    s = h.status(lambda s: s.level == DiagnosticStatus.WARN)
    assert 'cannot be decoded' in s.message


def test_the_onnx_back_end_gives_the_models_boxes(context, executor, spin, tmp_path):
    # one candidate: class 1, score 0.9, input box (16, 24, 48, 40) in a 64 x 64 input; a
    # 128 x 64 image is letterboxed at scale 0.5 with 16 px of padding on top and below.
    table = np.zeros((6, 64), np.float32)
    table[:, 9] = (32, 32, 32, 16, 0.05, 0.9)
    path = yolo_graph(tmp_path / 'one.onnx', table, (64, 64), 8)
    h = Harness(context, executor, spin, backend='onnx', model_path=str(path),
                class_names=['boat', 'buoy'], input_width=64, input_height=64)
    cloud = h.send(image_msg(np.zeros((64, 128, 3), np.uint8), STAMP_NS))
    rows = from_cloud(cloud)
    assert rows.tolist() == [(1, np.float32(0.9), 32.0, 16.0, 96.0, 48.0)]


def test_a_missing_model_refuses_the_node_naming_the_parameter(context, tmp_path):
    with pytest.raises(ConfigurationError, match=r'model_path: .*absent\.onnx: no such file') \
            as err:
        DetectorNode(context=context, parameter_overrides=[
            Parameter('backend', value='onnx'),
            Parameter('model_path', value=str(tmp_path / 'absent.onnx'))])
    assert err.value.parameter == 'model_path'


def test_a_model_of_the_wrong_shape_refuses_the_node(context, tmp_path):
    path = yolo_graph(tmp_path / 'two.onnx', np.zeros((6, 64), np.float32), (64, 64), 8)
    with pytest.raises(ConfigurationError, match=r'gives an output of shape \[1, 6, 64\], the '
                       r'yolov8 layout with 4 classes is \[1, 8, N\]') as err:
        DetectorNode(context=context, parameter_overrides=[
            Parameter('backend', value='onnx'), Parameter('model_path', value=str(path)),
            Parameter('input_width', value=64), Parameter('input_height', value=64)])
    assert err.value.parameter == 'model_path'


def test_switching_live_to_a_model_that_is_not_there_is_refused(context, executor, spin):
    h = Harness(context, executor, spin)
    client = param_client(executor, spin, context, 'detector')
    result = set_param(executor, spin, client, 'backend', 'onnx')
    assert not result.successful and 'model_path: empty' in result.reason
    assert h.node.settings.backend == 'classical'


def test_a_back_end_that_fails_on_a_frame_is_a_counted_fault_with_its_reason(
        context, executor, spin, monkeypatch):
    h = Harness(context, executor, spin)

    def broken(image):
        raise cv2.error('OpenCV(5.0.0) net.cpp:1: error: (-215:Assertion failed) in forward')

    monkeypatch.setattr(h.node.settings.detector, 'detect', broken)
    h.send(image_msg(water(64, 48, np.random.default_rng(2)), STAMP_NS), answer=False)
    assert h.node.failures == 1 and h.clouds == []     # a failed frame is not answered
    s = h.status(lambda s: s.level == DiagnosticStatus.ERROR)
    assert 'classical back end failed on a frame' in s.message
    assert 'Assertion failed' in s.message
    values = {kv.key: kv.value for kv in s.values}
    assert values['backend_failures'] == '1'


def test_an_encoding_it_cannot_read_is_counted(context, executor, spin):
    h = Harness(context, executor, spin)
    h.send(image_msg(np.zeros((4, 4), np.uint16), STAMP_NS, '16UC1'), answer=False)
    assert h.node.bad_images == 1
    s = h.status(lambda s: s.level == DiagnosticStatus.WARN)
    assert "image encoding '16UC1' is not read" in s.message
