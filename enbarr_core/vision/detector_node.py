"""Detector node: camera images in, the objects found in them out, with a pluggable back end.

``camera/image_raw`` (``input: raw``) or ``camera/image_raw/compressed`` (``input:
compressed``) -> ``detections`` (``sensor_msgs/PointCloud2``, the encoding of
``enbarr_interfaces.detections``: one point per box, class id, score, box in the image's
pixels; the image's header) and, while a viewer subscribes, ``detections/image`` (the image
with its boxes drawn).

Back ends (``backend``), pure modules beside this node:

- ``classical`` (``enbarr_core.vision.classical``): HSV colour boxes, one per class
  (``hsv_lower``/``hsv_upper``, three values per class in ``class_names`` order), then shape
  tests on each blob (``min_area``, ``min_aspect``/``max_aspect``, ``min_solidity``,
  ``min_extent``). Its defaults find red, green, yellow and orange buoys (the simulated
  world's default is orange).
- ``onnx`` (``enbarr_core.vision.onnx_model``): one's own YOLO-style model, ``model_path``, in
  ``layout`` (``yolov8`` or ``yolov5``), with ``input_width`` x ``input_height``,
  ``score_threshold``, ``iou_threshold``, ``max_detections``; ``class_names`` has one name per
  class of the model. ``docs/vision.md`` says how to export one.

Every frame that is read is answered, also with no box (an empty cloud: looked, nothing
there). A frame that cannot be read (an encoding not handled, a JPEG that does not decode) or
a back end that fails on it (the model's forward pass raises) is not answered: each is counted
and ``/diagnostics`` (every second) says why, ERROR while back-end failures happened in the
last second. Parameters that cannot work (no model file, a model of another output shape, an
HSV value out of range) refuse the node at start, or the ``ros2 param set``, naming the
parameter.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import threading
import time
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CompressedImage, Image

from enbarr_core.framework.health import DEGRADED, ERROR, OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_core.vision.classical import ClassicalDetector, ColourClass, ShapeLimits
from enbarr_core.vision.detection import Detection, Detector
from enbarr_core.vision.onnx_model import OnnxDetector, OnnxSettings
from enbarr_interfaces import convert, topics
from enbarr_interfaces.detections import to_cloud
from enbarr_interfaces.image_msgs import (
    bgr_to_image, compressed_to_bgr, image_to_bgr, ImageEncodingError)

BACKENDS = ('classical', 'onnx')
INPUTS = ('raw', 'compressed')

SPECS = [
    ParamSpec('backend', 'classical', 'classical (HSV colour and shape) or onnx (a YOLO-style '
              'model, model_path)'),
    ParamSpec('input', 'raw', 'raw: camera/image_raw; compressed: camera/image_raw/compressed',
              read_only=True),
    ParamSpec('class_names', ['red_buoy', 'green_buoy', 'yellow_buoy', 'orange_buoy'],
              "Class names in class_id order: one per HSV box (classical), the model's "
              'classes (onnx)'),
    # OpenCV's HSV: H 0..179 (degrees / 2), S and V 0..255. Red straddles hue 0: a low hue
    # above the high one wraps. V starts low for the shaded side of a buoy. Orange (the
    # simulated world's default buoy) lies between red and yellow.
    ParamSpec('hsv_lower', [170, 100, 50, 45, 100, 50, 19, 100, 50, 8, 100, 50],
              'classical: lower H, S, V of each class, three per class in class_names order',
              '', 0, 255),
    ParamSpec('hsv_upper', [7, 255, 255, 85, 255, 255, 35, 255, 255, 18, 255, 255],
              'classical: upper H, S, V of each class (a hue below its lower one wraps '
              'through 0)', '', 0, 255),
    ParamSpec('min_area', 150.0, 'classical: smallest blob (contour area)', 'px^2', 1.0, 1e8),
    ParamSpec('min_aspect', 0.6, 'classical: least box height / width of a blob (buoys '
              'float upright)', '', 0.0, 100.0),
    ParamSpec('max_aspect', 4.0, 'classical: largest box height / width of a blob', '', 0.0,
              100.0),
    ParamSpec('min_solidity', 0.8, 'classical: least contour area / convex hull area', '', 0.0,
              1.0),
    ParamSpec('min_extent', 0.5, 'classical: least contour area / box area (an ellipse is '
              '0.785)', '', 0.0, 1.0),
    ParamSpec('model_path', '', 'onnx: the model file (docs/vision.md)'),
    ParamSpec('layout', 'yolov8', "onnx: the model's output layout: yolov8 ([1, 4 + nc, N]) "
              'or yolov5 ([1, N, 5 + nc])'),
    ParamSpec('input_width', 640, "onnx: the model's input width", 'px', 1, 8192),
    ParamSpec('input_height', 640, "onnx: the model's input height", 'px', 1, 8192),
    ParamSpec('score_threshold', 0.25, 'onnx: least class score of a box', '', 0.0, 1.0),
    ParamSpec('iou_threshold', 0.45, 'onnx: a box overlapping a better one of its class by '
              'more than this intersection over union is suppressed', '', 0.0, 1.0),
    ParamSpec('max_detections', 100, 'onnx: most boxes per frame', '', 1, 100000),
]

#: Box colours of the annotated image, by class_id (BGR), cycled.
PALETTE = ((0, 0, 255), (0, 200, 0), (0, 220, 255), (255, 128, 0), (255, 0, 255))


@dataclass(frozen=True)
class DetectorSettings:
    """Settings of ``DetectorNode`` (see ``SPECS``): the back end, built and checked."""

    backend: str
    input: str
    class_names: tuple[str, ...]
    detector: Detector

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> DetectorSettings:
        """Build from the parameters (``ValueError`` naming the parameter); loads a model."""
        if v['backend'] not in BACKENDS:
            raise ValueError(f'backend: {v["backend"]!r} is not one of {", ".join(BACKENDS)}')
        if v['input'] not in INPUTS:
            raise ValueError(f'input: {v["input"]!r} is not one of {", ".join(INPUTS)}')
        names = tuple(v['class_names'])
        if not names or any(not n for n in names):
            raise ValueError('class_names: needs at least one name, none empty')
        detector: Detector
        if v['backend'] == 'classical':
            detector = _classical(v, names)
        else:
            detector = OnnxDetector(OnnxSettings(
                model_path=v['model_path'], layout=v['layout'], classes=len(names),
                input_size=(v['input_width'], v['input_height']),
                score_threshold=v['score_threshold'], iou_threshold=v['iou_threshold'],
                max_detections=v['max_detections']))
        return cls(v['backend'], v['input'], names, detector)


def _classical(v: Mapping[str, Any], names: Sequence[str]) -> ClassicalDetector:
    low, high = list(v['hsv_lower']), list(v['hsv_upper'])
    for key, values in (('hsv_lower', low), ('hsv_upper', high)):
        if len(values) != 3 * len(names):
            raise ValueError(f'{key}: {len(values)} values; class_names has {len(names)} '
                             f'classes, three (H, S, V) each: {3 * len(names)}')
    classes = []
    for i, name in enumerate(names):
        c = ColourClass(name, tuple(low[3 * i:3 * i + 3]),  # type: ignore[arg-type]
                        tuple(high[3 * i:3 * i + 3]))      # type: ignore[arg-type]
        c.validate()
        classes.append(c)
    shape = ShapeLimits(min_area=v['min_area'], min_aspect=v['min_aspect'],
                        max_aspect=v['max_aspect'], min_solidity=v['min_solidity'],
                        min_extent=v['min_extent'])
    shape.validate()
    return ClassicalDetector(classes, shape)


def annotate(image: NDArray[np.uint8], found: Sequence[Detection],
             names: Sequence[str]) -> NDArray[np.uint8]:
    """Return a copy of ``image`` with each detection's box and ``name score`` drawn."""
    out = image.copy()
    for d in found:
        colour = PALETTE[d.class_id % len(PALETTE)]
        p0 = (round(d.x_min), round(d.y_min))
        cv2.rectangle(out, p0, (round(d.x_max) - 1, round(d.y_max) - 1), colour, 2)
        name = names[d.class_id] if d.class_id < len(names) else str(d.class_id)
        cv2.putText(out, f'{name} {d.score:.2f}', (p0[0], max(12, p0[1] - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return out


def _reason(err: Exception) -> str:
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return f'{type(err).__name__}: {lines[-1] if lines else ""}'


class DetectorNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'detector', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: DetectorSettings
        self._lock = threading.Lock()   # frames against a parameter change's new back end
        self.bind_settings(SPECS, DetectorSettings.from_params, self._apply)
        self.frames = 0
        self.answered = 0
        self.bad_images = 0
        self.failures = 0
        self.last_fault = ''
        self.last_count = 0
        self.last_process_s = 0.0
        self._failures_reported = 0
        self._bad_reported = 0
        self._detections_pub = self.create_topic_publisher(topics.DETECTIONS)
        # A viewer's topic: a plain ROS publisher, whose subscriber count decides whether the
        # annotated image is drawn at all.
        spec = topics.DETECTION_IMAGE
        self._image_pub = self.create_publisher(spec.msg_type, spec.name, spec.qos)
        if self.settings.input == 'raw':
            self.create_topic_subscription(topics.CAMERA_IMAGE, self._on_image)
        else:
            self.create_topic_subscription(topics.CAMERA_COMPRESSED, self._on_compressed)
        self.create_periodic(1.0, self._report)

    def _apply(self, settings: DetectorSettings) -> None:
        with self._lock:
            self.settings = settings

    def _on_image(self, msg: Image) -> None:
        self._process(msg, image_to_bgr)

    def _on_compressed(self, msg: CompressedImage) -> None:
        self._process(msg, compressed_to_bgr)

    def _process(self, msg: Any, to_bgr: Any) -> None:
        self.frames += 1
        try:
            image = to_bgr(msg)
        except ImageEncodingError as err:
            self.bad_images += 1
            self.last_fault = str(err)
            self.get_logger().warn(f'frame not read: {err}', throttle_duration_sec=5.0)
            return
        start = time.perf_counter()   # wall: OpenCV works on its own threads too
        with self._lock:
            s = self.settings
            try:
                found = s.detector.detect(image)
            except (cv2.error, ValueError) as err:
                self.failures += 1
                self.last_fault = f'{s.backend} back end failed on a frame: {_reason(err)}'
                self.get_logger().error(self.last_fault, throttle_duration_sec=5.0)
                return
        self.last_process_s = time.perf_counter() - start
        self.answered += 1
        self.last_count = len(found)
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        frame_id = msg.header.frame_id or topics.CAMERA_OPTICAL_FRAME
        self._detections_pub.publish(to_cloud(
            [(d.class_id, d.score, d.x_min, d.y_min, d.x_max, d.y_max) for d in found],
            stamp_ns, frame_id))
        if self._image_pub.get_subscription_count() > 0:
            out = bgr_to_image(annotate(image, found, s.class_names))
            out.header = msg.header
            self._image_pub.publish(out)

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for ``/diagnostics``."""
        level, message = OK, 'ok'
        if self.bad_images > self._bad_reported:
            level, message = DEGRADED, (f'{self.bad_images - self._bad_reported} frame(s) '
                                        f'not read in the last second: {self.last_fault}')
        if self.failures > self._failures_reported:
            level, message = ERROR, (f'{self.failures - self._failures_reported} frame(s) '
                                     f'failed in the last second: {self.last_fault}')
        self._failures_reported, self._bad_reported = self.failures, self.bad_images
        return level, message, {
            'backend': self.settings.backend, 'frames': self.frames,
            'answered': self.answered, 'bad_images': self.bad_images,
            'backend_failures': self.failures, 'last_fault': self.last_fault,
            'detections': self.last_count,
            'process_ms': round(self.last_process_s * 1e3, 3)}

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())
