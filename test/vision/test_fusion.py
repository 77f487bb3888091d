"""Camera and lidar fusion: projection against a hand-computed pinhole, assignment, gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.vision import fusion as fu
from enbarr_interfaces.obstacles import CIRCLE, NO_CLASS, Obstacle, SEGMENT

pytestmark = pytest.mark.unit

# A camera 0.25 m above base_link's origin looking along base_link's x (REP-103 optical frame:
# x_opt = -y_base, y_opt = -z_base, z_opt = x_base), typed rather than taken from the tree.
OPTICAL_FROM_BASE = np.array([[0.0, -1.0, 0.0, 0.0],
                              [0.0, 0.0, -1.0, 0.25],
                              [1.0, 0.0, 0.0, 0.0],
                              [0.0, 0.0, 0.0, 1.0]])
K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
CAMERA = fu.Camera(K, np.zeros(5), 640, 480, OPTICAL_FROM_BASE)
SETTINGS = fu.FusionSettings(object_height=0.5, min_iou=0.2)


def buoy(i: int, x: float, y: float, r: float = 0.2, **kw: float) -> Obstacle:
    return Obstacle(i, CIRCLE, x, y, r, **kw)  # type: ignore[arg-type]


def test_projection_matches_the_pinhole_by_hand() -> None:
    # Vessel at (10, 5) heading north (psi = pi/2, ENU): the buoy at (10, 9) is 4 m ahead.
    # Radius 0.2: tangent points at 4 - 0.2 * 0.05 = 3.99 m ahead, 0.2 * sqrt(1 - 0.05^2) =
    # 0.199750 m aside: u = 320 -+ 500 * 0.199750 / 3.99 = 294.9687 .. 345.0313. The nearest
    # rim point is 3.8 m ahead; the top (0.5 m) is 0.25 m above the camera, the waterline
    # 0.25 m below: v = 240 -+ 500 * 0.25 / 3.8 = 207.1053 .. 272.8947.
    box = fu.project_obstacle(buoy(1, 10.0, 9.0), np.array([10.0, 5.0, math.pi / 2]),
                              CAMERA, SETTINGS)
    assert box is not None
    assert box.x_min == pytest.approx(294.969, abs=1.0)
    assert box.x_max == pytest.approx(345.031, abs=1.0)
    assert box.y_min == pytest.approx(207.105, abs=1.0)
    assert box.y_max == pytest.approx(272.895, abs=1.0)
    # tighter than the 1 px asked: the tangents and the nearest point are exact (the rim
    # samples alone, every 5 degrees, miss the edges by about 0.02 px)
    assert (box.x_min, box.x_max) == pytest.approx((294.9687, 345.0313), abs=0.005)
    assert (box.y_min, box.y_max) == pytest.approx((207.1053, 272.8947), abs=0.005)


def test_projection_turns_with_the_heading() -> None:
    # Heading north, a buoy 0.5 m west of the bow line is on the left of the image:
    # centre u about 320 - 500 * 0.5 / 4 = 257.5.
    box = fu.project_obstacle(buoy(1, 9.5, 9.0), np.array([10.0, 5.0, math.pi / 2]),
                              CAMERA, SETTINGS)
    assert box is not None
    assert 0.5 * (box.x_min + box.x_max) == pytest.approx(257.5, abs=1.0)


def test_projection_moves_the_obstacle_to_the_image_stamp() -> None:
    # 0.5 s after the scan, a buoy moving 0.4 m/s east is 0.2 m to the right of where it was:
    # centre u = 320 + 500 * 0.2 / 4 = 345 (vessel at the origin heading east).
    moving = buoy(1, 4.0, 0.0, vx=0.0, vy=-0.4)
    box = fu.project_obstacle(moving, np.zeros(3), CAMERA, SETTINGS, dt=0.5)
    assert box is not None
    assert 0.5 * (box.x_min + box.x_max) == pytest.approx(345.0, abs=1.0)


def test_behind_the_camera_and_outside_the_image_are_not_projected() -> None:
    assert fu.project_obstacle(buoy(1, -4.0, 0.0), np.zeros(3), CAMERA, SETTINGS) is None
    # beside the vessel: 90 degrees off the axis, nothing of it in front
    assert fu.project_obstacle(buoy(1, 0.0, 4.0), np.zeros(3), CAMERA, SETTINGS) is None
    # in front but far off to the left: u = 320 - 500 * 3 / 1 < 0 for the whole cylinder
    assert fu.project_obstacle(buoy(1, 1.0, 3.0), np.zeros(3), CAMERA, SETTINGS) is None
    wall = Obstacle(2, SEGMENT, 4.0, -1.0, 0.0, x2=4.0, y2=1.0)
    assert fu.project_obstacle(wall, np.zeros(3), CAMERA, SETTINGS) is None


def test_behind_camera_obstacle_takes_no_class_from_its_mirror_image() -> None:
    # A detection where a buoy 4 m ahead would be; the only obstacle is 4 m astern.
    ahead = fu.project_obstacle(buoy(1, 4.0, 0.0), np.zeros(3), CAMERA, SETTINGS)
    assert ahead is not None
    out = fu.fuse([buoy(1, -4.0, 0.0)], np.zeros(3), 0, CAMERA,
                  [fu.DetectedBox(3, 0.9, ahead)], SETTINGS)
    assert out.matches == [] and out.unmatched_detections == [0]
    assert out.obstacles[0].class_id == NO_CLASS


def box(x0: float, x1: float) -> fu.Box:
    return fu.Box(x0, 0.0, x1, 10.0)


def test_assignment_beats_greedy_on_a_crossing() -> None:
    # IoU: P0-D0 9/11 = 0.82 (the best pair), P0-D1 7/13, P1-D0 7/13, P1-D1 3/17 < the gate.
    # Greedy takes P0-D0 and leaves P1 alone; the assignment pairs both, crosswise.
    projected = [box(4.0, 14.0), box(0.0, 10.0)]
    detected = [box(3.0, 13.0), box(7.0, 17.0)]
    assert fu.iou(projected[0], detected[0]) == pytest.approx(9 / 11)
    assert sorted(fu.associate(projected, detected, 0.2)) == [(0, 1), (1, 0)]


def test_assignment_takes_the_larger_overlaps() -> None:
    # All four pairs inside the gate: P0-D0 and P1-D1 overlap fully, the cross pairs 5/15.
    projected = [box(0.0, 10.0), box(5.0, 15.0)]
    detected = [box(0.0, 10.0), box(5.0, 15.0)]
    assert fu.iou(projected[0], detected[1]) == pytest.approx(1 / 3)
    assert sorted(fu.associate(projected, detected, 0.1)) == [(0, 0), (1, 1)]


def test_gate_refuses_a_pair_below_min_iou() -> None:
    # IoU of [0, 10] and [7, 17]: 3 / 17 = 0.176
    assert fu.associate([box(0.0, 10.0)], [box(7.0, 17.0)], 0.2) == []
    assert fu.associate([box(0.0, 10.0)], [box(7.0, 17.0)], 0.15) == [(0, 0)]


def test_fuse_classes_the_matched_and_keeps_the_rest() -> None:
    left, right = buoy(1, 4.0, 0.6), buoy(2, 4.0, -0.6)
    far_left = fu.project_obstacle(left, np.zeros(3), CAMERA, SETTINGS)
    far_right = fu.project_obstacle(right, np.zeros(3), CAMERA, SETTINGS)
    assert far_left is not None and far_right is not None
    wall = Obstacle(9, SEGMENT, -20.0, 3.0, 0.0, x2=20.0, y2=3.0)
    stray = fu.DetectedBox(0, 0.7, fu.Box(10.0, 10.0, 40.0, 40.0))   # no obstacle there
    detections = [fu.DetectedBox(2, 0.8, far_right), stray, fu.DetectedBox(1, 0.9, far_left)]
    out = fu.fuse([left, wall, right], np.zeros(3), 0, CAMERA, detections, SETTINGS)
    assert [o.class_id for o in out.obstacles] == [1, NO_CLASS, 2]
    assert [o.class_score for o in out.obstacles] == pytest.approx([0.9, 0.0, 0.8])
    # the lidar's geometry is untouched
    assert (out.obstacles[0].x, out.obstacles[0].y, out.obstacles[0].radius) == (4.0, 0.6, 0.2)
    assert out.obstacles[1] == wall
    # the stray box is reported, not made an obstacle
    assert out.unmatched_detections == [1]
    assert len(out.obstacles) == 3


def test_class_memory_votes_over_frames_and_keeps_the_class_out_of_view() -> None:
    memory = fu.ClassMemory()
    b = buoy(5, 4.0, 0.0)
    seen = fu.project_obstacle(b, np.zeros(3), CAMERA, SETTINGS)
    assert seen is not None
    for class_id, score in ((3, 0.9), (3, 0.8), (0, 0.95)):
        out = fu.fuse([b], np.zeros(3), 0, CAMERA, [fu.DetectedBox(class_id, score, seen)],
                      SETTINGS, memory)
    assert out.obstacles[0].class_id == 3   # one odd frame does not flip it
    assert out.obstacles[0].class_score == pytest.approx(1.7 / 2.65)
    out = fu.fuse([b], np.zeros(3), 0, CAMERA, [], SETTINGS, memory)
    assert out.obstacles[0].class_id == 3
    # the track ends: its votes go; a new track with the id reused starts unclassified
    fu.fuse([], np.zeros(3), 0, CAMERA, [], SETTINGS, memory)
    out = fu.fuse([b], np.zeros(3), 0, CAMERA, [], SETTINGS, memory)
    assert out.obstacles[0].class_id == NO_CLASS


def test_settings_refuse_nonsense() -> None:
    with pytest.raises(ValueError, match='min_iou'):
        fu.FusionSettings(min_iou=0.0)
    with pytest.raises(ValueError, match='object_height'):
        fu.FusionSettings(object_height=-1.0)


def test_iou_matrix_agrees_with_the_pairwise_iou() -> None:
    rng = np.random.default_rng(3)
    corners = rng.uniform(0.0, 15.0, (9, 2))
    boxes = [fu.Box(x, y, x + w, y + h)
             for (x, y), (w, h) in zip(corners, rng.uniform(5.0, 20.0, (9, 2)))]
    boxes.append(fu.Box(5.0, 5.0, 5.0, 9.0))      # empty
    m = fu.iou_matrix(boxes[:4], boxes[4:])
    pairwise = np.array([[fu.iou(a, b) for b in boxes[4:]] for a in boxes[:4]])
    assert (pairwise[:, :-1] > 0.0).sum() >= 10 and np.all(pairwise[:, -1] == 0.0)
    assert m == pytest.approx(pairwise)
    # by hand: [0, 10] x [0, 10] and [5, 15] x [0, 10]: 50 / 150
    assert fu.iou_matrix([box(0.0, 10.0)], [box(5.0, 15.0)])[0, 0] == pytest.approx(1 / 3)


def test_a_box_half_out_of_the_image_is_clipped_to_it() -> None:
    # 2.6 m right of the axis at 4 m: centre u = 320 + 500 * 2.6 / 4 = 645 > 640. The left
    # tangent's bearing: atan2(2.6, 4) - asin(0.2 / hypot(2.6, 4)) = 0.576375 - 0.041935 =
    # 0.534440 rad, u = 320 + 500 tan(0.534440) = 615.95; the box ends at the image's edge.
    b = fu.project_obstacle(buoy(1, 4.0, -2.6), np.zeros(3), CAMERA, SETTINGS)
    assert b is not None
    assert b.x_max == 640.0 and b.x_min == pytest.approx(615.95, abs=0.05)
