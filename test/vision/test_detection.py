"""Decoding of YOLO-style outputs, letterboxing and class-wise suppression, checked exactly:
on hand-made tables and through real ONNX graphs (``support.onnx_graphs``, built here with
onnx.helper and run by OpenCV's dnn), against boxes computed by hand below.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.onnx_graphs import yolo_graph

from enbarr_core.vision.detection import (
    Candidates, decode, Detection, detections, iou, Letterbox, suppress)
from enbarr_core.vision.onnx_model import OnnxDetector, OnnxSettings, preprocess

pytestmark = pytest.mark.unit

# Candidates in model input pixels, (cx, cy, w, h, scores of classes 0, 1, 2). Threshold 0.25,
# IoU 0.45. By hand:
#   A class 0, 0.9, corners (10, 10, 30, 30): kept, the best.
#   B class 0, 0.8, (12, 10, 32, 30): IoU with A = 18*20 / (400 + 400 - 360) = 0.818: dropped.
#   C class 1, 0.7, A's box: another class, never suppressed by A: kept.
#   D class 0, 0.6, (20, 10, 40, 30): IoU with A = 200 / 600 = 0.333: kept.
#   E class 2, 0.2 (best of 0.1, 0.15, 0.2): under the threshold: dropped.
#   F class 2, 0.5 (0.3, 0.1, 0.5: its best class wins), (40, 40, 60, 50): kept.
TABLE = [
    (20, 20, 20, 20, 0.9, 0.0, 0.0),   # A
    (22, 20, 20, 20, 0.8, 0.1, 0.0),   # B
    (20, 20, 20, 20, 0.0, 0.7, 0.0),   # C
    (30, 20, 20, 20, 0.6, 0.0, 0.0),   # D
    (50, 50, 8, 8, 0.1, 0.15, 0.2),    # E
    (50, 45, 20, 10, 0.3, 0.1, 0.5),   # F
]
#: What survives, best score first: (class, score, x_min, y_min, x_max, y_max), input pixels.
KEPT = [(0, 0.9, 10, 10, 30, 30), (1, 0.7, 10, 10, 30, 30), (0, 0.6, 20, 10, 40, 30),
        (2, 0.5, 40, 40, 60, 50)]
INPUT = (64, 64)
STRIDE = 8           # 8 x 8 = 64 candidates; the rest of the table is zeros (score 0)


def v8_table() -> np.ndarray:
    """[4 + nc, N]: the candidates above in columns 3, 10, ..., zeros elsewhere."""
    n = (INPUT[0] // STRIDE) * (INPUT[1] // STRIDE)
    t = np.zeros((7, n), np.float32)
    for k, row in enumerate(TABLE):
        t[:, 3 + 7 * k] = row
    return t


def as_tuples(found: list[Detection]) -> list[tuple[float, ...]]:
    return [(d.class_id, round(d.score, 5), d.x_min, d.y_min, d.x_max, d.y_max)
            for d in found]


def test_yolov8_decoding_and_classwise_suppression_give_the_hand_computed_boxes() -> None:
    c = decode(v8_table()[None], 'yolov8', 3, 0.25)
    assert len(c.scores) == 5                             # E is under the threshold
    kept = suppress(c, 0.25, 0.45, 100)
    assert as_tuples(detections(c, kept)) == KEPT


def test_yolov5_layout_multiplies_objectness_into_the_class_scores() -> None:
    # [N, 5 + nc]: objectness 0.5 halves every score; A's 0.9 x 0.5 = 0.45 stays, C's 0.35
    # and D's 0.3 stay, F's 0.25 is not above the threshold 0.25: dropped (OpenCV's and
    # Ultralytics' rule: strictly above).
    rows = np.array([(*r[:4], 0.5, *r[4:]) for r in TABLE], np.float32)
    c = decode(rows[None], 'yolov5', 3, 0.25)
    assert len(c.scores) == 4                 # A, B (0.4), C, D: F's 0.25 is not above
    got = as_tuples(detections(c, suppress(c, 0.25, 0.45, 100)))
    assert got == [(0, 0.45, 10, 10, 30, 30), (1, 0.35, 10, 10, 30, 30),
                   (0, 0.3, 20, 10, 40, 30)]


def test_suppression_keeps_a_box_whose_overlap_equals_the_threshold() -> None:
    # (10, 10, 30, 30) and (10, 10, 50, 30): intersection 400, union 800, IoU exactly 0.5.
    c = Candidates(np.array([[10, 10, 30, 30], [10, 10, 50, 30]], float), np.array([0.9, 0.8]),
                   np.array([0, 0]))
    assert suppress(c, 0.25, 0.5, 100) == [0, 1]
    assert suppress(c, 0.25, 0.49, 100) == [0]
    assert iou(Detection(0, 1, 10, 10, 30, 30), Detection(0, 1, 10, 10, 50, 30)) == 0.5


def test_max_detections_keeps_the_best() -> None:
    c = decode(v8_table()[None], 'yolov8', 3, 0.25)
    assert as_tuples(detections(c, suppress(c, 0.25, 0.45, 2))) == KEPT[:2]


def test_letterbox_scales_pads_and_maps_back() -> None:
    # 640 x 480 into 320 x 320: scale 0.5, 320 x 240 placed 40 px down (80 of padding split).
    lb = Letterbox.fit((640, 480), (320, 320))
    assert (lb.scale, lb.pad_x, lb.pad_y) == (0.5, 0, 40)
    img = np.full((480, 640, 3), 200, np.uint8)
    out = lb.apply(img, (320, 320))
    assert out.shape == (320, 320, 3)
    assert (out[:40] == 114).all() and (out[280:] == 114).all() and (out[40:280] == 200).all()
    # input (10, 50, 30, 90) -> image ((10 - 0) / 0.5, (50 - 40) / 0.5, ...)
    assert lb.to_image(np.array([[10.0, 50.0, 30.0, 90.0]])).tolist() == [[20, 20, 60, 100]]
    # a tall image pads left and right; an odd pad puts the extra pixel right
    lb = Letterbox.fit((100, 201), (64, 64))
    assert (lb.scale, lb.pad_x, lb.pad_y) == (64 / 201, 16, 0)    # round(100 * 64/201) = 32


@pytest.fixture
def v8_model(tmp_path):
    return yolo_graph(tmp_path / 'v8.onnx', v8_table(), INPUT, STRIDE)


def settings(path, **kw) -> OnnxSettings:
    values = dict(model_path=str(path), layout='yolov8', classes=3, input_size=INPUT,
                  score_threshold=0.25, iou_threshold=0.45, max_detections=100)
    return OnnxSettings(**{**values, **kw})


def test_an_onnx_graph_through_opencv_gives_the_boxes_in_image_pixels(v8_model) -> None:
    # A 128 x 64 image into the 64 x 64 input: scale 0.5, pad_y 16. Each input box maps to
    # x / 0.5 and (y - 16) / 0.5, then clipped to the image (128 x 64).
    found = OnnxDetector(settings(v8_model)).detect(np.zeros((64, 128, 3), np.uint8))
    assert as_tuples(found) == [
        (0, 0.9, 20, 0, 60, 28),        # A: y (10 - 16) / 0.5 = -12 -> clipped to 0
        (1, 0.7, 20, 0, 60, 28),
        (0, 0.6, 40, 0, 80, 28),
        (2, 0.5, 80, 48, 120, 64)]      # F: (40, 40, 60, 50) -> (80, 48, 120, 68) -> y 64


def test_an_onnx_graph_in_the_yolov5_layout(tmp_path) -> None:
    n = (INPUT[0] // STRIDE) * (INPUT[1] // STRIDE)
    t = np.zeros((8, n), np.float32)
    t[:, 0] = (32, 32, 16, 8, 1.0, 0.0, 0.0, 0.8)    # class 2, box (24, 28, 40, 36)
    path = yolo_graph(tmp_path / 'v5.onnx', t, INPUT, STRIDE, 'yolov5')
    found = OnnxDetector(settings(path, layout='yolov5')).detect(
        np.zeros((64, 64, 3), np.uint8))
    assert as_tuples(found) == [(2, 0.8, 24, 28, 40, 36)]


def test_a_missing_model_file_names_the_parameter_and_the_file(tmp_path) -> None:
    with pytest.raises(ValueError, match=r'^model_path: .*nothing\.onnx: no such file'):
        OnnxDetector(settings(tmp_path / 'nothing.onnx'))
    with pytest.raises(ValueError, match=r'^model_path: empty'):
        OnnxDetector(settings(''))


def test_a_file_that_is_not_a_model_is_refused(tmp_path) -> None:
    junk = tmp_path / 'junk.onnx'
    junk.write_bytes(b'not a protobuf at all')
    with pytest.raises(ValueError, match=r'^model_path: .*junk\.onnx: OpenCV cannot read it'):
        OnnxDetector(settings(junk))


def test_an_output_of_the_wrong_shape_names_shape_and_layout(v8_model) -> None:
    # the graph has 3 classes (7 rows); 5 class names want 9
    with pytest.raises(ValueError, match=r'^model_path: .*v8\.onnx gives an output of shape '
                       r'\[1, 7, 64\], the yolov8 layout with 5 classes is \[1, 9, N\]'):
        OnnxDetector(settings(v8_model, classes=5))
    with pytest.raises(ValueError, match=r'the yolov5 layout with 3 classes is \[1, N, 8\]'):
        OnnxDetector(settings(v8_model, layout='yolov5'))


def test_an_input_size_the_model_does_not_take_names_input_width(v8_model) -> None:
    with pytest.raises(ValueError, match=r'^input_width: .*v8\.onnx fails on a 32 x 64 input'):
        OnnxDetector(settings(v8_model, input_size=(32, 64)))


def test_an_unknown_layout_is_refused(v8_model) -> None:
    with pytest.raises(ValueError, match=r"^layout: 'yolov3' is not one of yolov8, yolov5"):
        OnnxDetector(settings(v8_model, layout='yolov3'))


def test_the_model_is_fed_rgb_scaled_to_one_letterboxed() -> None:
    # a 4 x 2 BGR image into a 4 x 4 input: one row of padding above and below
    img = np.zeros((2, 4, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 51, 102, 255     # B, G, R
    blob, lb = preprocess(img, (4, 4))
    assert blob.shape == (1, 3, 4, 4) and blob.dtype == np.float32
    assert (lb.scale, lb.pad_x, lb.pad_y) == (1.0, 0, 1)
    assert np.allclose(blob[0, :, 1:3], np.array([1.0, 0.4, 0.2])[:, None, None])   # R, G, B
    assert np.allclose(blob[0, :, 0], 114 / 255) and np.allclose(blob[0, :, 3], 114 / 255)
