"""Detections in an image, YOLO-style decoding, letterboxing and non-maximum suppression.

Pure (numpy and OpenCV, no ROS). Boxes are in pixels of the image they were found in:
``x_min, y_min`` the top-left corner, ``x_max, y_max`` the bottom-right one, x to the right
and y down (OpenCV's image coordinates, pixel centres at integers).

Layouts of a model's output (``LAYOUTS``), for ``nc`` classes and ``N`` candidate boxes, every
box ``cx, cy, w, h`` in pixels of the model's input (after letterboxing):

- ``yolov8``: shape ``[1, 4 + nc, N]``; row ``0..3`` the box, rows ``4..`` the class scores
  (already through a sigmoid, no objectness): Ultralytics' ONNX export of its YOLOv8, YOLOv9
  and YOLO11 detection models (``yolo export format=onnx``).
- ``yolov5``: shape ``[1, N, 5 + nc]``; per candidate the box, an objectness and the class
  scores; a class's score is objectness x class score (YOLOv5's ``export.py --include onnx``,
  YOLOv7's with ``--grid``).

The layout is a parameter, never guessed from the shape: a ``[1, 84, 84]`` output reads both
ways. Exports with the suppression inside the graph (``nms=True``, end-to-end heads whose
output is ``[1, max_det, 6]``) and models with several outputs (segmentation, pose) are not
read: the first output is taken, and its shape does not fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

LAYOUTS = ('yolov8', 'yolov5')
#: Grey of the letterbox's padding: Ultralytics' (the value the YOLO models were trained on).
PAD_VALUE = 114


@dataclass(frozen=True)
class Detection:
    """One object found in an image: its class, a score in [0, 1] and a box in pixels."""

    class_id: int
    score: float
    x_min: float
    y_min: float
    x_max: float
    y_max: float

    @property
    def width(self) -> float:
        """Width of the box [px]."""
        return self.x_max - self.x_min

    @property
    def height(self) -> float:
        """Height of the box [px]."""
        return self.y_max - self.y_min

    @property
    def area(self) -> float:
        """Area of the box [px^2] (0 for an empty box)."""
        return max(0.0, self.width) * max(0.0, self.height)


class Detector(Protocol):
    """A back end of the detector node: the objects of one BGR frame."""

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Return the objects of a BGR image, best score first (boxes in its pixels)."""


def iou(a: Detection, b: Detection) -> float:
    """Intersection over union of two boxes (0 when both are empty)."""
    w = min(a.x_max, b.x_max) - max(a.x_min, b.x_min)
    h = min(a.y_max, b.y_max) - max(a.y_min, b.y_min)
    inter = max(0.0, w) * max(0.0, h)
    union = a.area + b.area - inter
    return inter / union if union > 0.0 else 0.0


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted into a model's input: scaled by ``scale``, then padded.

    Input pixel = image pixel x ``scale`` + ``(pad_x, pad_y)``; the image keeps its aspect
    ratio and the padding is split evenly (the odd pixel goes right and down).
    """

    scale: float
    pad_x: float
    pad_y: float

    @classmethod
    def fit(cls, image_size: tuple[int, int], input_size: tuple[int, int]) -> Letterbox:
        """Return the letterbox of an image ``(width, height)`` in an input ``(width, height)``."""
        w, h = image_size
        iw, ih = input_size
        scale = min(iw / w, ih / h)
        sw, sh = round(w * scale), round(h * scale)
        return cls(scale, (iw - sw) // 2, (ih - sh) // 2)

    def apply(self, image: NDArray[np.uint8], input_size: tuple[int, int]) -> NDArray[np.uint8]:
        """Return ``image`` scaled and padded to ``input_size`` (``PAD_VALUE`` around it)."""
        h, w = image.shape[:2]
        iw, ih = input_size
        sw, sh = round(w * self.scale), round(h * self.scale)
        scaled = image if (sw, sh) == (w, h) else cv2.resize(
            image, (sw, sh), interpolation=cv2.INTER_LINEAR)
        px, py = int(self.pad_x), int(self.pad_y)
        return np.asarray(cv2.copyMakeBorder(scaled, py, ih - sh - py, px, iw - sw - px,
                                             cv2.BORDER_CONSTANT, value=(PAD_VALUE,) * 3),
                          dtype=np.uint8)

    def to_image(self, boxes: NDArray[np.float64]) -> NDArray[np.float64]:
        """Map ``[n, 4]`` corner boxes (x_min, y_min, x_max, y_max) from input to image pixels."""
        out = np.array(boxes, dtype=np.float64, copy=True)
        out[:, 0::2] = (out[:, 0::2] - self.pad_x) / self.scale
        out[:, 1::2] = (out[:, 1::2] - self.pad_y) / self.scale
        return out


@dataclass(frozen=True)
class Candidates:
    """Boxes above the score threshold, before suppression (corners, input pixels)."""

    boxes: NDArray[np.float64]      # [n, 4] x_min, y_min, x_max, y_max
    scores: NDArray[np.float64]     # [n]
    class_ids: NDArray[np.int64]    # [n]


def expected_shape(layout: str, classes: int) -> str:
    """Return the output shape ``layout`` has for ``classes`` classes, as text (for errors)."""
    if layout == 'yolov8':
        return f'[1, {4 + classes}, N]'
    if layout == 'yolov5':
        return f'[1, N, {5 + classes}]'
    raise ValueError(f'layout: {layout!r} is not one of {", ".join(LAYOUTS)}')


def check_output(output: NDArray[np.float32], layout: str, classes: int) -> str | None:
    """Why ``output`` is not a ``layout`` output for ``classes`` classes (None: it is)."""
    want = expected_shape(layout, classes)
    shape = tuple(int(d) for d in output.shape)
    if len(shape) != 3 or shape[0] != 1:
        return f'output of shape {list(shape)}, the {layout} layout is {want}'
    if layout == 'yolov8' and shape[1] != 4 + classes:
        return (f'output of shape {list(shape)}, the {layout} layout with {classes} classes '
                f'is {want}')
    if layout == 'yolov5' and shape[2] != 5 + classes:
        return (f'output of shape {list(shape)}, the {layout} layout with {classes} classes '
                f'is {want}')
    return None


def decode(output: NDArray[np.float32], layout: str, classes: int,
           score_threshold: float) -> Candidates:
    """Return the candidates of a model output whose best class scores above the threshold.

    Strictly above, as OpenCV's suppression and Ultralytics' ``conf`` filter. Each candidate
    keeps its best class only (as Ultralytics' own post-processing); the box goes from centre
    and size to corners. Raises ``ValueError`` for an output of another shape.
    """
    problem = check_output(output, layout, classes)
    if problem:
        raise ValueError(problem)
    # In the output's own float32 and order: a stock export has 8400 x 84 values, and only
    # the few candidates above the threshold are worth a copy.
    out = np.asarray(output[0])
    if layout == 'yolov8':
        box_rows, class_scores = out[:4], out[4:]               # [4, N], [nc, N]
    else:
        box_rows = out[:, :4].T                                 # [4, N]
        class_scores = (out[:, 5:] * out[:, 4:5]).T             # objectness x class score
    n = class_scores.shape[1]
    if n == 0:
        return Candidates(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.int64))
    class_ids = np.argmax(class_scores, axis=0)
    scores = class_scores[class_ids, np.arange(n)]
    keep = np.flatnonzero(scores > score_threshold)
    cx, cy, w, h = box_rows[:, keep].astype(np.float64)
    boxes = np.column_stack((cx - 0.5 * w, cy - 0.5 * h, cx + 0.5 * w, cy + 0.5 * h))
    return Candidates(boxes, scores[keep].astype(np.float64), class_ids[keep].astype(np.int64))


def suppress(candidates: Candidates, score_threshold: float, iou_threshold: float,
             max_detections: int) -> list[int]:
    """Class-wise non-maximum suppression: the indices kept, best score first.

    OpenCV's ``cv2.dnn.NMSBoxesBatched`` (it is class-wise already, so nothing is written
    here): within one class, a box is dropped when its intersection over union with a
    better-scoring kept box is above ``iou_threshold`` (equal is kept), and a score not above
    ``score_threshold`` is dropped; boxes of different classes never suppress each other (a
    buoy in front of a boat is both). At most ``max_detections`` are kept.
    """
    n = len(candidates.scores)
    if n == 0:
        return []
    b = candidates.boxes
    xywh = np.column_stack((b[:, 0], b[:, 1], b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]))
    kept = cv2.dnn.NMSBoxesBatched(
        xywh.tolist(), candidates.scores.tolist(), candidates.class_ids.tolist(),
        float(score_threshold), float(iou_threshold))
    order = sorted((int(i) for i in np.asarray(kept).reshape(-1)),
                   key=lambda i: (-candidates.scores[i], i))
    return order[:max_detections]


def detections(candidates: Candidates, kept: Sequence[int],
               letterbox: Letterbox | None = None,
               image_size: tuple[int, int] | None = None) -> list[Detection]:
    """Return the kept candidates as detections in image pixels, clipped to ``image_size``."""
    boxes = candidates.boxes[list(kept)]
    if letterbox is not None:
        boxes = letterbox.to_image(boxes)
    if image_size is not None:
        boxes[:, 0::2] = np.clip(boxes[:, 0::2], 0.0, float(image_size[0]))
        boxes[:, 1::2] = np.clip(boxes[:, 1::2], 0.0, float(image_size[1]))
    return [Detection(int(candidates.class_ids[i]), float(candidates.scores[i]),
                      *(float(v) for v in box)) for i, box in zip(kept, boxes)]
