"""Camera to 2D lidar extrinsics: where the lidar sits in the camera's optical frame.

The result is T_optical_laser (``frames.Transform``): it maps a point of the lidar's frame
(REP-103: x forward, y left, z up; a 2D scan lies in z = 0) into the camera's optical frame
(REP-103: z ahead, x right, y down): p_c = R p_l + t. It is the rotation and translation the
CS Saucer manual's tool (section 4.2, after ehong-tl's camera_2d_lidar_calibration, which
hands the same lidar-to-camera R, t to its reprojection) reports, and OpenCV's ``rvec, tvec``.

Two methods:

- ``solve_pnp``, the manual's: lidar points on marks at the lidar's height (tape on corners)
  paired with the pixels where the marks are seen; a perspective-n-point problem with known
  intrinsics. A 2D lidar's points are coplanar (z = 0), so this is the pose of a planar
  target: at least 4 pairs, no three of them on a line in practice and never all on one line
  (a wall), because a plane's image is a homography (8 degrees of freedom, 2 per pair). And the
  camera sits a few centimetres above the scan plane, so it sees that plane almost edge on:
  the marks fill a thin band of image rows, and a pixel of vertical error moves the solution
  far. ``docs/calibration_lidar.md`` gives what it achieves with N pairs.
- ``solve_planes``, Zhang and Pless (2004), "Extrinsic calibration of a camera and laser range
  finder", IROS: each pose of a checkerboard gives its plane in the camera frame (PnP on its
  corners, ``board_plane``), n . p_c = d, and the lidar points that hit the board must lie on
  it: n . (R p_l + t) = d. Linear in H = [r1 r2 t] (p_l has z = 0), so a least-squares
  start from at least 5 poses, then Gauss-Newton on the point-to-plane distances. No picking
  by hand; the scan points on a board are found from a rough transform
  (``select_board_points``).

Pure numpy, OpenCV and scipy; no ROS. Errors are ``CalibrationError`` saying what to change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
# mypy 2.4 takes scipy 1.17's least_squares for the submodule of the same name (its calls carry
# an ignore); the function is scipy's public API.
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.framework.frames import FrameTree, Transform
from enbarr_core.perception.scan_geometry import RangeNoise
from enbarr_core.vision.board import Board
from enbarr_core.vision.camera import PinholeCamera

Array = NDArray[np.float64]

#: A plane's image is a homography: 8 degrees of freedom, 2 equations per pair; OpenCV's
#: planar solver (IPPE) needs 4 points as well.
MIN_PNP_PAIRS = 4
#: The linear start of ``solve_planes``: 9 unknowns (H = [r1 r2 t]), and a scan line on a
#: board gives 2 independent equations; with an initial transform 3 poses do.
MIN_PLANES_LINEAR = 5
MIN_PLANES = 3
#: Points per board: a line needs 2.
MIN_POINTS_PER_BOARD = 2
#: The marks of ``solve_pnp`` are refused as collinear when their spread across the best line is
#: below this share of their spread along it (a corridor wall seen from its middle).
COLLINEAR_RATIO = 0.02
#: Board normals must not lie in one plane (all boards tilted about one axis) or along one
#: line (all parallel): the smallest eigenvalue of mean(n n^T) must exceed this (about a 3 deg
#: spread; then t along the missing direction and a rotation are left free).
MIN_NORMAL_SPREAD = 1.5e-3


class CameraModel(PinholeCamera):
    """The camera of a lidar calibration: a ``PinholeCamera`` built with ``of``.

    ``of`` takes K and D as arrays and refuses what it cannot use with a ``CalibrationError``.
    """

    @classmethod
    def of(cls, K: ArrayLike, dist: ArrayLike = (), width: int = 0, height: int = 0,
           distortion_model: str = 'plumb_bob') -> CameraModel:
        """Build from a 3x3 (or 9 numbers) ``K`` and distortion ``dist``; checks shapes."""
        k = np.asarray(K, dtype=float).reshape(3, 3)
        d = np.asarray(dist, dtype=float).ravel()
        if not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise CalibrationError(f'camera matrix K: expected positive focal lengths, got '
                                   f'{k.tolist()}')
        if d.size not in (0, 4, 5, 8, 12, 14):
            raise CalibrationError(f'distortion: expected 4, 5, 8, 12 or 14 coefficients '
                                   f'(plumb_bob: 5), got {d.size}')
        return cls(int(width), int(height), tuple(float(x) for x in k.ravel()),
                   tuple(float(x) for x in d) if d.size else (0.0,) * 5, distortion_model)


@dataclass(frozen=True, eq=False)
class ExtrinsicsResult:
    """A solved T_optical_laser and how well it fits.

    ``residuals``: per pair the pixel error [px] (``pnp``), per lidar point the signed distance
    to its board's plane [m] (``planes``). ``rms`` in the same unit; ``used`` marks the pairs or
    points kept (``pnp`` drops outliers). ``sigma_rotation`` [rad] and ``sigma_translation`` [m]
    are one standard deviation from the fit's Jacobian (the rotation as a small rotation vector
    in the optical frame): what the noise of these data leaves, not systematic errors.
    """

    transform: Transform
    method: str               # 'pnp' or 'planes'
    rms: float
    unit: str                 # 'px' or 'm'
    residuals: Array
    used: NDArray[np.bool_]
    sigma_rotation: Array     # (3,) [rad]
    sigma_translation: Array  # (3,) [m]
    per_board_rms: tuple[float, ...] = ()   # [m], ``planes`` only

    def summary(self) -> str:
        """Return a few lines: the transform, the fit and its uncertainty, for a terminal."""
        t = self.transform
        # as a quaternion: the laser's axes are about 90 deg from the optical frame's, where
        # roll-pitch-yaw are near their singularity (the camera_link pose reads better)
        lines = [
            f'T_optical_laser ({self.method}): xyz [m] '
            f'{_fmt(t.translation, 4)}, quaternion [x, y, z, w] {_fmt(t.rotation, 5)}',
            f'  rms {self.rms:.4g} {self.unit} over {int(self.used.sum())} of '
            f'{len(self.used)} {"pairs" if self.method == "pnp" else "points"}',
            f'  1-sigma: rotation [deg] {_fmt(np.degrees(self.sigma_rotation), 3)}, '
            f'translation [m] {_fmt(self.sigma_translation, 4)}',
        ]
        if self.per_board_rms:
            lines.append('  per board rms [mm]: '
                         + ' '.join(f'{1000 * r:.1f}' for r in self.per_board_rms))
        return '\n'.join(lines)


def _fmt(v: ArrayLike, digits: int) -> str:
    return '[' + ', '.join(f'{x:.{digits}f}' for x in np.asarray(v, dtype=float)) + ']'


def _transform(rvec: ArrayLike, tvec: ArrayLike) -> Transform:
    q = Rotation.from_rotvec(np.asarray(rvec, dtype=float).ravel()).as_quat()
    t = np.asarray(tvec, dtype=float).ravel()
    return Transform((float(t[0]), float(t[1]), float(t[2])),
                     (float(q[0]), float(q[1]), float(q[2]), float(q[3])))


def _rvec(transform: Transform) -> Array:
    out: Array = Rotation.from_quat(transform.rotation).as_rotvec()
    return out


def _sigmas(jac: Array, residuals: Array) -> tuple[Array, Array]:
    """One standard deviation of [rvec, t] from J and the residuals: s^2 (J^T J)^-1."""
    dof = max(len(residuals) - 6, 1)
    s2 = float(residuals @ residuals) / dof
    try:
        cov = s2 * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.full(3, np.inf), np.full(3, np.inf)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return sd[:3], sd[3:]


def _as_points(values: ArrayLike, cols: int, what: str) -> Array:
    a = np.asarray(values, dtype=float)
    if a.ndim != 2 or a.shape[1] != cols:
        raise CalibrationError(f'{what}: expected an (N, {cols}) array, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f'{what}: not all finite')
    return a


# -- (a) the manual's method: marks seen by both ---------------------------------------------
def solve_pnp(laser_xy: ArrayLike, pixels: ArrayLike, camera: CameraModel, *,
              outlier_px: float = 8.0) -> ExtrinsicsResult:
    """T_optical_laser from lidar points (N, 2) [m] and their pixels (N, 2) [px].

    Planar PnP (IPPE: both of a plane's candidate poses, the better kept), refined by
    Levenberg-Marquardt; then, while the worst pair is off by more than ``outlier_px`` and more
    than ``MIN_PNP_PAIRS`` pairs remain, that pair is dropped and the rest solved again (a
    mis-click must not pull the rest). ``CalibrationError`` for fewer than 4 pairs, marks on
    one line, or a solution that puts the marks behind the camera.
    """
    xy = _as_points(laser_xy, 2, 'lidar points')
    uv = _as_points(pixels, 2, 'pixels')
    if len(xy) != len(uv):
        raise CalibrationError(f'{len(xy)} lidar points but {len(uv)} pixels: one pixel per '
                               'point')
    if len(xy) < MIN_PNP_PAIRS:
        raise CalibrationError(
            f'{len(xy)} pairs: the lidar points are coplanar (a 2D scan), so PnP needs at least '
            f"{MIN_PNP_PAIRS} (a plane's image has 8 degrees of freedom, 2 per pair); the "
            'manual suggests 10 to 20')
    centred = xy - xy.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] <= 0.0 or s[1] / s[0] < COLLINEAR_RATIO:
        raise CalibrationError(
            'the lidar points lie on one line (one wall?): a planar PnP cannot tell the tilt '
            'about that line; mark corners at different depths and bearings')
    used = np.ones(len(xy), dtype=bool)
    while True:
        rvec, tvec = _pnp_once(xy[used], uv[used], camera)
        res = _pixel_errors(xy, uv, rvec, tvec, camera)
        worst = int(np.argmax(np.where(used, res, -1.0)))
        if res[worst] <= outlier_px or used.sum() <= MIN_PNP_PAIRS:
            break
        used[worst] = False
    obj = _laser3(xy[used])
    depth = (obj @ cv2.Rodrigues(rvec)[0].T + tvec.ravel())[:, 2]
    if np.any(depth <= 0.0):
        raise CalibrationError('the solution puts marks behind the camera: check that each '
                               'pixel belongs to its lidar point (the order of the pairs)')
    px, jac = cv2.projectPoints(obj, rvec, tvec, camera.matrix, camera.dist_coeffs)
    r_used = (px.reshape(-1, 2) - uv[used]).ravel()
    sig_r, sig_t = _sigmas(np.asarray(jac, dtype=np.float64)[:, :6], r_used)
    return ExtrinsicsResult(
        _transform(rvec, tvec), 'pnp', float(np.sqrt(np.mean(res[used] ** 2))), 'px',
        res, used, sig_r, sig_t)


def _laser3(xy: Array) -> Array:
    return np.column_stack([xy, np.zeros(len(xy))])


def _pnp_once(xy: Array, uv: Array, camera: CameraModel) -> tuple[Array, Array]:
    obj = _laser3(xy)
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, uv, camera.matrix, camera.dist_coeffs,
                                              flags=cv2.SOLVEPNP_IPPE)
    if not ok or not len(rvecs):
        raise CalibrationError('PnP found no pose for these pairs')
    best: tuple[float, Array, Array] | None = None
    for rv0, tv0 in zip(rvecs, tvecs):
        refined = cv2.solvePnPRefineLM(obj, uv, camera.matrix, camera.dist_coeffs, rv0.copy(),
                                       tv0.copy())
        rv: Array = np.asarray(refined[0], dtype=np.float64)
        tv: Array = np.asarray(refined[1], dtype=np.float64)
        err = float(np.sum(_pixel_errors(xy, uv, rv, tv, camera) ** 2))
        if best is None or err < best[0]:
            best = (err, rv, tv)
    assert best is not None
    return best[1], best[2]


def _pixel_errors(xy: Array, uv: Array, rvec: Array, tvec: Array,
                  camera: CameraModel) -> Array:
    px, _ = cv2.projectPoints(_laser3(xy), rvec, tvec, camera.matrix, camera.dist_coeffs)
    out: Array = np.linalg.norm(np.asarray(px).reshape(-1, 2) - uv, axis=1)
    return out


# -- (b) Zhang and Pless: checkerboard planes ----------------------------------------------------
@dataclass(frozen=True, eq=False)
class BoardPlane:
    """A board's pose in the optical frame and its plane n . p = d (n unit, d > 0 [m])."""

    rotation: Array      # 3x3: board frame -> optical frame
    translation: Array   # (3,) [m]: the board frame's origin (its first inner corner)
    normal: Array        # (3,) unit, pointing away from the camera
    distance: float      # [m]
    rms_px: float        # the corners' reprojection error
    corners: Array | None = None         # (M, 2) [px]: what the pose was solved from, which
    object_points: Array | None = None   # (M, 3) [m]  ``solve_planes`` refines it with

    def in_board(self, points_c: Array) -> Array:
        """Points (N, 3) of the optical frame in the board's frame."""
        out: Array = (points_c - self.translation) @ self.rotation
        return out


def board_object_points(cols: int, rows: int, square: float) -> Array:
    """Return the inner corners of a ``cols`` x ``rows`` (inner corners) board [m].

    Row by row as ``cv2.findChessboardCorners`` orders them: x along a row, y down the rows,
    z = 0 on the board.
    """
    try:
        board = Board(cols, rows, float(square))
    except ValueError as err:
        raise CalibrationError(f'board: {cols}x{rows} inner corners of {square} m: expected '
                               'at least 2x2 and a positive square size') from err
    out: Array = board.object_points()
    return out


def board_plane(corners_px: ArrayLike, object_points: ArrayLike,
                camera: CameraModel) -> BoardPlane:
    """Solve the board's plane in the optical frame from its corners' pixels (PnP)."""
    uv = _as_points(np.asarray(corners_px, dtype=float).reshape(-1, 2), 2, 'corners')
    obj = _as_points(object_points, 3, 'board points')
    if len(uv) != len(obj) or len(uv) < MIN_PNP_PAIRS:
        raise CalibrationError(f'{len(uv)} corners for {len(obj)} board points: expected as '
                               f'many, and at least {MIN_PNP_PAIRS}')
    ok, rvec, tvec = cv2.solvePnP(obj, uv, camera.matrix, camera.dist_coeffs,
                                  flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("PnP found no pose for the board's corners")
    rvec, tvec = cv2.solvePnPRefineLM(obj, uv, camera.matrix, camera.dist_coeffs, rvec, tvec)
    return _plane_of_pose(np.asarray(rvec, dtype=np.float64).ravel(),
                          np.asarray(tvec, dtype=np.float64).ravel(), uv, obj, camera)


def _plane_of_pose(rvec: Array, t: Array, uv: Array, obj: Array,
                   camera: CameraModel) -> BoardPlane:
    """Return the board's plane from its pose (rvec, t) and how well its corners fit."""
    R: Array = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
    n = R[:, 2].copy()
    d = float(n @ t)
    if d < 0.0:
        n, d = -n, -d
    px, _ = cv2.projectPoints(obj, rvec, t, camera.matrix, camera.dist_coeffs)
    rms = float(np.sqrt(np.mean(np.sum((np.asarray(px).reshape(-1, 2) - uv) ** 2, axis=1))))
    return BoardPlane(R, t, n, d, rms, uv, obj)


def select_board_points(laser_xy: ArrayLike, plane: BoardPlane, guess: Transform,
                        extent: tuple[float, float, float, float], *,
                        tolerance: float = 0.1) -> NDArray[np.bool_]:
    """Which scan points (N, 2) [m] hit the board, given a rough T_optical_laser ``guess``.

    A point is kept when, moved into the optical frame by ``guess``, it lies within
    ``tolerance`` [m] of the board's plane and inside ``extent`` = (x_min, x_max, y_min, y_max)
    of the board's frame [m] (the physical board: the inner corners' span and the margin to the
    board's edges) widened by ``tolerance``; then only the longest run of neighbouring rays is
    kept, so a wall behind the board's edge does not join. The guess is the profile's frame
    tree: a few centimetres and degrees off are within the default tolerance.
    """
    xy = _as_points(laser_xy, 2, 'scan points')
    pc = guess.apply(_laser3(xy))
    off = pc @ plane.normal - plane.distance
    b = plane.in_board(pc)
    x0, x1, y0, y1 = extent
    inside = ((np.abs(off) <= tolerance) & (b[:, 0] >= x0 - tolerance)
              & (b[:, 0] <= x1 + tolerance) & (b[:, 1] >= y0 - tolerance)
              & (b[:, 1] <= y1 + tolerance))
    out = np.zeros(len(xy), dtype=bool)
    if inside.all() or not inside.any():
        return inside
    # The scan is a ring: start the search after a miss, so a board across the scan's first
    # ray (angle_min at the bow) is one run.
    shift = int(np.argmin(inside))
    ring = np.roll(inside, -shift)
    best_start, best_len, start = 0, 0, -1
    for i, k in enumerate([*ring.tolist(), False]):
        if k and start < 0:
            start = i
        elif not k and start >= 0:
            if i - start > best_len:
                best_start, best_len = start, i - start
            start = -1
    out[(np.arange(best_start, best_start + best_len) + shift) % len(xy)] = True
    return out


def solve_planes(planes: Sequence[BoardPlane], laser_points: Sequence[ArrayLike], *,
                 initial: Transform | None = None, camera: CameraModel | None = None,
                 range_noise: RangeNoise | None = None) -> ExtrinsicsResult:
    """T_optical_laser from board planes and the lidar points (each (N_i, 2) [m]) on them.

    The linear estimate (least squares in H = [r1 r2 t], projected onto a rotation) starts the
    refinement unless ``initial`` is given; scipy's least squares then minimises the
    point-to-plane distances with the board planes fixed. With ``camera`` (and the boards'
    corners, as ``board_plane`` keeps them) a last step refines the board poses together with
    the transform, maximum likelihood: the corners' pixel errors over their scatter, and each
    lidar point's range error (the range to its board's plane along its ray minus the range
    measured) over ``range_noise`` (the lidar's figures; None: one scatter for all, estimated).
    The boards' planes carry most of the error of this method, so letting the lidar points and
    the corners share it helps. ``CalibrationError`` for fewer than 3 boards (5 without
    ``initial``), a board with fewer than 2 lidar points, or boards whose normals do not span
    space (all parallel, or all tilted about one axis).
    """
    if len(planes) != len(laser_points):
        raise CalibrationError(f'{len(planes)} boards but {len(laser_points)} point sets')
    if len(planes) < MIN_PLANES:
        raise CalibrationError(f'{len(planes)} board poses: at least {MIN_PLANES} are needed '
                               f'({MIN_PLANES_LINEAR} without an initial transform); 10 to 20 '
                               'are better')
    pts = []
    for i, p in enumerate(laser_points):
        a = np.asarray(p, dtype=float).reshape(-1, 2)
        if len(a) < MIN_POINTS_PER_BOARD:
            raise CalibrationError(
                f'board {i}: {len(a)} lidar points on it: the scan plane must cross the board '
                "(hold it at the lidar's height); drop that pose or move the board")
        pts.append(_as_points(a, 2, f'board {i}: lidar points'))
    normals = np.array([p.normal for p in planes])
    ev = np.linalg.eigvalsh(normals.T @ normals / len(normals))
    if ev[0] < MIN_NORMAL_SPREAD:
        what = ('all boards are parallel' if ev[1] < MIN_NORMAL_SPREAD else
                'all boards are tilted about one axis')
        raise CalibrationError(
            f'{what} (their normals spread {math.degrees(math.sqrt(2 * max(ev[0], 0))):.1f} '
            'deg across): part of the transform is then unobservable; tilt the board left and '
            'right and up and down between poses')
    n_of = np.concatenate([np.repeat(p.normal[None, :], len(a), axis=0)
                           for p, a in zip(planes, pts)])
    d_of = np.concatenate([np.full(len(a), p.distance) for p, a in zip(planes, pts)])
    board_of = np.concatenate([np.full(len(a), i) for i, a in enumerate(pts)])
    xy = np.concatenate(pts)
    if initial is None:
        if len(planes) < MIN_PLANES_LINEAR:
            raise CalibrationError(
                f'{len(planes)} board poses: the linear start needs {MIN_PLANES_LINEAR} (each '
                'gives 2 equations for 9 unknowns); give more poses or an initial transform')
        initial = _linear_planes(xy, n_of, d_of)
    p3 = _laser3(xy)

    def residuals(x: Array) -> Array:
        R = Rotation.from_rotvec(x[:3]).as_matrix()
        out: Array = np.sum(n_of * (p3 @ R.T + x[3:]), axis=1) - d_of
        return out

    x0 = np.concatenate([_rvec(initial), initial.translation])
    sol = least_squares(residuals, x0, method='lm', x_scale='jac')  # type: ignore[operator]
    x = np.asarray(sol.x, dtype=float)
    res = residuals(x)
    sig_r, sig_t = _sigmas(np.asarray(sol.jac), res)
    if camera is not None and all(p.corners is not None for p in planes):
        x, planes, sig_r, sig_t = _joint(x, planes, pts, camera, range_noise,
                                         float(np.sqrt(np.mean(res ** 2))))
        # the residuals reported: the points to the refined planes
        n_of = np.concatenate([np.repeat(p.normal[None, :], len(a), axis=0)
                               for p, a in zip(planes, pts)])
        d_of = np.concatenate([np.full(len(a), p.distance) for p, a in zip(planes, pts)])
        res = residuals(x)
    per_board = tuple(float(np.sqrt(np.mean(res[board_of == i] ** 2)))
                      for i in range(len(planes)))
    return ExtrinsicsResult(
        _transform(x[:3], x[3:]), 'planes', float(np.sqrt(np.mean(res ** 2))), 'm',
        res, np.ones(len(res), dtype=bool), sig_r, sig_t, per_board)


def _joint(x0: Array, planes: Sequence[BoardPlane], pts: Sequence[Array], camera: CameraModel,
           range_noise: RangeNoise | None, plane_rms: float
           ) -> tuple[Array, list[BoardPlane], Array, Array]:
    """Refine [rvec, t] and every board pose together (see ``solve_planes``)."""
    B = len(planes)
    corners = [np.asarray(p.corners) for p in planes]
    objs = [np.asarray(p.object_points) for p in planes]
    # The corners' scatter from the boards' own fits (never below a twentieth of a pixel, so
    # noise-free data stay well posed).
    sig_px = max(float(np.sqrt(np.mean([p.rms_px ** 2 for p in planes]))), 0.05)
    r_meas = [np.linalg.norm(a, axis=1) for a in pts]
    u_l = [_laser3(a / r[:, None]) for a, r in zip(pts, r_meas)]
    if range_noise is not None:
        sig_r = [np.maximum(range_noise.sigma(r), 1e-4) for r in r_meas]
    else:
        sig_r = [np.full(len(r), max(plane_rms, 1e-4)) for r in r_meas]
    xb = [np.concatenate([Rotation.from_matrix(p.rotation).as_rotvec(), p.translation])
          for p in planes]
    x_start = np.concatenate([x0, *xb])

    def f(x: Array) -> Array:
        R = Rotation.from_rotvec(x[:3]).as_matrix()
        t = x[3:6]
        out = []
        for i in range(B):
            rv, tv = x[6 + 6 * i:9 + 6 * i], x[9 + 6 * i:12 + 6 * i]
            px, _ = cv2.projectPoints(objs[i], rv, tv, camera.matrix, camera.dist_coeffs)
            out.append(((np.asarray(px).reshape(-1, 2) - corners[i]) / sig_px).ravel())
            n = Rotation.from_rotvec(rv).as_matrix()[:, 2]
            # the range along each ray to the board's plane: n . (t + s R u) = n . t_board
            s = (n @ tv - n @ t) / (u_l[i] @ R.T @ n)
            out.append((s - r_meas[i]) / sig_r[i])
        return np.concatenate(out)

    rows = sum(2 * len(c) + len(a) for c, a in zip(corners, pts))
    sparsity = lil_matrix((rows, 6 + 6 * B), dtype=int)  # type: ignore[no-untyped-call]
    row = 0
    for i in range(B):
        sparsity[row:row + 2 * len(corners[i]), 6 + 6 * i:12 + 6 * i] = 1
        row += 2 * len(corners[i])
        sparsity[row:row + len(pts[i]), :6] = 1
        sparsity[row:row + len(pts[i]), 6 + 6 * i:12 + 6 * i] = 1
        row += len(pts[i])
    sol = least_squares(  # type: ignore[operator]
        f, x_start, jac_sparsity=sparsity, method='trf', x_scale='jac')
    res = f(sol.x)
    jac = sol.jac.toarray() if hasattr(sol.jac, 'toarray') else np.asarray(sol.jac)
    dof = max(len(res) - len(sol.x), 1)
    try:
        cov = float(res @ res) / dof * np.linalg.inv(jac.T @ jac)
        sd = np.sqrt(np.clip(np.diag(cov)[:6], 0.0, None))
    except np.linalg.LinAlgError:
        sd = np.full(6, np.inf)
    refined = [_plane_of_pose(np.asarray(sol.x[6 + 6 * i:9 + 6 * i], dtype=np.float64),
                              np.asarray(sol.x[9 + 6 * i:12 + 6 * i], dtype=np.float64),
                              corners[i], objs[i], camera) for i in range(B)]
    return np.asarray(sol.x[:6]), refined, sd[:3], sd[3:]


def _linear_planes(xy: Array, n: Array, d: Array) -> Transform:
    """n^T H [x, y, 1]^T = d for every point, least squares in H = [r1 r2 t] (row-major)."""
    ph = np.column_stack([xy, np.ones(len(xy))])
    A = np.einsum('ij,ik->ijk', n, ph).reshape(len(xy), 9)
    h, _, rank, sv = np.linalg.lstsq(A, d, rcond=None)
    if rank < 9:
        raise CalibrationError('the board poses leave the linear estimate undetermined: give '
                               'more poses at different tilts, or an initial transform')
    H = h.reshape(3, 3)
    r1, r2, t = H[:, 0], H[:, 1], H[:, 2]
    M = np.column_stack([r1, r2, np.cross(r1, r2)])
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))]) @ Vt
    scale = 2.0 / (np.linalg.norm(r1) + np.linalg.norm(r2))
    q = Rotation.from_matrix(R).as_quat()
    tt = t * scale if np.isfinite(scale) else t
    return Transform((float(tt[0]), float(tt[1]), float(tt[2])),
                     (float(q[0]), float(q[1]), float(q[2]), float(q[3])))


# -- the frame tree ----------------------------------------------------------------------------
def project_scan(laser_xy: ArrayLike, transform: Transform,
                 camera: CameraModel) -> tuple[Array, NDArray[np.bool_]]:
    """Pixels (N, 2) of scan points (N, 2) [m] and which are drawable.

    Drawable: in front of the camera and, when the camera's size is known, inside the image.
    """
    xy = np.asarray(laser_xy, dtype=float).reshape(-1, 2)
    pc = transform.apply(_laser3(xy))
    px = camera.project(pc)
    ok = pc[:, 2] > 1e-3
    if camera.width and camera.height:
        ok &= ((px[:, 0] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] >= 0)
               & (px[:, 1] < camera.height))
    return px, ok


def optical_laser(tree: FrameTree, optical: str = 'camera_optical_frame',
                  laser: str = 'laser') -> Transform:
    """T_optical_laser as the frame tree has it now (the start and the selection's guess)."""
    return tree.lookup(optical, laser)


def frame_pose_from(tree: FrameTree, result: Transform, *, frame: str = 'camera_link',
                    optical: str = 'camera_optical_frame', laser: str = 'laser') -> Transform:
    """Return the pose of ``frame`` in its parent that makes T_optical_laser ``result``.

    A camera to lidar calibration measures only where the two sit relative to each other; the
    lidar's pose on the hull stays as the tree has it and the camera moves. ``frame`` is the
    frame whose pose is written: ``camera_link`` by default, so that the optical frame's fixed
    REP-103 rotation under it (a convention, not a measurement) stays as it is. ``frame`` must
    be ``optical`` or one of its ancestors, not an ancestor of ``laser``, and static.
    """
    f = tree.frame(frame)
    if f.parent is None or f.dynamic:
        raise CalibrationError(f'frame {frame!r} is the root or dynamic: the calibration '
                               'writes a static frame')
    if frame != optical and frame not in _ancestors(tree, optical):
        raise CalibrationError(f'frame {frame!r} is not {optical!r} or above it: writing it '
                               'would not move the camera')
    if frame == laser or frame in _ancestors(tree, laser):
        raise CalibrationError(f'frame {frame!r} is {laser!r} or above it: writing it would '
                               'move the lidar with the camera')
    # T_parent_frame = T_parent_laser T_laser_optical T_optical_frame
    t_parent_laser = tree.lookup(f.parent, laser)
    t_optical_frame = tree.lookup(optical, frame)
    return t_parent_laser @ result.inverse() @ t_optical_frame


def _ancestors(tree: FrameTree, name: str) -> list[str]:
    out = []
    p = tree.frame(name).parent
    while p is not None:
        out.append(p)
        p = tree.frame(p).parent
    return out
