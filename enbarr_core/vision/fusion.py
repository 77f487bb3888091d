"""Camera and lidar fusion: tracked lidar obstacles given the class of the boxes they fall in.

The lidar knows where an obstacle is, how large and how fast (``enbarr_interfaces.obstacles``);
the camera's detector knows what it is but, being monocular, not how far
(``enbarr_interfaces.detections``). Fusion projects each tracked circle into the image and
pairs the projections with the boxes:

1. Each circle obstacle (odom, ENU) is moved to the image's stamp with its own velocity, then
   into ``base_link`` with the vessel's pose at that stamp, and taken as an upright cylinder
   of ``object_height`` standing on the waterline (``base_link`` z = 0; the buoys of the
   world are such cylinders). Its silhouette (both rims, sampled, with the exact tangent
   points of the circle seen from the camera) goes through the camera's extrinsics
   (``base_link`` -> optical frame) and intrinsics (K and the plumb_bob distortion D of
   ``camera_info``, ``cv2.projectPoints``) to a box, clipped to the image. A cylinder with
   any point closer than ``min_depth`` in front of the camera (behind it, or so close the
   projection is meaningless) or wholly outside the image is not projected. Segments (walls)
   are not projected: a detector draws no box round a wall.
2. Cost of a pair = 1 - IoU (intersection over union) of the projected box and the
   detection's box; pairs with an IoU below ``min_iou`` are never matched (the gate). The
   assignment minimizing the total cost (``scipy.optimize.linear_sum_assignment``, the
   Hungarian method) is taken, not the greedy best pair first: two obstacles side by side
   whose boxes overlap would otherwise swap or lose a class.
3. A matched obstacle keeps everything the lidar gave (position, radius, velocity,
   covariances, id) and takes the detection's class and score. With a :class:`ClassMemory`
   the class is voted over the frames of the track (the sum of the scores of each class
   seen on that track id), so one misclassified frame does not flip it and an obstacle
   keeps its class when it leaves the image. A detection matched to no obstacle is returned
   among ``unmatched_detections``: without a range it is no obstacle, and none is invented.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from enbarr_interfaces.obstacles import CIRCLE, Obstacle

Vector = NDArray[np.float64]

#: Points sampled on each rim of a cylinder (the exact tangent points are added to them).
RIM_SAMPLES = 72


@dataclass(frozen=True)
class FusionSettings:
    """How obstacles are projected and paired with detections.

    ``object_height`` [m] above the waterline of every circle obstacle (the cylinder's top);
    ``min_iou``: the gate, the least intersection over union of a pair; ``min_depth`` [m]:
    the nearest a silhouette point may be in front of the camera.
    """

    object_height: float = 0.5
    min_iou: float = 0.1
    min_depth: float = 0.1

    def __post_init__(self) -> None:
        if not self.object_height > 0.0:
            raise ValueError(f'object_height: {self.object_height} must be > 0 m')
        if not 0.0 < self.min_iou <= 1.0:
            raise ValueError(f'min_iou: {self.min_iou} must be in (0, 1]')
        if not self.min_depth > 0.0:
            raise ValueError(f'min_depth: {self.min_depth} must be > 0 m')


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: intrinsics as ``camera_info`` gives them, and its mount.

    ``k`` the 3 x 3 camera matrix [px], ``d`` the plumb_bob distortion (k1, k2, p1, p2[, k3])
    (empty: none), ``width`` x ``height`` [px]; ``optical_from_base`` the 4 x 4 transform
    mapping ``base_link`` coordinates to the optical frame's (z ahead, x right, y down).
    """

    k: Vector
    d: Vector
    width: int
    height: int
    optical_from_base: Vector


@dataclass(frozen=True)
class Box:
    """An image box [px], x right and y down, corners at pixel edges."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float

    @property
    def area(self) -> float:
        """Area [px^2] (0 for an empty box)."""
        return max(0.0, self.x_max - self.x_min) * max(0.0, self.y_max - self.y_min)


@dataclass(frozen=True)
class DetectedBox:
    """One detection: its class, score and box."""

    class_id: int
    score: float
    box: Box


@dataclass(frozen=True)
class FusionResult:
    """What one detections message made of the obstacles.

    ``obstacles``: every obstacle given, in order, the matched ones (and, with a memory, the
    ones whose track was classified before) with their class; ``matches``: (obstacle index,
    detection index) pairs; ``projected``: obstacle index -> its box;
    ``unmatched_detections``: indices of the detections paired with no obstacle.
    """

    obstacles: list[Obstacle]
    matches: list[tuple[int, int]]
    projected: dict[int, Box]
    unmatched_detections: list[int]


def iou(a: Box, b: Box) -> float:
    """Intersection over union of two boxes (0 when either is empty)."""
    inter = Box(max(a.x_min, b.x_min), max(a.y_min, b.y_min),
                min(a.x_max, b.x_max), min(a.y_max, b.y_max)).area
    union = a.area + b.area - inter
    return inter / union if union > 0.0 else 0.0


def _cylinder_points(cx: float, cy: float, r: float, height: float,
                     eye: Vector) -> Vector:
    """Silhouette points (N, 3) of an upright cylinder in ``base_link`` seen from ``eye``."""
    a = np.linspace(0.0, 2.0 * math.pi, RIM_SAMPLES, endpoint=False)
    ring = [np.column_stack((cx + r * np.cos(a), cy + r * np.sin(a)))]
    # The tangent points from the eye (horizontally): c + r (cos(al) u +- sin(al) n), u the
    # unit vector from the centre to the eye, al = acos(r / distance); they are the
    # silhouette's left and right edges, which sampling alone would miss by a fraction.
    dx, dy = float(eye[0]) - cx, float(eye[1]) - cy
    dist = math.hypot(dx, dy)
    if dist > r:
        ux, uy = dx / dist, dy / dist
        al = math.acos(r / dist)
        ca, sa = math.cos(al), math.sin(al)
        ring.append(np.array([[cx + r * (ca * ux - sa * uy), cy + r * (ca * uy + sa * ux)],
                              [cx + r * (ca * ux + sa * uy), cy + r * (ca * uy - sa * ux)],
                              [cx + r * ux, cy + r * uy]]))
    xy = np.vstack(ring)
    n = len(xy)
    out = np.empty((2 * n, 3))
    out[:n, :2] = xy
    out[:n, 2] = 0.0
    out[n:, :2] = xy
    out[n:, 2] = height
    return out


def project_obstacle(obstacle: Obstacle, eta: Vector, camera: Camera,
                     settings: FusionSettings, dt: float = 0.0) -> Box | None:
    """Return the image box of a circle obstacle, or None when not seen whole in front.

    ``eta`` = [x, y, psi] the vessel's pose (odom, ENU) at the image's stamp; ``dt`` [s] =
    image stamp - obstacle stamp, over which the obstacle moves with its velocity.
    None for a segment, a cylinder with a point nearer than ``settings.min_depth`` to the
    camera plane, or one whose box misses the image.
    """
    if obstacle.kind != CIRCLE:
        return None
    ox, oy = obstacle.x + obstacle.vx * dt, obstacle.y + obstacle.vy * dt
    c, s = math.cos(float(eta[2])), math.sin(float(eta[2]))
    # odom -> base_link: R(psi)^T (p - [x, y])
    bx = c * (ox - float(eta[0])) + s * (oy - float(eta[1]))
    by = -s * (ox - float(eta[0])) + c * (oy - float(eta[1]))
    t = camera.optical_from_base
    eye = -t[:3, :3].T @ t[:3, 3]   # the camera's centre in base_link
    pts = _cylinder_points(bx, by, obstacle.radius, settings.object_height, eye)
    cam = pts @ t[:3, :3].T + t[:3, 3]
    if float(cam[:, 2].min()) < settings.min_depth:
        return None
    rvec = np.zeros(3)
    tvec = np.zeros(3)
    d = np.asarray(camera.d, dtype=float)
    uv, _ = cv2.projectPoints(cam.reshape(-1, 1, 3), rvec, tvec,
                              np.asarray(camera.k, dtype=float), d if d.size else None)
    uv = uv.reshape(-1, 2)
    box = Box(max(0.0, float(uv[:, 0].min())), max(0.0, float(uv[:, 1].min())),
              min(float(camera.width), float(uv[:, 0].max())),
              min(float(camera.height), float(uv[:, 1].max())))
    if box.x_max <= box.x_min or box.y_max <= box.y_min:
        return None
    return box


def associate(projected: Sequence[Box], detected: Sequence[Box],
              min_iou: float) -> list[tuple[int, int]]:
    """Pair projected boxes with detected boxes: least total 1 - IoU, gated at ``min_iou``.

    Returns (projected index, detected index) pairs, each index at most once, every pair with
    an IoU of at least ``min_iou``.
    """
    if not projected or not detected:
        return []
    overlap = np.array([[iou(p, q) for q in detected] for p in projected])
    # Pairs outside the gate cost more than any inside would save, so the solver takes one
    # only when nothing else is left; such a pair is dropped below.
    cost = np.where(overlap >= min_iou, 1.0 - overlap, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols) if overlap[i, j] >= min_iou]


@dataclass
class ClassMemory:
    """Class votes per track id: each match adds its score to its class on that id.

    The class of a track is the class with the largest sum; its score, that sum over the sum
    of all its votes (the share of the evidence). Ids not among the obstacles are forgotten
    (a track id is unique while the track lives).
    """

    votes: dict[int, dict[int, float]] = field(default_factory=dict)

    def vote(self, track_id: int, class_id: int, score: float) -> None:
        """Add one match of ``track_id`` to ``class_id`` with ``score``."""
        per = self.votes.setdefault(track_id, {})
        per[class_id] = per.get(class_id, 0.0) + max(score, 1e-6)

    def of(self, track_id: int) -> tuple[int, float] | None:
        """Return (class, share) of ``track_id``, or None when it was never matched."""
        per = self.votes.get(track_id)
        if not per:
            return None
        best = max(per, key=lambda k: (per[k], -k))
        return best, per[best] / sum(per.values())

    def keep_only(self, track_ids: set[int]) -> None:
        """Forget every id not in ``track_ids``."""
        for gone in [i for i in self.votes if i not in track_ids]:
            del self.votes[gone]


def fuse(obstacles: Sequence[Obstacle], eta: Vector, image_stamp_ns: int, camera: Camera,
         detections: Sequence[DetectedBox], settings: FusionSettings,
         memory: ClassMemory | None = None) -> FusionResult:
    """Give the obstacles the classes of the detections they project onto.

    ``eta``: the vessel's pose at ``image_stamp_ns`` (odom); each obstacle is moved to that
    stamp with its velocity before projection. Without ``memory`` an obstacle's class is
    this frame's match alone; with one, the vote over its track (see :class:`ClassMemory`).
    """
    projected: dict[int, Box] = {}
    for i, o in enumerate(obstacles):
        dt = (image_stamp_ns - o.stamp_ns) * 1e-9 if o.stamp_ns else 0.0
        box = project_obstacle(o, eta, camera, settings, dt)
        if box is not None:
            projected[i] = box
    index = list(projected)
    pairs = associate([projected[i] for i in index], [d.box for d in detections],
                      settings.min_iou)
    matches = [(index[p], j) for p, j in pairs]
    out = list(obstacles)
    if memory is not None:
        memory.keep_only({o.id for o in obstacles})
        for i, j in matches:
            memory.vote(obstacles[i].id, detections[j].class_id, detections[j].score)
        for i, o in enumerate(obstacles):
            voted = memory.of(o.id)
            if voted is not None:
                out[i] = replace(o, class_id=voted[0], class_score=voted[1])
    else:
        for i, j in matches:
            out[i] = replace(obstacles[i], class_id=detections[j].class_id,
                             class_score=detections[j].score)
    matched = {j for _, j in matches}
    return FusionResult(out, matches, projected,
                        [j for j in range(len(detections)) if j not in matched])


def detected_boxes(rows: Any) -> list[DetectedBox]:
    """Return the detections of a ``enbarr_interfaces.detections.from_cloud`` array."""
    return [DetectedBox(int(r['class_id']), float(r['score']),
                        Box(float(r['x_min']), float(r['y_min']), float(r['x_max']),
                            float(r['y_max']))) for r in rows]
