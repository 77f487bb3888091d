"""The checkerboard renderer and the poses of a calibration run (pure numpy and OpenCV).

The projection is checked against OpenCV's ``projectPoints`` (a second formulation of
plumb_bob), the picture against where the squares must be, and the corners OpenCV finds in
it against the projected inner corners.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from enbarr_core.vision import board as vb
from enbarr_core.vision.board import (
    Board, calibration_poses, Camera, fits, Pose, project, render_board, undistort)
from enbarr_core.vision.intrinsics import find_corners, good_enough, view_params

pytestmark = pytest.mark.unit

#: A Raspberry Pi camera-like lens at 320x240: barrel distortion, a little tangential.
CAM = Camera(320, 240, 260.0, 262.0, 161.5, 118.5, (-0.25, 0.08, 0.001, -0.0005, 0.01))
#: The CS Saucer manual's board (4.1): 9x7 squares of 40 mm.
MANUAL_BOARD = Board(8, 6, 0.040)
BIG_SQUARES = Board(6, 4, 0.05)


def orderings(corners: np.ndarray, board: Board) -> list[np.ndarray]:
    """The four orders a board of odd x odd squares can be reported in (it is symmetric)."""
    g = corners.reshape(board.rows, board.cols, 2)
    return [g, g[::-1, ::-1], g[:, ::-1], g[::-1, :]]


def corner_error(found: np.ndarray, truth: np.ndarray, board: Board) -> float:
    t = truth.reshape(board.rows, board.cols, 2)
    return min(float(np.abs(o - t).max()) for o in orderings(found, board))


def test_the_manual_board_is_9x7_squares_of_40_mm():
    assert MANUAL_BOARD.outline()[1, 0] - MANUAL_BOARD.outline()[0, 0] == pytest.approx(0.36)
    assert MANUAL_BOARD.outline()[2, 1] - MANUAL_BOARD.outline()[1, 1] == pytest.approx(0.28)
    pts = MANUAL_BOARD.object_points()
    assert pts.shape == (48, 3)
    assert pts[1].tolist() == pytest.approx([0.040, 0.0, 0.0])    # along a row first
    assert pts[8].tolist() == pytest.approx([0.0, 0.040, 0.0])    # then the next row


def test_projection_is_opencvs_plumb_bob():
    pose = Pose((0.3, -0.2, 0.1), (0.05, -0.02, 0.6))
    pts = MANUAL_BOARD.object_points()
    ours = project(CAM, pose, pts)
    theirs, _ = cv2.projectPoints(pts, np.array(pose.rvec), np.array(pose.tvec), CAM.matrix,
                                  np.array(CAM.d))
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-9


def test_undistort_inverts_the_distortion_and_marks_the_fold():
    rng = np.random.default_rng(1)
    u = rng.uniform(0, CAM.width - 1, 500)
    v = rng.uniform(0, CAM.height - 1, 500)
    x, y, valid = undistort(CAM, u, v)
    assert valid.all()
    uu, vv = vb.distort(CAM, x, y)
    assert np.abs(uu - u).max() < 1e-6 and np.abs(vv - v).max() < 1e-6
    # Past the fold of a strong barrel lens no ray reaches the pixel: marked, not drawn.
    fisheye = Camera(320, 240, 100.0, 100.0, 160.0, 120.0, (-0.6, 0.0, 0.0, 0.0, 0.0))
    _, _, valid = undistort(fisheye, np.array([0.0, 160.0]), np.array([0.0, 120.0]))
    assert valid.tolist() == [False, True]


def test_the_picture_has_the_squares_where_they_project():
    pose = Pose((0.0, 0.0, 0.0), (-0.14, -0.1, 0.8))
    img = render_board(CAM, MANUAL_BOARD, pose)
    s = MANUAL_BOARD.square
    # Square (i, j) spans [i s, (i+1) s) x [j s, (j+1) s); the one at the origin corner's
    # upper left, (-1, -1), is black, and colours alternate.
    for i, j, colour in ((-1, -1, vb.BLACK), (0, -1, vb.WHITE), (0, 0, vb.BLACK),
                         (3, 2, vb.WHITE), (7, 5, vb.BLACK)):
        u, v = project(CAM, pose, np.array([[(i + 0.5) * s, (j + 0.5) * s, 0.0]]))[0]
        assert img[int(round(v)), int(round(u))] == pytest.approx(colour, abs=2), (i, j)
    # White paper round the squares, then the scene behind.
    u, v = project(CAM, pose, np.array([[-1.5 * s, 2.5 * s, 0.0]]))[0]
    assert img[int(round(v)), int(round(u))] == vb.WHITE
    u, v = project(CAM, pose, np.array([[-2.5 * s, 2.5 * s, 0.0]]))[0]
    assert img[int(round(v)), int(round(u))] == vb.BACKGROUND


def test_opencv_finds_the_corners_where_they_project_to_sub_pixel():
    # At 320x240 the fourth view (a small board in a corner) is too small for OpenCV's
    # detector; the first three are of the sizes a calibration gives.
    poses = calibration_poses(CAM, BIG_SQUARES, 3, seed=5)
    for pose in poses:
        img = render_board(CAM, BIG_SQUARES, pose)
        found = find_corners(img, BIG_SQUARES)
        assert found is not None
        truth = project(CAM, pose, BIG_SQUARES.object_points())
        assert corner_error(found, truth, BIG_SQUARES) < 0.3


def test_anti_aliasing_is_what_makes_the_corners_sub_pixel():
    pose = Pose((0.35, -0.3, 0.2), (-0.1, -0.05, 0.75))
    truth = project(CAM, pose, BIG_SQUARES.object_points())
    errors = {}
    for n in (1, 4):
        found = find_corners(render_board(CAM, BIG_SQUARES, pose, supersample=n), BIG_SQUARES)
        assert found is not None
        errors[n] = corner_error(found, truth, BIG_SQUARES)
    assert errors[4] < 0.25 < errors[1]


@pytest.mark.parametrize('axis', [0, 1])
def test_an_edge_along_the_pixel_grid_gets_fine_grey_levels(axis):
    # A board square to the image, moved across two pixels in 64 steps: the pixel its middle
    # edge sweeps over takes a regular 4x4 grid's 5 grey levels, the n-rooks arrangement's
    # 17; for an edge along the columns (axis 0: moved in x) and along the rows alike.
    cam = Camera(160, 120, 200.0, 200.0, 80.0, 60.0)
    edge = np.array([[0.1, 0.075, 0.0]]) if axis == 0 else np.array([[0.125, 0.1, 0.0]])
    start = Pose((0.0, 0.0, 0.0), (-0.1251, -0.0751, 1.0))
    u, v = np.rint(project(cam, start, edge)[0]).astype(int)
    values = set()
    for k in range(64):
        t = [-0.1251, -0.0751, 1.0]
        t[axis] += (k / 32 - 1) / cam.fx      # [m] at 1 m: -1 px to +1 px
        img = render_board(cam, BIG_SQUARES, Pose((0.0, 0.0, 0.0), (t[0], t[1], t[2])))
        values.add(int(img[v, u]))
    assert len(values) >= 15


def test_noise_is_seeded_and_blur_softens():
    pose = calibration_poses(CAM, BIG_SQUARES, 1, seed=2)[0]
    a = render_board(CAM, BIG_SQUARES, pose, noise=3.0, seed=7)
    b = render_board(CAM, BIG_SQUARES, pose, noise=3.0, seed=7)
    c = render_board(CAM, BIG_SQUARES, pose, noise=3.0, seed=8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    sharp = render_board(CAM, BIG_SQUARES, pose).astype(float)
    soft = render_board(CAM, BIG_SQUARES, pose, blur=1.5).astype(float)
    assert np.abs(np.diff(soft, axis=1)).max() < np.abs(np.diff(sharp, axis=1)).max()
    assert render_board(CAM, BIG_SQUARES, pose, color=True).shape == (240, 320, 3)


@pytest.mark.parametrize('seed', range(4))
def test_a_calibration_run_covers_the_image_as_the_ros_calibrator_wants(seed):
    cam = Camera(640, 480, 500.0, 505.0, 322.0, 238.0, (-0.25, 0.08, 0.001, -0.0005, 0.0))
    poses = calibration_poses(cam, MANUAL_BOARD, 20, seed=seed)
    assert len(poses) == 20
    assert all(fits(cam, MANUAL_BOARD, p, 10.0) for p in poses)
    params = [view_params(project(cam, p, MANUAL_BOARD.object_points()), MANUAL_BOARD,
                          cam.size) for p in poses]
    assert good_enough(params)
    assert calibration_poses(CAM, MANUAL_BOARD, 5, seed=3) == calibration_poses(
        CAM, MANUAL_BOARD, 5, seed=3)


def test_impossible_requests_are_errors():
    with pytest.raises(ValueError, match='inner corners'):
        Board(1, 6, 0.04)
    with pytest.raises(ValueError, match='5 coefficients'):
        Camera(320, 240, 260.0, 260.0, 160.0, 120.0, (0.1, 0.0))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='fits'):
        calibration_poses(Camera(16, 12, 20.0, 20.0, 8.0, 6.0), MANUAL_BOARD, 1)
