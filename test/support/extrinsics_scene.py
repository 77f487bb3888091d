"""Synthetic camera and 2D lidar data with a known transform, computed here and nowhere else.

The geometry is written out in this file (ray-plane intersections, OpenCV's projection with
distortion), not taken from the code under test. Figures typed from the CS Saucer manual:
the RPLidar A1 (Table 1.1: 1 deg angular resolution, range noise 1 % below 3 m, 2 % from 3 to
5 m, 2.5 % beyond, read as one standard deviation), the checkerboard of section 4.1 (9 x 7
squares of 40 mm, so 8 x 6 inner corners, on A3 paper, 420 x 297 mm), the camera looking
ahead from a rod behind and above the lidar (section 1.5).
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from enbarr_core.framework.frames import Transform

# The manual's figures (typed, not read from the code under test).
ANGLE_STEP_DEG = 1.0                       # Table 1.1: angular resolution
NOISE_LIMITS = (3.0, 5.0)                  # Table 1.1 [m]
NOISE_FRACTIONS = (0.01, 0.02, 0.025)      # Table 1.1
BOARD_COLS, BOARD_ROWS, SQUARE = 8, 6, 0.040   # section 4.1: 9 x 7 squares of 40 mm
PAPER_W, PAPER_H = 0.420, 0.297            # A3 [m]

# A 640 x 480 camera (the saucer profile's size) with a wide lens's barrel distortion.
WIDTH, HEIGHT = 640, 480
K = np.array([[520.0, 0.0, 322.0], [0.0, 518.0, 236.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.09, 0.001, -0.0005, -0.01])

#: The laser frame's axes in the optical frame (x ahead -> z, y left -> -x, z up -> -y).
R_NOMINAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def range_sigma(r: np.ndarray) -> np.ndarray:
    """The manual's range noise (one standard deviation) [m] at ranges ``r`` [m]."""
    frac = np.where(r < NOISE_LIMITS[0], NOISE_FRACTIONS[0],
                    np.where(r <= NOISE_LIMITS[1], NOISE_FRACTIONS[1], NOISE_FRACTIONS[2]))
    return frac * r


def true_transform(rot_deg: tuple[float, float, float] = (1.5, -2.0, 1.0),
                   offset: tuple[float, float, float] = (0.012, -0.008, 0.015)) -> Transform:
    """T_optical_laser: the lidar 8 cm ahead of and 10 cm below the camera, then perturbed."""
    R = Rotation.from_rotvec(np.radians(rot_deg)).as_matrix() @ R_NOMINAL
    t = np.array([0.0, 0.10, 0.08]) + np.asarray(offset)
    q = Rotation.from_matrix(R).as_quat()
    return Transform(tuple(t), tuple(q))  # type: ignore[arg-type]


def board_points() -> np.ndarray:
    """Inner corners in the board frame, row by row (findChessboardCorners' order)."""
    g = np.mgrid[0:BOARD_COLS, 0:BOARD_ROWS].T.reshape(-1, 2) * SQUARE
    return np.column_stack([g, np.zeros(len(g))])


#: The paper in the board frame (x_min, x_max, y_min, y_max): the pattern centred on A3.
_CX, _CY = (BOARD_COLS - 1) * SQUARE / 2, (BOARD_ROWS - 1) * SQUARE / 2
EXTENT = (_CX - PAPER_W / 2, _CX + PAPER_W / 2, _CY - PAPER_H / 2, _CY + PAPER_H / 2)


@dataclass
class BoardPose:
    rotation: np.ndarray      # board -> optical
    translation: np.ndarray   # board origin in optical [m]
    corners: np.ndarray       # (48, 2) observed pixels
    scans: list[np.ndarray]   # per revolution: (360, 2) ranges' points in laser, inf = none
    on_board: list[np.ndarray]   # per revolution: which rays hit the board
    ranges: list[tuple[float, np.ndarray]]   # per revolution: (angle_min, ranges) [rad, m]


def _rays(phase: float) -> np.ndarray:
    return np.radians(np.arange(0.0, 360.0, ANGLE_STEP_DEG) + phase)


def scan_board(T: Transform, R_cb: np.ndarray, t_cb: np.ndarray, rng: np.random.Generator,
               wall: float = 4.5) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """One revolution: points (360, 2) in the laser frame, which hit the board, and the
    revolution as a LaserScan has it (angle_min [rad], ranges [m]).

    Rays that miss the board hit a wall ``wall`` m ahead (x = wall) or are lost (inf).
    """
    theta = _rays(rng.uniform(0.0, ANGLE_STEP_DEG))
    u_l = np.column_stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)])
    R = np.asarray(T.rotation_matrix)
    o_c = np.asarray(T.translation)
    u_c = u_l @ R.T
    n = R_cb[:, 2]
    d = n @ t_cb
    denom = u_c @ n
    with np.errstate(divide='ignore', invalid='ignore'):
        s = (d - n @ o_c) / denom
    p_c = o_c + s[:, None] * u_c
    b = (p_c - t_cb) @ R_cb
    hit = ((s > 0.1) & np.isfinite(s) & (b[:, 0] >= EXTENT[0]) & (b[:, 0] <= EXTENT[1])
           & (b[:, 1] >= EXTENT[2]) & (b[:, 1] <= EXTENT[3]))
    with np.errstate(divide='ignore', invalid='ignore'):
        s_wall = np.where(u_l[:, 0] > 0.05, wall / u_l[:, 0], np.inf)
    r = np.where(hit, s, np.where(s_wall < 12.0, s_wall, np.inf))
    fin = np.isfinite(r)
    r[fin] += rng.normal(0.0, range_sigma(r[fin]))
    with np.errstate(invalid='ignore'):
        pts = np.column_stack([r * np.cos(theta), r * np.sin(theta)])
    return pts, hit, float(theta[0]), r


def board_poses(T: Transform, n: int, rng: np.random.Generator, *, scans: int = 10,
                pixel_noise: float = 0.2, tilt_deg: float = 35.0, near: float = 0.8,
                far: float = 2.0, parallel: bool = False,
                one_axis: bool = False) -> list[BoardPose]:
    """``n`` board poses seen by the camera and crossed by the scan plane.

    The board's centre is ``near`` to ``far`` m ahead at the lidar's height (+-4 cm), within
    the camera's view; it faces the camera, turned up to ``tilt_deg`` about each axis (none:
    ``parallel``; only about the camera's vertical axis: ``one_axis``). ``scans`` revolutions
    per pose (the board is held still).
    """
    out: list[BoardPose] = []
    centre_b = np.array([_CX, _CY, 0.0])
    obj = board_points()
    while len(out) < n:
        dist = rng.uniform(near, far)
        bearing = math.radians(rng.uniform(-20.0, 20.0))
        c_l = np.array([dist * math.cos(bearing), dist * math.sin(bearing),
                        rng.uniform(-0.04, 0.04)])
        c_c = T.apply(c_l)
        tilt = np.zeros(3) if parallel else np.radians(rng.uniform(-tilt_deg, tilt_deg, 3))
        tilt[2] *= 0.5   # roll in the board's own plane matters less
        if one_axis:
            tilt[0] = tilt[2] = 0.0
        R_cb = Rotation.from_rotvec(tilt).as_matrix()
        t_cb = c_c - R_cb @ centre_b
        rvec = cv2.Rodrigues(R_cb)[0]
        px, _ = cv2.projectPoints(obj, rvec, t_cb, K, DIST)
        px = px.reshape(-1, 2)
        if (px[:, 0].min() < 5 or px[:, 0].max() > WIDTH - 5 or px[:, 1].min() < 5
                or px[:, 1].max() > HEIGHT - 5):
            continue
        px = px + rng.normal(0.0, pixel_noise, px.shape)
        revs = [scan_board(T, R_cb, t_cb, rng) for _ in range(scans)]
        if min(int(rev[1].sum()) for rev in revs) < 3:
            continue
        out.append(BoardPose(R_cb, t_cb, px, [rev[0] for rev in revs], [rev[1] for rev in revs],
                             [(rev[2], rev[3]) for rev in revs]))
    return out


def marks(T: Transform, n: int, rng: np.random.Generator, *, click_px: float = 1.0,
          quantize: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The manual's tape marks: ``n`` corners at the lidar's height, 1 to 5 m ahead.

    Returns (lidar points (n, 2) as picked, pixels (n, 2) as clicked, true points (n, 2)).
    The picked lidar point is the nearest ray's (within half the angular step, ``quantize``)
    with the range noise; the click is off by ``click_px`` (one standard deviation).
    """
    pts, px_all = [], []
    while len(pts) < n:
        r = rng.uniform(1.0, 5.0)
        b = math.radians(rng.uniform(-26.0, 26.0))
        p = np.array([r * math.cos(b), r * math.sin(b), 0.0])
        px, _ = cv2.projectPoints(T.apply(p)[None, :], np.zeros(3), np.zeros(3), K, DIST)
        px = px.reshape(2)
        if not (0 <= px[0] < WIDTH and 0 <= px[1] < HEIGHT):
            continue
        pts.append(p[:2])
        px_all.append(px + rng.normal(0.0, click_px, 2))
    true = np.array(pts)
    r = np.linalg.norm(true, axis=1)
    b = np.arctan2(true[:, 1], true[:, 0])
    if quantize:
        b = b + np.radians(rng.uniform(-ANGLE_STEP_DEG / 2, ANGLE_STEP_DEG / 2, n))
    r = r + rng.normal(0.0, range_sigma(r))
    picked = np.column_stack([r * np.cos(b), r * np.sin(b)])
    return picked, np.array(px_all), true


def rotation_error_deg(a: Transform, b: Transform) -> float:
    """The angle [deg] of the rotation between two transforms' rotations."""
    ra = Rotation.from_quat(a.rotation)
    rb = Rotation.from_quat(b.rotation)
    return float(np.degrees((ra.inv() * rb).magnitude()))


def translation_error(a: Transform, b: Transform) -> float:
    """The distance [m] between two transforms' translations."""
    return float(np.linalg.norm(np.subtract(a.translation, b.translation)))


@functools.lru_cache(maxsize=2)
def _pixel_rays(s: int) -> np.ndarray:
    """The optical-frame ray (x, y, 1) of each of ``s`` x ``s`` points per pixel (row-major)."""
    off = (np.arange(s) + 0.5) / s - 0.5
    u = np.tile(np.repeat(np.arange(WIDTH), s) + np.tile(off, WIDTH), (HEIGHT * s, 1))
    v = np.tile((np.repeat(np.arange(HEIGHT), s) + np.tile(off, HEIGHT))[:, None],
                (1, WIDTH * s))
    pix = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    rays = cv2.undistortPoints(pix.reshape(-1, 1, 2), K, DIST, criteria=(
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9)).reshape(-1, 2)
    return np.column_stack([rays, np.ones(len(rays))])


def render_board(R_cb: np.ndarray | None, t_cb: np.ndarray | None,
                 supersample: int = 2) -> np.ndarray:
    """A BGR image of the board (9 x 7 squares on white A3) seen through the camera.

    Every pixel's ray (undistorted with the camera's K and distortion) is cut with the board's
    plane; its point on the board is black or white by the squares, white on the paper's
    margin, grey beyond. ``supersample`` rays per pixel side smooth the edges. None: no board.
    """
    s = supersample
    if R_cb is None or t_cb is None:
        return np.full((HEIGHT, WIDTH, 3), 128, np.uint8)
    rays = _pixel_rays(s)
    n = R_cb[:, 2]
    depth = (n @ t_cb) / (rays @ n)
    b = (rays * depth[:, None] - t_cb) @ R_cb
    i = np.floor(b[:, 0] / SQUARE).astype(int) + 1
    j = np.floor(b[:, 1] / SQUARE).astype(int) + 1
    in_squares = (i >= 0) & (i <= BOARD_COLS) & (j >= 0) & (j <= BOARD_ROWS)
    on_paper = ((b[:, 0] >= EXTENT[0]) & (b[:, 0] <= EXTENT[1]) & (b[:, 1] >= EXTENT[2])
                & (b[:, 1] <= EXTENT[3]) & (depth > 0))
    gray = np.where(on_paper, 255.0, 128.0)
    gray = np.where(on_paper & in_squares & ((i + j) % 2 == 0), 0.0, gray)
    img = gray.reshape(HEIGHT, s, WIDTH, s).mean(axis=(1, 3))
    return np.repeat(img.round().astype(np.uint8)[:, :, None], 3, axis=2)
