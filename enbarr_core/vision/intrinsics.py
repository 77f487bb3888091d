"""Intrinsic calibration from checkerboard views, the way ROS's camera_calibration does it.

Followed: ros-perception/image_pipeline, camera_calibration/src/camera_calibration/
calibrator.py at release 5.0.1 (rolling, commit 30b982a, March 2024; Jazzy ships the 5.0
line):

- detection (``_get_corners``): ``cv2.findChessboardCorners`` with adaptive threshold,
  image normalization and the fast check, on a pattern of (max, min) of the two sizes; a view
  with an inner corner within 8 px of the image edge is rejected; the corners are ordered
  top to bottom; ``cornerSubPix`` with a window sized by the smallest corner spacing
  (``REFINE_WINDOW``: calibrator.py takes half of it; and it indexes rows with ``n_rows``
  where it means ``n_cols`` when it looks for that spacing; the spacing meant is used here);
- coverage (``get_parameters``): per view X, Y, size and skew in [0, 1] from the four outer
  inner corners: area = |p x q| / 2 of the quadrilateral, border = sqrt(area), X = (mean u -
  border / 2) / (width - border) clipped, likewise Y, size = sqrt(area / (width height)),
  skew = min(1, 2 |pi/2 - angle(up_left, up_right, down_right)|);
- view selection (``is_good_sample``): a view is kept when the L1 distance of its four
  numbers to every kept view's exceeds 0.2;
- progress (``compute_goodenough``): per number min((max - min) / range, 1) over the kept
  views with range (0.7, 0.7, 0.4, 0.5) and the minimum of size and skew taken as 0; good
  enough when all four are 1 or 40 views are kept;
- calibration (``cal_fromcorners``): ``cv2.calibrateCamera`` from the identity, flags from
  the number of radial coefficients (cameracalibrator's ``-k``, default 2: k3 fixed at 0);
- projection (``set_alpha(0.0)``): a monocular camera's R is the identity and P = [K' | 0]
  with K' = ``cv2.getOptimalNewCameraMatrix(K, D, size, alpha=0)``, the camera matrix of the
  undistorted image in which every pixel is valid (not K itself).

Not followed: calibrator.py detects on a copy scaled down to about 640x480 and refines in the
full image; here detection runs on the full image. Pure numpy and OpenCV; no ROS.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
import math

import cv2
import numpy as np

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision.board import Board

#: An inner corner this close to the image edge rejects the view [px] (calibrator.py BORDER).
BORDER = 8
#: The spread of X, Y, size and skew that counts as full coverage (calibrator.py).
PARAM_RANGES = (0.7, 0.7, 0.4, 0.5)
PARAM_NAMES = ('X', 'Y', 'Size', 'Skew')
#: cornerSubPix's half window as a share of the smallest corner spacing. calibrator.py takes
#: half; in a foreshortened view that window reached the paper's edge beside an outer corner
#: and pulled the corner pixels off (test_intrinsics), a third of a spacing does not.
REFINE_WINDOW = 0.35
#: A view is kept when its L1 distance to every kept view exceeds this (calibrator.py).
MIN_DISTANCE = 0.2
#: With this many views kept, calibration is allowed whatever the coverage (calibrator.py).
ENOUGH_VIEWS = 40


@dataclass(frozen=True)
class View:
    """One detected board: its corners (N, 2) [px] and its coverage numbers."""

    corners: np.ndarray
    params: tuple[float, float, float, float]   # X, Y, size, skew in [0, 1]
    label: str = ''                             # where it came from (file, frame, stamp)


def pattern_size(board: Board) -> tuple[int, int]:
    """Return the (columns, rows) the detector is asked for: the longer side first."""
    return max(board.cols, board.rows), min(board.cols, board.rows)


def to_gray(image: np.ndarray) -> np.ndarray:
    """Convert a BGR, BGRA or grey uint8 image to grey."""
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    return image


def find_corners(image: np.ndarray, board: Board, *, fast_check: bool = True
                 ) -> np.ndarray | None:
    """Find the board's inner corners in ``image`` (N, 2) [px], refined; ``None``: not found.

    ``fast_check``: OpenCV's quick rejection of images without a board, as the calibrator
    uses it; it also rejects a small board (squares some ten pixels wide), which the lidar
    calibration needs (a board far enough for the scan to cross it), so that turns it off.
    """
    gray = to_gray(image)
    h, w = gray.shape[:2]
    cols, rows = pattern_size(board)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    if fast_check:
        flags |= cv2.CALIB_CB_FAST_CHECK
    ok, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=flags)
    if not ok or corners is None:
        return None
    c = corners.reshape(-1, 2)
    if not np.all((c[:, 0] > BORDER) & (c[:, 0] < w - BORDER) & (c[:, 1] > BORDER)
                  & (c[:, 1] < h - BORDER)):
        return None
    if cols != rows:
        if c[0, 1] > c[-1, 1]:
            c = c[::-1].copy()
    else:
        down = (c[-1] - c[0]) >= 0
        if not np.all(down):
            grid = c.reshape(rows, cols, 2)
            if not np.any(down):
                c = c[::-1].copy()
            elif down[0]:
                c = np.rot90(grid).reshape(-1, 2).copy()
            else:
                c = np.rot90(grid, 3).reshape(-1, 2).copy()
    grid = c.reshape(rows, cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
                  np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    radius = max(1, int(math.ceil(spacing * REFINE_WINDOW)))
    refined = cv2.cornerSubPix(
        gray, np.ascontiguousarray(c.reshape(-1, 1, 2), dtype=np.float32), (radius, radius),
        (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1))
    return refined.reshape(-1, 2).astype(np.float64)


def outside_corners(corners: np.ndarray, board: Board) -> tuple[np.ndarray, ...]:
    """(up_left, up_right, down_right, down_left): the four outer inner corners."""
    cols, _ = pattern_size(board)
    c = np.asarray(corners, dtype=float).reshape(-1, 2)
    return c[0], c[cols - 1], c[-1], c[-cols]


def quad_area(quad: Sequence[np.ndarray]) -> float:
    """Area of a convex quadrilateral (up_left, up_right, down_right, down_left) [px^2]."""
    up_left, up_right, down_right, down_left = quad
    a = up_right - up_left
    b = down_right - up_right
    c = down_left - down_right
    p = b + c
    q = a + b
    return float(abs(p[0] * q[1] - p[1] * q[0]) / 2.0)


def skew(quad: Sequence[np.ndarray]) -> float:
    """How far the angle at up_right is from 90 degrees: min(1, 2 |pi/2 - angle|)."""
    up_left, up_right, down_right, _ = quad
    ab = up_left - up_right
    cb = down_right - up_right
    cos = float(np.dot(ab, cb) / (np.linalg.norm(ab) * np.linalg.norm(cb)))
    angle = math.acos(min(1.0, max(-1.0, cos)))
    return min(1.0, 2.0 * abs(math.pi / 2.0 - angle))


def view_params(corners: np.ndarray, board: Board, size: tuple[int, int]
                ) -> tuple[float, float, float, float]:
    """X, Y, size and skew of a view, each in [0, 1] (calibrator.py ``get_parameters``)."""
    width, height = size
    c = np.asarray(corners, dtype=float).reshape(-1, 2)
    quad = outside_corners(c, board)
    area = quad_area(quad)
    border = math.sqrt(area)
    # X and Y on an image shrunk by half the board all round: a large board cannot move far.
    p_x = min(1.0, max(0.0, (float(np.mean(c[:, 0])) - border / 2) / (width - border)))
    p_y = min(1.0, max(0.0, (float(np.mean(c[:, 1])) - border / 2) / (height - border)))
    p_size = math.sqrt(area / (width * height))
    return p_x, p_y, p_size, skew(quad)


def param_distance(a: Sequence[float], b: Sequence[float]) -> float:
    """Return the L1 distance between two views' numbers."""
    return sum(abs(x - y) for x, y in zip(a, b))


@dataclass(frozen=True)
class Progress:
    """Coverage of one number: the range the kept views span, and progress in [0, 1]."""

    name: str
    low: float
    high: float
    progress: float


@dataclass
class ViewSelector:
    """Keeps the views that differ enough from those kept; reports coverage as it goes."""

    board: Board
    size: tuple[int, int]          # (width, height) [px]
    views: list[View] = field(default_factory=list)
    seen: int = 0                  # images offered
    detected: int = 0              # of which the board was found in

    def offer(self, image: np.ndarray, label: str = '') -> View | None:
        """Detect the board in ``image``; return the view if it is kept."""
        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise CalibrationError(f'{label or "image"}: {w}x{h}, but the first image was '
                                   f'{self.size[0]}x{self.size[1]}')
        self.seen += 1
        corners = find_corners(image, self.board)
        if corners is None:
            return None
        self.detected += 1
        return self.offer_corners(corners, label)

    def offer_corners(self, corners: np.ndarray, label: str = '') -> View | None:
        """Keep detected ``corners`` if their view is new enough (``is_good_sample``)."""
        params = view_params(corners, self.board, self.size)
        if self.views and min(param_distance(params, v.params) for v in self.views) \
                <= MIN_DISTANCE:
            return None
        view = View(corners, params, label)
        self.views.append(view)
        return view

    def progress(self) -> list[Progress]:
        """Coverage of X, Y, size and skew (``compute_goodenough``); empty with no view."""
        return coverage([v.params for v in self.views])

    @property
    def good_enough(self) -> bool:
        """Enough views to calibrate: every number covered, or ``ENOUGH_VIEWS`` kept."""
        return good_enough([v.params for v in self.views])


def coverage(params: Sequence[Sequence[float]]) -> list[Progress]:
    """Coverage of X, Y, size and skew by the views' numbers (``compute_goodenough``)."""
    if not params:
        return []
    lo = [min(p[i] for p in params) for i in range(4)]
    hi = [max(p[i] for p in params) for i in range(4)]
    lo[2] = lo[3] = 0.0   # small size and no skew are not rewarded
    return [Progress(name, lo[i], hi[i], min((hi[i] - lo[i]) / PARAM_RANGES[i], 1.0))
            for i, name in enumerate(PARAM_NAMES)]


def good_enough(params: Sequence[Sequence[float]]) -> bool:
    """Whether views with these numbers may be calibrated (``compute_goodenough``)."""
    return bool(params) and (len(params) >= ENOUGH_VIEWS
                             or all(p.progress == 1.0 for p in coverage(params)))


def format_progress(progress: Iterable[Progress]) -> str:
    """One line: ``X 0.53 Y 1.00 Size 0.41 Skew 0.12``."""
    return ' '.join(f'{p.name} {p.progress:.2f}' for p in progress)


@dataclass(frozen=True)
class Intrinsics:
    """A monocular calibration: sensor_msgs/CameraInfo's K, D, R, P and the RMS error."""

    width: int
    height: int
    k: np.ndarray          # 3x3
    d: np.ndarray          # 5: k1, k2, p1, p2, k3 (plumb_bob)
    r: np.ndarray          # 3x3, the identity
    p: np.ndarray          # 3x4
    rms: float             # reprojection error [px]
    views: int

    @property
    def distortion_model(self) -> str:
        """Always plumb_bob (five coefficients)."""
        return 'plumb_bob'


def calibration_flags(k_coefficients: int) -> int:
    """Return calibrateCamera flags for ``k_coefficients`` radial terms of plumb_bob (1-3)."""
    if not 1 <= k_coefficients <= 3:
        raise CalibrationError(f'plumb_bob has 1 to 3 radial coefficients, got '
                               f'{k_coefficients}')
    flags = cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6
    if k_coefficients < 3:
        flags |= cv2.CALIB_FIX_K3
    if k_coefficients < 2:
        flags |= cv2.CALIB_FIX_K2
    return flags


def calibrate(views: Sequence[View], board: Board, size: tuple[int, int],
              k_coefficients: int = 2) -> Intrinsics:
    """Calibrate from the kept views (``cal_fromcorners`` + ``set_alpha(0.0)``)."""
    if len(views) < 3:
        raise CalibrationError(f'{len(views)} view(s) of the board: at least 3 are needed '
                               '(better 20 or more, covering the image)')
    cols, rows = pattern_size(board)
    obj = Board(cols, rows, board.square).object_points().astype(np.float32)
    object_points = [obj for _ in views]
    image_points = [np.ascontiguousarray(v.corners, dtype=np.float32).reshape(-1, 1, 2)
                    for v in views]
    try:
        rms, k, d, _, _ = cv2.calibrateCamera(
            object_points, image_points, size, np.eye(3), None,
            flags=calibration_flags(k_coefficients))
    except cv2.error as err:
        raise CalibrationError(f'OpenCV could not calibrate: {err}') from err
    d = np.asarray(d, dtype=float).ravel()[:5]
    new_k, _ = cv2.getOptimalNewCameraMatrix(k, d, size, 0.0)
    p = np.zeros((3, 4))
    p[:, :3] = new_k
    return Intrinsics(width=size[0], height=size[1], k=np.asarray(k, dtype=float), d=d,
                      r=np.eye(3), p=p, rms=float(rms), views=len(views))
