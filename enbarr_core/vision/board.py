"""A checkerboard as a real camera sees it, and the poses of a calibration run.

``render_board(camera, board, pose)`` draws a printed checkerboard seen by a pinhole camera
with plumb_bob distortion (the model of sensor_msgs/CameraInfo, OpenCV's five coefficients
k1, k2, p1, p2, k3): every output pixel is traced back through the distortion and the lens to
the board plane, so straight edges bend exactly as the model bends them. A pixel is the mean
of ``supersample`` x ``supersample`` rays spread over its area (a box filter, what a sensor pixel
integrates), which is what lets ``cv2.cornerSubPix`` place a corner to a small fraction of a
pixel. Optional Gaussian blur (defocus) and noise.

``calibration_poses(camera, board, n, seed)`` gives the views a person waving the board in
front of the camera would give: spread over the image (X, Y), near and far (size), tilted
(skew), each with the whole board in the picture.

Frames: the camera frame is the optical frame (x right, y down, z forward, REP-103
``_optical``). The board frame has its origin at the first inner corner, x along a row of
inner corners (``cols`` of them), y along a column (``rows``), z into the board: a board
facing the camera has its z along the camera's. Pure numpy and OpenCV; no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import cv2
import numpy as np

from enbarr_core.vision.camera import PinholeCamera

#: Grey levels of the print: black ink on white paper, as a camera with sensible exposure
#: sees them (never 0 or 255, so noise is not clipped on one side only).
BLACK = 30
WHITE = 225
#: The scene behind the board.
BACKGROUND = 128


class Camera(PinholeCamera):
    """A pinhole camera with plumb_bob distortion (sensor_msgs/CameraInfo ``K`` and ``D``).

    Built from ``fx``, ``fy``, ``cx``, ``cy`` in pixels and ``d`` = (k1, k2, p1, p2, k3),
    OpenCV's order: the shared ``PinholeCamera`` as the board renderer needs it (a known
    size, the five coefficients its own ray tracing reads).
    """

    def __init__(self, width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                 d: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
                 ) -> None:
        if width <= 0 or height <= 0:
            raise ValueError(f'image size must be positive, got {width}x{height}')
        if fx <= 0 or fy <= 0:
            raise ValueError(f'focal lengths must be positive, got {fx}, {fy}')
        if len(d) != 5:
            raise ValueError(f'plumb_bob has 5 coefficients, got {len(d)}')
        super().__init__(width, height,
                         (float(fx), 0.0, float(cx), 0.0, float(fy), float(cy), 0.0, 0.0, 1.0),
                         tuple(float(x) for x in d), 'plumb_bob')


@dataclass(frozen=True)
class Board:
    """A checkerboard: ``cols`` x ``rows`` inner corners, squares of ``square`` metres.

    It has (cols + 1) x (rows + 1) squares; the CS Saucer manual's board (4.1) is 9x7 squares
    of 40 mm, i.e. ``Board(8, 6, 0.040)``. ``margin`` is the white paper round the squares
    [m]: the detector needs light round the outer squares.
    """

    cols: int
    rows: int
    square: float          # [m]
    margin: float = -1.0   # [m]; negative: one square

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f'a board needs at least 2x2 inner corners, got '
                             f'{self.cols}x{self.rows}')
        if not self.square > 0:
            raise ValueError(f'square size must be positive, got {self.square}')

    @property
    def paper(self) -> float:
        """The white margin [m]."""
        return self.square if self.margin < 0 else self.margin

    def object_points(self) -> np.ndarray:
        """Return the inner corners in the board frame, (cols*rows, 3) [m], row by row.

        The order ``cv2.findChessboardCorners(image, (cols, rows))`` reports them in.
        """
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        pts = np.zeros((self.rows * self.cols, 3))
        pts[:, 0] = i.ravel() * self.square
        pts[:, 1] = j.ravel() * self.square
        return pts

    def outline(self) -> np.ndarray:
        """Return the four outer corners of the squares (not the paper), (4, 3) [m]."""
        s = self.square
        x0, y0, x1, y1 = -s, -s, self.cols * s, self.rows * s
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])

    @property
    def centre(self) -> np.ndarray:
        """The middle of the squares in the board frame [m]."""
        return np.array([(self.cols - 1) * self.square / 2, (self.rows - 1) * self.square / 2,
                         0.0])


@dataclass(frozen=True)
class Pose:
    """The board in the camera frame: ``p_cam = R(rvec) p_board + tvec``.

    ``rvec`` is a rotation vector (axis times angle [rad], OpenCV's ``rvec``), ``tvec`` [m].
    """

    rvec: tuple[float, float, float]
    tvec: tuple[float, float, float]

    @property
    def rotation(self) -> np.ndarray:
        """``R`` (3x3)."""
        return cv2.Rodrigues(np.asarray(self.rvec, dtype=float).reshape(3, 1))[0]

    @classmethod
    def from_matrix(cls, rotation: np.ndarray, tvec: np.ndarray) -> Pose:
        """Build from a rotation matrix and a translation."""
        r = cv2.Rodrigues(np.asarray(rotation, dtype=float))[0].ravel()
        t = np.asarray(tvec, dtype=float).ravel()
        return cls((float(r[0]), float(r[1]), float(r[2])),
                   (float(t[0]), float(t[1]), float(t[2])))


def distort(camera: Camera, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map normalized image coordinates to pixels through plumb_bob (OpenCV's model)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    uv = camera.project(np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1))
    return uv[:, 0].reshape(x.shape), uv[:, 1].reshape(x.shape)


def project(camera: Camera, pose: Pose, points: np.ndarray) -> np.ndarray:
    """Board-frame points (N, 3) [m] -> pixels (N, 2); ``nan`` behind the camera."""
    p = np.asarray(points, dtype=float) @ pose.rotation.T + np.asarray(pose.tvec)
    z = np.where(p[:, 2] > 1e-9, p[:, 2], np.nan)
    u, v = distort(camera, p[:, 0] / z, p[:, 1] / z)
    return np.stack([u, v], axis=1)


def undistort(camera: Camera, u: np.ndarray, v: np.ndarray, iterations: int = 30
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels -> normalized coordinates, and where the inverse is exact.

    OpenCV's ``undistortPoints`` (``PinholeCamera.normalized``); a pixel whose result does
    not map back onto itself (past the fold of a strong barrel lens, where no ray reaches
    it) is marked invalid rather than drawn wrong.
    """
    u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    xy = camera.normalized(np.stack([u.ravel(), v.ravel()], axis=1), iterations)
    x, y = xy[:, 0].reshape(u.shape), xy[:, 1].reshape(u.shape)
    uu, vv = distort(camera, x, y)
    valid = np.isfinite(uu) & np.isfinite(vv) & (np.abs(uu - u) < 1e-3) & (
        np.abs(vv - v) < 1e-3)
    return x, y, valid


class _Rays:
    """The normalized ray of every pixel centre and its derivatives (cached per camera).

    A pixel's sub-samples are placed on the board by the first-order expansion about its
    centre: over a pixel both the distortion and the perspective are linear to far below
    the precision that matters, and the expansion costs a multiply-add per sample.
    """

    def __init__(self, camera: Camera) -> None:
        v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
        x, y, valid = undistort(camera, u.ravel(), v.ravel())
        self.shape = (camera.height, camera.width)
        self.x = np.where(valid, x, 0.0).reshape(self.shape)
        self.y = np.where(valid, y, 0.0).reshape(self.shape)
        self.valid = valid.reshape(self.shape)


_RAYS: dict[Camera, _Rays] = {}


def _rays(camera: Camera) -> _Rays:
    if camera not in _RAYS:
        if len(_RAYS) >= 4:   # a few cameras at a time; each costs megabytes
            _RAYS.pop(next(iter(_RAYS)))
        _RAYS[camera] = _Rays(camera)
    return _RAYS[camera]


def _sample_offsets(n: int) -> list[tuple[np.float32, np.float32]]:
    """Return n*n sample positions in a pixel, from its centre [px].

    The n-rooks ("canonical multi-jittered") arrangement: one sample per cell of an n x n
    grid and, at the same time, one per row and column of an n^2 x n^2 grid. A regular n x n
    grid gives an edge parallel to the pixel rows only n + 1 grey levels, which cornerSubPix
    turns into an error of up to 1/(2n) px on a board square to the image; this gives it
    n^2 + 1.
    """
    out = []
    for i in range(n):
        for j in range(n):
            out.append((np.float32((i + (j + 0.5) / n) / n - 0.5),
                        np.float32((j + (i + 0.5) / n) / n - 0.5)))
    return out


def render_board(camera: Camera, board: Board, pose: Pose, *, supersample: int = 4,
                 blur: float = 0.0, noise: float = 0.0, seed: int | None = None,
                 color: bool = False) -> np.ndarray:
    """Render the image ``camera`` takes of ``board`` at ``pose`` (uint8 HxW, HxWx3 if color).

    ``supersample``: rays per pixel side (box filter); ``blur``: Gaussian sigma [px] (defocus);
    ``noise``: Gaussian sensor noise, standard deviation in grey levels, seeded by ``seed``.
    The square at the board origin (its first inner corner's upper left) is black, and so
    are the other three corner squares of a board of odd x odd squares, as printed ones are.
    """
    if supersample < 1:
        raise ValueError(f'supersample must be at least 1, got {supersample}')
    rays = _rays(camera)
    r = pose.rotation
    t = np.asarray(pose.tvec, dtype=float)
    # A ray s*(x, y, 1) meets the board plane n.(p - t) = 0, n = R e_z, at
    # s = n.t / n.(x, y, 1); the hit point in the board frame is R^T (s (x, y, 1) - t).
    n = r[:, 2]
    denom = n[0] * rays.x + n[1] * rays.y + n[2]
    with np.errstate(divide='ignore', invalid='ignore'):
        s = float(n @ t) / denom
    hit = rays.valid & (s > 0) & np.isfinite(s)
    s = np.where(hit, s, 0.0)
    px = s * rays.x - t[0]
    py = s * rays.y - t[1]
    pz = s - t[2]
    bx = r[0, 0] * px + r[1, 0] * py + r[2, 0] * pz
    by = r[0, 1] * px + r[1, 1] * py + r[2, 1] * pz
    # In square units from here: the squares' corners are integers.
    inv = 1.0 / board.square
    bx = (bx * inv).astype(np.float32)
    by = (by * inv).astype(np.float32)
    # d(board)/d(pixel) by central differences (one-sided at the image edge).
    bx_v, bx_u = np.gradient(bx)
    by_v, by_u = np.gradient(by)
    m = np.float32(board.paper * inv)
    cols, rows = np.float32(board.cols), np.float32(board.rows)
    paper = hit.astype(np.float32) * np.float32(WHITE - BACKGROUND)
    acc = np.zeros(rays.shape, dtype=np.float32)
    for du, dv in _sample_offsets(supersample):
        x = bx + bx_u * du + bx_v * dv
        y = by + by_u * du + by_v * dv
        fx = np.floor(x)
        fy = np.floor(y)
        on_paper = (x >= -1 - m) & (x < cols + m) & (y >= -1 - m) & (y < rows + m)
        black = (fx >= -1) & (fx < cols) & (fy >= -1) & (fy < rows) & ((fx + fy) % 2 == 0)
        acc += paper * on_paper
        acc += black * hit * np.float32(BLACK - WHITE)
    img: np.ndarray = BACKGROUND + acc / (supersample * supersample)
    if blur > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), blur))
    if noise > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return np.asarray(cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)) if color else out


def _look_at_pose(camera: Camera, board: Board, u: float, v: float, distance: float,
                  tilt_x: float, tilt_y: float, roll: float) -> Pose:
    """Put the board centre on pixel (u, v) at ``distance`` [m], turned by the angles [rad]."""
    x, y, _ = undistort(camera, np.array([u]), np.array([v]))
    ray = np.array([x[0], y[0], 1.0])
    ray /= np.linalg.norm(ray)
    rot = (cv2.Rodrigues(np.array([tilt_x, 0.0, 0.0]))[0]
           @ cv2.Rodrigues(np.array([0.0, tilt_y, 0.0]))[0]
           @ cv2.Rodrigues(np.array([0.0, 0.0, roll]))[0])
    t = distance * ray - rot @ board.centre
    return Pose.from_matrix(rot, t)


def fits(camera: Camera, board: Board, pose: Pose, border: float) -> bool:
    """Whether the board's squares are all in the image, ``border`` px inside its edges."""
    s = board.square
    m = min(board.paper, s) / 2
    edge = board.outline()
    edge[:, :2] += np.array([[-m, -m], [m, -m], [m, m], [-m, m]])
    # Sample the outline densely: a distorted edge bulges between its end points.
    pts = np.concatenate([edge[i] + np.linspace(0, 1, 16)[:, None] * (edge[(i + 1) % 4]
                          - edge[i]) for i in range(4)])
    uv = project(camera, pose, pts)
    return bool(np.all(np.isfinite(uv)) and np.all(uv[:, 0] >= border)
                and np.all(uv[:, 0] <= camera.width - 1 - border)
                and np.all(uv[:, 1] >= border) and np.all(uv[:, 1] <= camera.height - 1 - border))


def calibration_poses(camera: Camera, board: Board, n: int, seed: int = 0, *,
                      max_tilt: float = math.radians(50), border: float = 10.0
                      ) -> list[Pose]:
    """``n`` board poses of a calibration run, as a person waving the board gives them.

    The views cycle through the image's corners, edges and middle (X, Y), near and far
    (the board from about a third to three quarters of the image width: size) and tilted
    by up to ``max_tilt`` about an axis in its plane (skew), with a little roll; jitter is
    seeded by ``seed``. Every pose keeps the whole board ``border`` px inside the image; a
    draw that does not is drawn again nearer the middle and further away.
    """
    if n < 1:
        raise ValueError(f'n must be at least 1, got {n}')
    rng = np.random.default_rng(seed)
    width_m = (board.cols + 1) * board.square
    places = [(0.5, 0.5), (0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9),
              (0.5, 0.1), (0.9, 0.5), (0.5, 0.9), (0.1, 0.5)]
    sizes = (0.35, 0.55, 0.75, 0.3)
    poses: list[Pose] = []
    for i in range(n):
        fx, fy = places[i % len(places)]
        size = sizes[(i // len(places) + i) % len(sizes)]
        # The board turned by up to max_tilt about an axis in its plane: small boards
        # turned far show squares a few pixels across, which no one calibrates with.
        tilt = rng.uniform(0.4, 0.8) * max_tilt
        heading = rng.uniform(-math.pi, math.pi)
        if i % 3 == 2:   # every third view turned fully about a diagonal: the most skew
            tilt = max_tilt
            heading = math.pi / 4 + (i // 3 % 4) * math.pi / 2
        if size < 0.35:
            tilt *= 0.6
        tilt_x, tilt_y = tilt * math.cos(heading), tilt * math.sin(heading)
        roll = rng.uniform(-0.25, 0.25)
        for attempt in range(40):
            shrink = 0.9 ** attempt   # towards the middle, further away, less tilt
            u = camera.width * (0.5 + (fx - 0.5) * shrink + rng.uniform(-0.04, 0.04))
            v = camera.height * (0.5 + (fy - 0.5) * shrink + rng.uniform(-0.04, 0.04))
            distance = camera.fx * width_m / (size * shrink * camera.width)
            pose = _look_at_pose(camera, board, u, v, distance, tilt_x * shrink,
                                 tilt_y * shrink, roll)
            if fits(camera, board, pose, border):
                poses.append(pose)
                break
        else:
            raise ValueError(f'no pose of a {board.cols}x{board.rows} board fits a '
                             f'{camera.width}x{camera.height} image')
    return poses
