"""The ONNX detector: one's own YOLO-style model run by OpenCV's ``dnn`` module.

Pure (OpenCV and numpy, no ROS). No model ships with Enbarr and nothing is downloaded: the
``model_path`` parameter names an ``.onnx`` file (``docs/vision.md``: exporting one, its
layouts and parameters). Per frame: letterbox into ``input_size`` (aspect kept, grey
padding), BGR -> RGB, scaled to 0..1, NCHW float32 (``cv2.dnn.blobFromImage``, as
Ultralytics' exports expect), one forward pass, decoding in the model's layout
(``enbarr_core.vision.detection``), class-wise non-maximum suppression, and the boxes mapped
back through the letterbox to the image's pixels.

OpenCV's ``dnn`` rather than onnxruntime: ``opencv-python-headless`` is already a dependency,
it reads the opsets that YOLO exports use, and one fewer wheel to build on a Raspberry Pi.

Loading checks what a user can get wrong, each a ``ValueError`` that starts with the
parameter it is about: a missing or unreadable file (``model_path``), an input size the model
does not take (``input_width``/``input_height``), an output that is not the layout for the
number of ``class_names`` (``model_path``, shape found and shape expected). A forward pass that
fails on a frame later raises ``cv2.error``: the node counts it (``/diagnostics``).
"""

from __future__ import annotations

from dataclasses import dataclass
import os

import cv2
import numpy as np
from numpy.typing import NDArray

from enbarr_core.vision.detection import (
    check_output, decode, Detection, detections, LAYOUTS, Letterbox, suppress)


@dataclass(frozen=True)
class OnnxSettings:
    """What the ONNX back end needs (parameters of the detector node)."""

    model_path: str
    layout: str                       # one of LAYOUTS
    classes: int                      # the number of class names
    input_size: tuple[int, int]       # (width, height) of the model's input [px]
    score_threshold: float
    iou_threshold: float
    max_detections: int

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` for a layout or an input size that cannot be."""
        if self.layout not in LAYOUTS:
            raise ValueError(f'layout: {self.layout!r} is not one of {", ".join(LAYOUTS)}')
        if min(self.input_size) < 1:
            raise ValueError(f'input_size: {self.input_size} has a side below 1 px')


def _first_line(err: Exception) -> str:
    lines = [line.strip() for line in str(err).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(err).__name__


def preprocess(image: NDArray[np.uint8], input_size: tuple[int, int]
               ) -> tuple[NDArray[np.float32], Letterbox]:
    """Return the model's input for a BGR image and the letterbox that maps boxes back.

    [1, 3, height, width] float32, RGB, 0..1: what Ultralytics' exports were trained on.
    """
    h, w = image.shape[:2]
    letterbox = Letterbox.fit((w, h), input_size)
    blob = cv2.dnn.blobFromImage(letterbox.apply(image, input_size), 1.0 / 255.0, swapRB=True)
    return np.asarray(blob, dtype=np.float32), letterbox


class OnnxDetector:
    """A YOLO-style ONNX model; ``detect(bgr)`` gives the objects of one frame."""

    def __init__(self, settings: OnnxSettings) -> None:
        settings.validate()
        self.settings = s = settings
        path = s.model_path
        if not path:
            raise ValueError('model_path: empty; the onnx back end needs a model file '
                             '(docs/vision.md)')
        if not os.path.isfile(path):
            raise ValueError(f'model_path: {path}: no such file')
        try:
            self.net = cv2.dnn.readNetFromONNX(path)
        except cv2.error as err:
            raise ValueError(f'model_path: {path}: OpenCV cannot read it as an ONNX model: '
                             f'{_first_line(err)}') from err
        w, h = s.input_size
        try:
            out = self.forward(np.zeros((1, 3, h, w), np.float32))
        except cv2.error as err:
            raise ValueError(f'input_width: {path} fails on a {w} x {h} input (is that the '
                             f"model's input size?): {_first_line(err)}") from err
        problem = check_output(out, s.layout, s.classes)
        if problem:
            raise ValueError(f'model_path: {path} gives an {problem} (class_names has '
                             f'{s.classes})')

    def forward(self, blob: NDArray[np.float32]) -> NDArray[np.float32]:
        """Return the model's (first) output for a blob of ``preprocess``."""
        self.net.setInput(blob)
        return np.asarray(self.net.forward())

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Return the objects of a BGR image, best score first (boxes in its pixels, clipped)."""
        s = self.settings
        h, w = image.shape[:2]
        blob, letterbox = preprocess(image, s.input_size)
        out = self.forward(blob)
        candidates = decode(out, s.layout, s.classes, s.score_threshold)
        kept = suppress(candidates, s.score_threshold, s.iou_threshold, s.max_detections)
        return detections(candidates, kept, letterbox, (w, h))
