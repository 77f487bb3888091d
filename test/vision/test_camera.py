"""Unit tests: the shared pinhole camera model (K, D, size; projection through OpenCV)."""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision.board import Camera
from enbarr_core.vision.camera import PinholeCamera
from enbarr_core.vision.extrinsics import CameraModel
from enbarr_plugins.camera.sim_render import PinholeModel

pytestmark = pytest.mark.unit

K = (500.0, 0.0, 322.0, 0.0, 505.0, 238.0, 0.0, 0.0, 1.0)
D = (-0.25, 0.08, 0.001, -0.0005, 0.01)


def plumb_bob(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Brown-Conrady as sensor_msgs/CameraInfo documents it, written out (not OpenCV's)."""
    k1, k2, p1, p2, k3 = D
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([500.0 * xd + 322.0, 505.0 * yd + 238.0], axis=1)


def test_project_is_the_plumb_bob_model_and_normalized_inverts_it() -> None:
    cam = PinholeCamera(640, 480, K, D)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.5, 0.5, (50, 2))
    depth = rng.uniform(0.5, 8.0, 50)
    points = np.column_stack([xy * depth[:, None], depth])
    uv = cam.project(points)
    assert uv == pytest.approx(plumb_bob(xy[:, 0], xy[:, 1]), abs=1e-9)
    assert cam.normalized(uv) == pytest.approx(xy, abs=1e-9)
    assert cam.project(np.zeros((0, 3))).shape == cam.normalized(np.zeros((0, 2))).shape


def test_project_takes_a_pose_as_opencv_does() -> None:
    cam = PinholeCamera(0, 0, K, ())
    # (0, 0, 1) turned a quarter about y is (1, 0, 0), then moved 2 m ahead: (1, 0, 2)
    uv = cam.project([[0.0, 0.0, 1.0]], rvec=(0.0, np.pi / 2, 0.0), tvec=(0.0, 0.0, 2.0))
    assert uv == pytest.approx(np.array([[322.0 + 500.0 * 1.0 / 2.0, 238.0]]))


def test_the_matrices_and_the_nominal_camera() -> None:
    cam = PinholeCamera.nominal(640, 480, 400.0)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.size) == (400.0, 400.0, 319.5, 239.5,
                                                          (640, 480))
    assert cam.matrix.tolist() == [[400.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]]
    assert cam.projection == (400.0, 0.0, 319.5, 0.0, 0.0, 400.0, 239.5, 0.0, 0.0, 0.0, 1.0,
                              0.0)
    assert PinholeCamera.nominal(64, 48, 50.0, (0.0,) * 8).distortion_model == \
        'rational_polynomial'
    assert PinholeCamera(1, 1, K, ()).dist_coeffs.tolist() == [0.0] * 5


@pytest.mark.parametrize('args, words', [
    ((-1, 480, K, D), 'image size'),
    ((640, 480, K[:8], D), 'K: expected 9'),
    ((640, 480, (0.0,) + K[1:], D), 'fx, fy > 0'),
    ((640, 480, (float('nan'),) + K[1:], D), 'finite'),
    ((640, 480, K, D[:3]), 'D: expected'),
])
def test_a_bad_camera_is_refused_with_its_field(args: tuple, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        PinholeCamera(*args)


def test_the_three_users_build_the_one_model() -> None:
    """The board renderer's, the lidar calibration's and the simulated camera's cameras are
    the shared model: equal intrinsics project alike."""
    board = Camera(640, 480, 500.0, 505.0, 322.0, 238.0, D)
    lidar = CameraModel.of(np.reshape(K, (3, 3)), D, 640, 480)
    sim = PinholeModel(640, 480, K, D)
    p = [[0.3, -0.2, 2.0]]
    for cam in (board, lidar, sim):
        assert isinstance(cam, PinholeCamera)
        assert (cam.k, cam.d) == (K, D)
        assert cam.project(p) == pytest.approx(board.project(p))
    with pytest.raises(CalibrationError, match='coefficients'):
        CameraModel.of(np.reshape(K, (3, 3)), D[:3])
    with pytest.raises(ValueError, match='draws'):
        PinholeModel(640, 480, K, D, 'equidistant')
