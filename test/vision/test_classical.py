"""The classical back end on images drawn here and on a generated set of scenes
(``enbarr_core.vision.synthetic``: shaded cylinders and spheres on textured water, a wall and a
boat with buoy-red stripes), with the node's default parameters: boxes, precision, recall.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from enbarr_core.vision.classical import ClassicalDetector, ColourClass, mask, ShapeLimits
from enbarr_core.vision.detection import Detection, iou
from enbarr_core.vision.detector_node import DetectorSettings, SPECS
from enbarr_core.vision.synthetic import CLASSES, scene, water


DEFAULTS = {s.name: s.default for s in SPECS}


def default_detector() -> ClassicalDetector:
    d = DetectorSettings.from_params(DEFAULTS).detector
    assert isinstance(d, ClassicalDetector)
    return d


def blank(rng_seed: int = 3) -> np.ndarray:
    return water(640, 480, np.random.default_rng(rng_seed))


def test_the_default_classes_are_the_scenes_colours_in_order() -> None:
    # the generated scenes number their classes red, green, yellow, orange: so do the defaults
    assert CLASSES == ('red', 'green', 'yellow', 'orange')
    assert DEFAULTS['class_names'] == ['red_buoy', 'green_buoy', 'yellow_buoy', 'orange_buoy']


def test_a_shaded_red_cylinder_is_found_with_its_box() -> None:
    img = blank()
    x0, y0, w, h = 200, 220, 40, 90       # pixels x0 .. x0 + w - 1, y0 .. y0 + h - 1
    for i in range(w):                      # lit from the left: dark on the right
        v = 0.35 + 0.65 * (1.0 - i / w)
        img[y0:y0 + h, x0 + i] = (int(35 * v), int(35 * v), int(205 * v))
    img[y0 + 3:y0 + h - 3, x0 + 12:x0 + 15] = (240, 240, 250)   # a specular highlight
    found = default_detector().detect(img)
    assert [d.class_id for d in found] == [0]
    d = found[0]
    # one blob across the highlight; corners at pixel edges: the last column is x0 + w - 1
    assert (d.x_min, d.y_min, d.x_max, d.y_max) == (x0, y0, x0 + w, y0 + h)
    assert 0.95 <= d.score <= 1.0


def test_specks_of_buoy_colour_beside_a_buoy_neither_grow_nor_hide_it() -> None:
    # 3 x 3 px red specks 4 px off both sides (spray, a reflection broken by ripples): the
    # opening removes them before the closing could join them to the buoy
    img = blank()
    x0, y0, w, h = 200, 220, 40, 90
    img[y0:y0 + h, x0:x0 + w] = (35, 35, 205)
    for y in range(y0 + 5, y0 + h - 5, 12):
        img[y:y + 3, x0 + w + 4:x0 + w + 7] = (35, 35, 205)
        img[y:y + 3, x0 - 7:x0 - 4] = (35, 35, 205)
    found = default_detector().detect(img)
    assert [(d.class_id, d.x_min, d.y_min, d.x_max, d.y_max) for d in found] == [
        (0, x0, y0, x0 + w, y0 + h)]


def test_a_noisy_camera_still_finds_every_buoy() -> None:
    # sensor noise of 20 grey levels (one standard deviation) speckles the hue of a buoy's
    # shaded side; the blur before thresholding keeps it whole
    rng = np.random.default_rng(11)
    detector = default_detector()
    for _ in range(4):
        img, truth = scene(rng, buoys=3)
        noisy = np.clip(img + 20.0 * rng.standard_normal(img.shape), 0, 255).astype(np.uint8)
        assert match(detector.detect(noisy), truth) == (len(truth), 0, 0)


def test_red_is_found_on_both_sides_of_hue_zero() -> None:
    # OpenCV hue 175 (magenta-red) and 3 (orange-red): one class, a range that wraps
    hsv = np.zeros((1, 3, 3), np.uint8)
    hsv[0, 0], hsv[0, 1], hsv[0, 2] = (175, 200, 200), (3, 200, 200), (90, 200, 200)
    red = ColourClass('red', (170, 100, 50), (7, 255, 255))
    assert mask(hsv, red)[0].tolist() == [255, 255, 0]


@pytest.mark.parametrize('shape', ['flat stripe', 'hoop', 'speck', 'diagonal streak'])
def test_buoy_coloured_shapes_that_are_not_buoys_are_refused(shape: str) -> None:
    img = blank()
    red = (35, 35, 205)
    if shape == 'flat stripe':          # aspect 10 / 120: below min_aspect
        cv2.rectangle(img, (100, 200), (219, 209), red, -1)
    elif shape == 'hoop':               # a U, 60 x 80, arms 15 thick: fills 0.59 of its box
        cv2.rectangle(img, (300, 200), (359, 279), red, -1)       # (extent passes), but
        cv2.rectangle(img, (315, 200), (344, 264), (125, 95, 45), -1)   # solidity 0.59 fails
    elif shape == 'speck':              # area below min_area
        cv2.rectangle(img, (100, 300), (107, 315), red, -1)
    else:                               # a thin diagonal: its box is mostly empty
        cv2.line(img, (100, 200), (180, 330), red, 7)
    assert default_detector().detect(img) == []


def test_the_shape_limits_are_each_what_refuses_them() -> None:
    """Each refusal above comes from the limit it is about: loosen that one alone and the
    shape is found (so the test above cannot pass for another reason)."""
    img = blank()
    cv2.rectangle(img, (100, 200), (219, 209), (35, 35, 205), -1)
    d = default_detector()
    loose = ClassicalDetector(d.classes, ShapeLimits(min_aspect=0.05))
    assert [x.class_id for x in loose.detect(img)] == [0]


def match(found: list[Detection], truth) -> tuple[int, int, int]:
    """True positives, false positives, false negatives: a detection matches an unmatched
    true box of its class with IoU >= 0.5."""
    used: set[int] = set()
    tp = 0
    for t in truth:
        tb = Detection(t.class_id, 1.0, t.x_min, t.y_min, t.x_max, t.y_max)
        best = [i for i, d in enumerate(found)
                if i not in used and d.class_id == t.class_id and iou(d, tb) >= 0.5]
        if best:
            used.add(best[0])
            tp += 1
    return tp, len(found) - len(used), len(truth) - tp


@pytest.mark.sim     # sixty frames drawn and searched: long for the unit tier
def test_precision_and_recall_on_generated_scenes() -> None:
    rng = np.random.default_rng(20261126)
    detector = default_detector()
    tp = fp = fn = 0
    for _ in range(60):
        img, truth = scene(rng)
        a, b, c = match(detector.detect(img), truth)
        tp, fp, fn = tp + a, fp + b, fn + c
    assert tp + fn >= 120                  # the set has enough buoys to mean something
    precision, recall = tp / (tp + fp), tp / (tp + fn)
    # on this seed all 143 buoys are found and nothing else: a margin of two either way
    assert precision >= 0.985, (tp, fp, fn)
    assert recall >= 0.985, (tp, fp, fn)


def test_hsv_and_class_parameters_are_checked_naming_the_parameter() -> None:
    with pytest.raises(ValueError, match=r'^hsv_lower: 6 values; class_names has 4 classes'):
        DetectorSettings.from_params({**DEFAULTS, 'hsv_lower': [0, 0, 0, 0, 0, 0]})
    with pytest.raises(ValueError, match=r"^hsv_upper: class 'green_buoy': H value 200 is "
                       r'outside 0..179'):
        DetectorSettings.from_params({**DEFAULTS, 'hsv_upper': [7, 255, 255, 200, 255, 255,
                                                                 35, 255, 255, 18, 255, 255]})
    with pytest.raises(ValueError, match=r"^hsv_lower: class 'red_buoy': S low 100 > high 50"):
        DetectorSettings.from_params({**DEFAULTS, 'hsv_upper': [7, 50, 255, 85, 255, 255,
                                                                 35, 255, 255, 18, 255, 255]})
    with pytest.raises(ValueError, match=r'^min_aspect: 5.0 > max_aspect 4.0'):
        DetectorSettings.from_params({**DEFAULTS, 'min_aspect': 5.0})
    with pytest.raises(ValueError, match=r"^backend: 'yolo' is not one of classical, onnx"):
        DetectorSettings.from_params({**DEFAULTS, 'backend': 'yolo'})
    with pytest.raises(ValueError, match=r'^class_names: needs at least one name'):
        DetectorSettings.from_params({**DEFAULTS, 'class_names': ['a', '']})
