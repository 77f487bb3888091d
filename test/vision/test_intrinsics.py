"""Intrinsic calibration as ROS's camera_calibration does it (image_pipeline 5.0.1
calibrator.py): the coverage numbers pinned on cases worked by hand, the view selection, the
progress, and calibrateCamera on views with known intrinsics (rendered ones in the sim tier).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision import intrinsics as vi
from enbarr_core.vision.board import (
    Board, calibration_poses, Camera, distort, Pose, project, render_board)
from enbarr_core.vision.intrinsics import (
    calibrate, coverage, find_corners, good_enough, view_params, ViewSelector)

BOARD = Board(8, 6, 0.040)      # the CS Saucer manual's board (4.1)
SIZE = (640, 480)
#: A Raspberry Pi camera-like lens: barrel distortion, a little tangential; k3 = 0 so that
#: the default of two radial coefficients (cameracalibrator's) can fit it exactly.
CAM = Camera(640, 480, 500.0, 505.0, 322.0, 238.0, (-0.25, 0.08, 0.001, -0.0005, 0.0))


def grid(x0: float, y0: float, step: float = 10.0, shear: float = 0.0) -> np.ndarray:
    """8x6 corners row by row from (x0, y0), ``step`` apart; each row shifted by ``shear``."""
    return np.array([(x0 + i * step + j * shear, y0 + j * step)
                     for j in range(6) for i in range(8)], dtype=float)


@pytest.mark.unit
def test_the_numbers_of_an_upright_rectangle():
    # Outer inner corners (100, 50), (170, 50), (170, 100), (100, 100): area 70 * 50 = 3500,
    # border sqrt(3500) = 59.161; mean (135, 75).
    # X = (135 - 29.580) / (640 - 59.161) = 0.18150, Y = (75 - 29.580) / (480 - 59.161) =
    # 0.10793, size = sqrt(3500 / (640 * 480)) = 0.10674, skew 0 (a right angle).
    x, y, size, skew = view_params(grid(100, 50), BOARD, SIZE)
    assert (x, y, size, skew) == pytest.approx((0.18150, 0.10793, 0.10674, 0.0), abs=5e-5)


@pytest.mark.unit
def test_skew_is_twice_the_departure_from_a_right_angle():
    # Rows shifted by -50 tan(10 deg) / 5 each: the angle at up_right is 80 deg, so skew is
    # 2 * 10 deg = 0.34907 rad; a shear keeps the area (3500), so size is unchanged.
    sheared = grid(100, 50, shear=-50 * math.tan(math.radians(10)) / 5)
    _, _, size, skew = view_params(sheared, BOARD, SIZE)
    assert skew == pytest.approx(0.34907, abs=1e-5)
    assert size == pytest.approx(0.10674, abs=5e-5)
    # 60 deg: 2 * 30 deg = 1.047 rad, clipped to 1.
    _, _, _, skew = view_params(grid(100, 50, shear=-50 * math.tan(math.radians(30)) / 5),
                                BOARD, SIZE)
    assert skew == 1.0


@pytest.mark.unit
def test_x_and_y_are_clipped_to_the_shrunk_image():
    x, y, _, _ = view_params(grid(-20, -20), BOARD, SIZE)   # mean (15, 5) < border / 2
    assert (x, y) == (0.0, 0.0)


@pytest.mark.unit
def test_a_view_is_kept_only_when_its_numbers_differ_by_more_than_0_2():
    # X moves by dx / (640 - 59.161): 0.19 for dx = 110.36 px, 0.21 for dx = 121.98 px.
    sel = ViewSelector(BOARD, SIZE)
    assert sel.offer_corners(grid(100, 50), 'first') is not None
    assert sel.offer_corners(grid(100 + 110.36, 50), 'near') is None
    kept = sel.offer_corners(grid(100 + 121.98, 50), 'far')
    assert kept is not None and kept.label == 'far'
    assert len(sel.views) == 2


@pytest.mark.unit
def test_progress_is_the_spread_over_the_ranges_with_size_and_skew_from_zero():
    params = [(0.1, 0.2, 0.3, 0.1), (0.5, 0.9, 0.2, 0.4)]
    # X: 0.4 / 0.7 = 0.5714; Y: 0.7 / 0.7 = 1; size: (0.3 - 0) / 0.4 = 0.75; skew 0.4 / 0.5.
    got = coverage(params)
    assert [p.name for p in got] == ['X', 'Y', 'Size', 'Skew']
    assert [(p.low, p.high, p.progress) for p in got] == [
        pytest.approx(v) for v in ((0.1, 0.5, 0.4 / 0.7), (0.2, 0.9, 1.0), (0.0, 0.3, 0.75),
                                   (0.0, 0.4, 0.8))]
    assert not good_enough(params)
    assert good_enough(params + [(0.9, 0.1, 0.45, 0.6)])
    assert coverage([]) == [] and not good_enough([])


@pytest.mark.unit
def test_forty_views_are_enough_whatever_their_coverage():
    same = [(0.5, 0.5, 0.3, 0.1)] * 39
    assert not good_enough(same)
    assert good_enough(same + [(0.5, 0.5, 0.3, 0.1)])


@pytest.mark.unit
def test_the_refinement_window_stays_off_the_paper_edge():
    # A foreshortened view in which calibrator.py's window of half the corner spacing pulled
    # the lower left inner corner 4.9 px towards the edge of the paper.
    pose = Pose((0.5574044793744584, 0.5248405757515608, 0.2113646890325008),
                (-0.4721817974303155, -0.11623487367206506, 0.8204478047155863))
    found = find_corners(render_board(CAM, BOARD, pose), BOARD)
    assert found is not None
    truth = project(CAM, pose, BOARD.object_points()).reshape(6, 8, 2)
    g = found.reshape(6, 8, 2)
    assert min(np.abs(o - truth).max() for o in (g, g[::-1, ::-1], g[:, ::-1], g[::-1])) < 0.3


def selected_truth(cam: Camera, n: int, noise: float, seed: int) -> ViewSelector:
    """Views of the projected corners (no picture) with pixel noise, through the selector."""
    rng = np.random.default_rng(seed)
    sel = ViewSelector(BOARD, cam.size)
    for i, pose in enumerate(calibration_poses(cam, BOARD, n, seed=seed)):
        corners = project(cam, pose, BOARD.object_points())
        sel.offer_corners(corners + rng.normal(0.0, noise, corners.shape), str(i))
    return sel


@pytest.mark.unit
def test_calibration_recovers_the_intrinsics_from_exact_corners():
    sel = selected_truth(CAM, 20, noise=0.05, seed=4)
    result = calibrate(sel.views, BOARD, CAM.size)
    k = result.k
    for got, want in ((k[0, 0], CAM.fx), (k[1, 1], CAM.fy), (k[0, 2], CAM.cx),
                      (k[1, 2], CAM.cy)):
        assert got == pytest.approx(want, rel=0.002)
    assert result.d[:4] == pytest.approx(CAM.d[:4], abs=0.003)
    assert result.d[4] == 0.0                         # k3 held at 0 with two coefficients
    assert 0.02 < result.rms < 0.1                    # the noise put in: 0.05 px per axis
    assert (result.width, result.height, result.views) == (640, 480, len(sel.views))


@pytest.mark.unit
def test_the_projection_matrix_keeps_every_rectified_pixel_inside_the_image():
    # ROS's P for a monocular camera: getOptimalNewCameraMatrix with alpha 0, the camera
    # matrix of the undistorted image all of whose pixels see the raw image. Checked here the
    # other way round: every border pixel of the rectified image, through P^-1 and the lens,
    # lands inside the raw image, and the tightest one on its edge.
    sel = selected_truth(CAM, 20, noise=0.0, seed=4)
    result = calibrate(sel.views, BOARD, CAM.size)
    p = result.p
    assert p[:, 3].tolist() == [0.0, 0.0, 0.0] and result.r.tolist() == np.eye(3).tolist()
    fitted = Camera(640, 480, result.k[0, 0], result.k[1, 1], result.k[0, 2], result.k[1, 2],
                    tuple(float(x) for x in result.d))  # type: ignore[arg-type]
    t = np.linspace(0, 1, 200)
    u = np.concatenate([t * 639, t * 639, np.zeros_like(t), np.full_like(t, 639)])
    v = np.concatenate([np.zeros_like(t), np.full_like(t, 479), t * 479, t * 479])
    x = (u - p[0, 2]) / p[0, 0]
    y = (v - p[1, 2]) / p[1, 1]
    uu, vv = distort(fitted, x, y)
    margin = np.minimum.reduce([uu, 639 - uu, vv, 479 - vv])
    assert margin.min() > -1.0 and margin.min() < 2.0
    assert p[0, 0] < result.k[0, 0]         # a barrel lens: zoomed in to hide the black rim
    undistorted = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    sel = selected_truth(undistorted, 12, noise=0.0, seed=1)
    flat = calibrate(sel.views, BOARD, undistorted.size, k_coefficients=1)
    assert flat.p[:, :3] == pytest.approx(flat.k, rel=1e-3)   # no distortion: P = [K | 0]


@pytest.mark.unit
def test_too_few_views_or_coefficients_are_errors():
    sel = ViewSelector(BOARD, SIZE)
    sel.offer_corners(grid(100, 50))
    with pytest.raises(CalibrationError, match='1 view'):
        calibrate(sel.views, BOARD, SIZE)
    with pytest.raises(CalibrationError, match='1 to 3'):
        vi.calibration_flags(4)
    with pytest.raises(CalibrationError, match='320x240, but the first image was 640x480'):
        sel.offer(np.zeros((240, 320), np.uint8), '')


@pytest.mark.sim
def test_calibration_from_rendered_views_recovers_the_intrinsics():
    """The acceptance: rendered views of the manual's board with a known lens and sensor
    noise; fx, fy, cx, cy within 0.5 %, reprojection RMS below 0.3 px."""
    sel = ViewSelector(BOARD, CAM.size)
    for i, pose in enumerate(calibration_poses(CAM, BOARD, 20, seed=3)):
        sel.offer(render_board(CAM, BOARD, pose, noise=2.0, blur=0.5, seed=i), f'view {i}')
    assert sel.detected >= 18 and sel.good_enough
    result = calibrate(sel.views, BOARD, CAM.size)
    k = result.k
    for got, want in ((k[0, 0], CAM.fx), (k[1, 1], CAM.fy), (k[0, 2], CAM.cx),
                      (k[1, 2], CAM.cy)):
        assert got == pytest.approx(want, rel=0.005)
    assert result.rms < 0.3
