"""The vision figures against hand-computed answers on made-up frames and runs."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from enbarr_interfaces import obstacles as ob
from enbarr_core.framework.frames import Transform
from enbarr_core.tools.vision_metrics import (
    fusion_latencies, fusion_position_error, iou, label_boxes, match_frame, precision_recall,
    Tally, TruthBox)
from enbarr_core.vision.classical import ColourClass
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Static, World
from enbarr_plugins.camera.sim_render import PinholeModel, SimulatedCamera

pytestmark = pytest.mark.unit

NS = 1_000_000_000
MIN_PIXELS = 150


def truth(box, class_id=3, pixels=1000, index=0) -> TruthBox:
    return TruthBox(index, class_id, box, pixels)


def test_label_boxes_take_pixel_edges_and_count_pixels():
    labels = np.full((6, 8), -1, np.int16)
    labels[0, 0] = 2                 # the top-left pixel alone: 0, 0, 1, 1
    labels[2:5, 3:7] = 0             # rows 2..4, columns 3..6
    labels[5, 7] = -2                # sky: no box
    assert label_boxes(labels) == {2: ((0.0, 0.0, 1.0, 1.0), 1),
                                   0: ((3.0, 2.0, 7.0, 5.0), 12)}


def test_iou_by_hand():
    assert iou((0, 0, 2, 2), (1, 0, 3, 2)) == pytest.approx(2 / 6)
    assert iou((0, 0, 2, 2), (2, 0, 4, 2)) == 0.0   # touching: no overlap
    assert iou((0, 0, 2, 2), (0, 0, 2, 2)) == 1.0


def test_a_missed_box_lowers_recall_by_one_over_n():
    frames = [([truth((10, 10, 30, 30))], [(3, (10, 10, 30, 30))]) for _ in range(3)]
    frames.append(([truth((10, 10, 30, 30))], []))   # the fourth box is missed
    tallies = [match_frame(t, d, MIN_PIXELS) for t, d in frames]
    assert precision_recall(tallies) == (1.0, 0.75)


def test_a_false_box_lowers_precision_only():
    truths = [truth((10, 10, 30, 30)), truth((50, 10, 70, 30), index=1)]
    found = [(3, (11, 10, 31, 30)), (3, (50, 11, 70, 31)), (3, (100, 100, 120, 120))]
    tally = match_frame(truths, found, MIN_PIXELS)
    assert tally == Tally(2, 3, 2)
    assert precision_recall([tally]) == (pytest.approx(2 / 3), 1.0)


def test_the_iou_threshold_is_inclusive():
    t = [truth((0, 0, 40, 20))]                       # area 800
    at_half = [(3, (0, 0, 40, 10))]                   # inside it, area 400: IoU 0.5
    below = [(3, (0, 0, 40, 9.9))]                    # IoU 0.495
    assert match_frame(t, at_half, MIN_PIXELS) == Tally(1, 1, 1)
    assert match_frame(t, below, MIN_PIXELS) == Tally(0, 1, 1)


def test_matching_is_one_to_one_and_by_class():
    t = [truth((10, 10, 30, 30))]
    twice = [(3, (10, 10, 30, 30)), (3, (10, 10, 30, 31))]
    assert match_frame(t, twice, MIN_PIXELS) == Tally(1, 2, 1)   # the second is false
    other_class = [(0, (10, 10, 30, 30))]
    assert match_frame(t, other_class, MIN_PIXELS) == Tally(0, 1, 1)


def test_a_box_of_too_few_pixels_is_neither_counted_nor_a_false_detection():
    small = truth((10, 10, 20, 20), pixels=MIN_PIXELS - 1)
    big = truth((50, 10, 70, 30), pixels=MIN_PIXELS, index=1)
    assert match_frame([small, big], [(3, (10, 10, 20, 20))], MIN_PIXELS) == Tally(0, 0, 1)
    assert match_frame([small, big], [], MIN_PIXELS) == Tally(0, 0, 1)
    assert precision_recall([Tally(0, 0, 0)]) == (None, None)


def test_an_occluded_obstacle_has_no_box():
    """A buoy straight behind a bigger nearer one shows no pixel; one beside it does."""
    zc = 0.3
    level = Transform.from_rpy((0.0, 0.0, zc), (-math.pi / 2, 0.0, -math.pi / 2))
    cam = SimulatedCamera(PinholeModel.nominal(320, 240, 250.0), level)
    world = World([Obstacle('near', Circle((3.0, 0.0), 0.3), Static()),
                   Obstacle('behind', Circle((6.0, 0.0), 0.2), Static()),
                   Obstacle('beside', Circle((6.0, 2.0), 0.2), Static())])
    boxes = label_boxes(cam.render(world, 0.0, 0.0, 0.0, 0.0).labels)
    assert set(boxes) == {0, 2}
    # the same buoy with the near one gone is seen
    alone = World([Obstacle('behind', Circle((6.0, 0.0), 0.2), Static())])
    assert set(label_boxes(cam.render(alone, 0.0, 0.0, 0.0, 0.0).labels)) == {0}


def test_fusion_position_error_of_classed_circles_at_their_stamps():
    world = World([Obstacle('boat', Circle((0.0, 0.0), 0.3), ConstantVelocity((1.0, 0.0)))])
    epoch = 1.0
    fused = [  # the boat is at (2, 0) at world time 2 s: stamp 3 s
        ob.Obstacle(1, ob.CIRCLE, 2.3, 0.4, 0.3, stamp_ns=3 * NS, class_id=3),   # 0.5 m
        ob.Obstacle(1, ob.CIRCLE, 2.0, 0.1, 0.3, stamp_ns=3 * NS, class_id=3),   # 0.1 m
        ob.Obstacle(2, ob.CIRCLE, 2.9, 0.0, 0.3, stamp_ns=3 * NS),               # no class
        ob.Obstacle(3, ob.CIRCLE, 9.0, 9.0, 0.3, stamp_ns=3 * NS, class_id=3),   # matches none
    ]
    assert fusion_position_error(fused, world, epoch) == pytest.approx(
        math.sqrt((0.5 ** 2 + 0.1 ** 2) / 2), abs=1e-4)
    assert fusion_position_error(fused[2:], world, epoch) is None


def _cloud(stamp_ns: int, classed: bool, recv: int) -> tuple[int, object]:
    o = ob.Obstacle(1, ob.CIRCLE, 1.0, 0.0, 0.2, stamp_ns=stamp_ns,
                    class_id=3 if classed else ob.NO_CLASS)
    return recv, ob.to_cloud([o], stamp_ns, 'odom')


def test_fusion_latency_is_image_stamp_to_the_next_classed_fused_message():
    det = [(int(1.10 * NS), SimpleNamespace(width=1, header=_header(int(1.00 * NS)))),
           (int(1.30 * NS), SimpleNamespace(width=0, header=_header(int(1.20 * NS)))),  # empty
           (int(1.50 * NS), SimpleNamespace(width=2, header=_header(int(1.45 * NS)))),
           (int(9.00 * NS), SimpleNamespace(width=1, header=_header(int(8.90 * NS))))]  # none
    fused = [_cloud(NS, True, int(1.05 * NS)),        # before the detections arrived
             _cloud(NS, False, int(1.15 * NS)),       # no class yet
             _cloud(NS, True, int(1.25 * NS)),        # the first image's: 0.25 s
             _cloud(NS, True, int(1.50 * NS))]        # the third's, same instant: 0.05 s
    assert fusion_latencies(det, fused) == pytest.approx([0.25, 0.05])


def _header(stamp_ns: int) -> SimpleNamespace:
    sec, nanosec = divmod(stamp_ns, NS)
    return SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec))


def test_colour_classes_by_the_detectors_hsv_boxes():
    from enbarr_core.tools.vision_metrics import colour_classes
    # the detector's default red and orange boxes (enbarr_core/vision/detector_node.py)
    classes = [ColourClass('red_buoy', (170, 100, 50), (7, 255, 255)),
               ColourClass('orange_buoy', (8, 100, 50), (18, 255, 255))]
    world = World([Obstacle('o', Circle((1.0, 0.0), 0.2), Static()),              # default
                   Obstacle('r', Circle((2.0, 0.0), 0.2), Static(), colour=(220, 20, 20)),
                   Obstacle('w', Circle((3.0, 0.0), 0.2), Static(), colour=(225, 225, 220))])
    assert colour_classes(world, classes) == [1, 0, -1]
