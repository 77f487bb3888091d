"""The pinhole camera model every vision module shares: sensor_msgs/CameraInfo's intrinsics.

``PinholeCamera`` holds what a camera_info carries of the lens: the image size, ``K`` (3x3
row-major, as ``CameraInfo.k``), the distortion model's name and its coefficients ``D`` in
OpenCV's order (plumb_bob: k1, k2, p1, p2, k3; rational_polynomial: eight). It takes plain
numbers, so a camera_info YAML file (``enbarr_plugins.camera.calibration``, a plugin) or a
``CameraInfo`` message converts into it where it is read, and this module stays free of
plugins and of ROS. Projection and undistortion delegate to OpenCV (``cv2.projectPoints``,
``cv2.undistortPoints``), the reference implementation of these distortion models.

A user of the model that accepts less (a renderer that draws two distortion models, a
calibration that needs a known image size) subclasses it and checks more in
``__post_init__``, with its own words and error type.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Self

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: How many distortion coefficients OpenCV's pinhole model reads (0: none).
OPENCV_COEFFICIENT_COUNTS = (0, 4, 5, 8, 12, 14)
#: ``cv2.undistortPoints``'s own default stops after 5 iterations, too few near the edge of a
#: strongly distorted image; iterate to convergence instead.
UNDISTORT_ITERATIONS = 200


@dataclass(frozen=True)
class PinholeCamera:
    """A camera's intrinsics: image size [px], ``k`` (K, 3x3 row-major [px]), distortion.

    ``width``/``height`` 0: the size is unknown (nothing is tested against the image's edge).
    ``d`` empty: no distortion. ``ValueError`` names what is wrong.
    """

    width: int
    height: int
    k: tuple[float, ...]
    d: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    distortion_model: str = 'plumb_bob'

    def __post_init__(self) -> None:
        if self.width < 0 or self.height < 0:
            raise ValueError(f'image size must not be negative, got {self.width}x{self.height}')
        if len(self.k) != 9 or not all(math.isfinite(x) for x in self.k) or not (
                self.k[0] > 0.0 and self.k[4] > 0.0):
            raise ValueError(f'K: expected 9 finite numbers with fx, fy > 0, got {self.k}')
        if len(self.d) not in OPENCV_COEFFICIENT_COUNTS:
            raise ValueError(f'D: expected {", ".join(map(str, OPENCV_COEFFICIENT_COUNTS))} '
                             f'coefficients, got {len(self.d)}')

    @classmethod
    def nominal(cls, width: int, height: int, focal: float,
                d: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> Self:
        """Return the camera of focal length ``focal`` [px] (fx = fy), centred."""
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        model = 'rational_polynomial' if len(d) == 8 else 'plumb_bob'
        return cls(width, height, (focal, 0.0, cx, 0.0, focal, cy, 0.0, 0.0, 1.0),
                   tuple(float(x) for x in d), model)

    @property
    def fx(self) -> float:
        """Focal length along x [px]."""
        return self.k[0]

    @property
    def fy(self) -> float:
        """Focal length along y [px]."""
        return self.k[4]

    @property
    def cx(self) -> float:
        """Principal point, x [px]."""
        return self.k[2]

    @property
    def cy(self) -> float:
        """Principal point, y [px]."""
        return self.k[5]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) [px], OpenCV's order."""
        return self.width, self.height

    @property
    def matrix(self) -> Array:
        """K as a 3x3 array (OpenCV's cameraMatrix), a new one at each call."""
        return np.array(self.k, dtype=float).reshape(3, 3)

    @property
    def dist_coeffs(self) -> Array:
        """D as OpenCV's distCoeffs (five zeros when there is none), a new one at each call."""
        return np.array(self.d if self.d else (0.0,) * 5, dtype=float)

    @property
    def projection(self) -> tuple[float, ...]:
        """P (3x4 row-major) of the CameraInfo: [K | 0], a monocular camera's."""
        k = self.k
        return (k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0)

    def project(self, points: ArrayLike, rvec: ArrayLike = (0.0, 0.0, 0.0),
                tvec: ArrayLike = (0.0, 0.0, 0.0)) -> Array:
        """Pixels (N, 2) of points (N, 3) [m]; any depth sign.

        The points are moved into the optical frame by OpenCV's pose first:
        p_c = R(rvec) p + tvec (none by default).
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if not len(p):
            return np.zeros((0, 2))
        px, _ = cv2.projectPoints(p, np.asarray(rvec, dtype=float),
                                  np.asarray(tvec, dtype=float), self.matrix, self.dist_coeffs)
        return np.asarray(px, dtype=float).reshape(-1, 2)

    def normalized(self, pixels: ArrayLike, iterations: int = UNDISTORT_ITERATIONS) -> Array:
        """Undistorted normalized coordinates (N, 2) (x/z, y/z) of pixels (N, 2) [px].

        OpenCV's fixed-point iteration, at most ``iterations`` steps (fewer once a step
        moves less than 1e-12). Past the fold of a strong barrel lens no ray reaches a
        pixel and the result is not its inverse: ``project`` it back to tell.
        """
        uv = np.asarray(pixels, dtype=float).reshape(-1, 1, 2)
        if not len(uv):
            return np.zeros((0, 2))
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 1e-12)
        xy = cv2.undistortPoints(uv, self.matrix, self.dist_coeffs, None, None, None,
                                 criteria)
        return np.asarray(xy, dtype=float).reshape(-1, 2)
