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


_ANGLES = np.linspace(0.0, 2.0 * math.pi, RIM_SAMPLES, endpoint=False)
_COS, _SIN = np.cos(_ANGLES), np.sin(_ANGLES)


def _silhouettes(cx: Vector, cy: Vector, r: Vector, height: float, eye: Vector) -> Vector:
    """Silhouette points (n, P, 3) of n upright cylinders in ``base_link`` seen from ``eye``.

    Both rims: ``RIM_SAMPLES`` points each, and the exact tangent points and the nearest point
    of the circle seen from the eye (horizontally): c + r (cos(al) u +- sin(al) n), u the unit
    vector from the centre to the eye, al = acos(r / distance). They are the silhouette's
    left and right edges, which sampling alone would miss by a fraction of a pixel.
    """
    dx, dy = eye[0] - cx, eye[1] - cy
    dist = np.maximum(np.hypot(dx, dy), 1e-12)
    ux, uy = dx / dist, dy / dist
    # An eye inside the circle has no tangent: al = 0 (its points lie behind the camera anyway)
    al = np.arccos(np.clip(r / dist, -1.0, 1.0))
    ca, sa = np.cos(al), np.sin(al)
    x = np.concatenate((cx[:, None] + r[:, None] * _COS,
                        (cx + r * (ca * ux - sa * uy))[:, None],
                        (cx + r * (ca * ux + sa * uy))[:, None],
                        (cx + r * ux)[:, None]), axis=1)
    y = np.concatenate((cy[:, None] + r[:, None] * _SIN,
                        (cy + r * (ca * uy + sa * ux))[:, None],
                        (cy + r * (ca * uy - sa * ux))[:, None],
                        (cy + r * uy)[:, None]), axis=1)
    n, m = x.shape
    out = np.empty((n, 2 * m, 3))
    out[:, :m, 0], out[:, :m, 1], out[:, :m, 2] = x, y, 0.0
    out[:, m:, 0], out[:, m:, 1], out[:, m:, 2] = x, y, height
    return out


def project_obstacles(obstacles: Sequence[Obstacle], eta: Vector, camera: Camera,
                      settings: FusionSettings,
                      dts: Sequence[float] | None = None) -> dict[int, Box]:
    """Return the image boxes of the circle obstacles seen whole in front, by index.

    ``eta`` = [x, y, psi] the vessel's pose (odom, ENU) at the image's stamp; ``dts`` [s] =
    image stamp - each obstacle's stamp, over which it moves with its velocity (None: 0).
    Left out: segments, cylinders with a point nearer than ``settings.min_depth`` to the
    camera plane, and those whose box misses the image. All in one ``cv2.projectPoints``.
    """
    index = [i for i, o in enumerate(obstacles) if o.kind == CIRCLE]
    if not index:
        return {}
    dt = np.zeros(len(index)) if dts is None else np.asarray([dts[i] for i in index], float)
    o = np.array([(obstacles[i].x, obstacles[i].y, obstacles[i].vx, obstacles[i].vy,
                   obstacles[i].radius) for i in index])
    ox, oy = o[:, 0] + o[:, 2] * dt, o[:, 1] + o[:, 3] * dt
    c, s = math.cos(float(eta[2])), math.sin(float(eta[2]))
    # odom -> base_link: R(psi)^T (p - [x, y])
    bx = c * (ox - float(eta[0])) + s * (oy - float(eta[1]))
    by = -s * (ox - float(eta[0])) + c * (oy - float(eta[1]))
    t = camera.optical_from_base
    eye = -t[:3, :3].T @ t[:3, 3]   # the camera's centre in base_link
    pts = _silhouettes(bx, by, o[:, 4], settings.object_height, eye)
    cam = pts @ t[:3, :3].T + t[:3, 3]
    front = cam[:, :, 2].min(axis=1) >= settings.min_depth
    if not front.any():
        return {}
    seen = cam[front]
    d = np.asarray(camera.d, dtype=float)
    uv, _ = cv2.projectPoints(seen.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                              np.asarray(camera.k, dtype=float), d if d.size else None)
    uv = uv.reshape(seen.shape[0], seen.shape[1], 2)
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    lo = np.maximum(lo, 0.0)
    hi = np.minimum(hi, (float(camera.width), float(camera.height)))
    out: dict[int, Box] = {}
    for k, i in enumerate(np.asarray(index)[front]):
        if hi[k, 0] > lo[k, 0] and hi[k, 1] > lo[k, 1]:
            out[int(i)] = Box(float(lo[k, 0]), float(lo[k, 1]), float(hi[k, 0]),
                              float(hi[k, 1]))
    return out


def project_obstacle(obstacle: Obstacle, eta: Vector, camera: Camera,
                     settings: FusionSettings, dt: float = 0.0) -> Box | None:
    """Return the image box of one obstacle, or None (see :func:`project_obstacles`)."""
    return project_obstacles([obstacle], eta, camera, settings, [dt]).get(0)


def iou_matrix(a: Sequence[Box], b: Sequence[Box]) -> Vector:
    """Intersection over union (len(a), len(b)) of every pair, as :func:`iou` computes it."""
    p = np.array([(q.x_min, q.y_min, q.x_max, q.y_max) for q in a]).reshape(-1, 4)
    d = np.array([(q.x_min, q.y_min, q.x_max, q.y_max) for q in b]).reshape(-1, 4)
    w = np.clip(np.minimum(p[:, None, 2], d[None, :, 2]) - np.maximum(p[:, None, 0],
                                                                      d[None, :, 0]), 0.0, None)
    h = np.clip(np.minimum(p[:, None, 3], d[None, :, 3]) - np.maximum(p[:, None, 1],
                                                                      d[None, :, 1]), 0.0, None)
    area_p = np.clip(p[:, 2] - p[:, 0], 0.0, None) * np.clip(p[:, 3] - p[:, 1], 0.0, None)
    area_d = np.clip(d[:, 2] - d[:, 0], 0.0, None) * np.clip(d[:, 3] - d[:, 1], 0.0, None)
    inter = w * h
    union = area_p[:, None] + area_d[None, :] - inter
    out: Vector = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0.0)
    return out


def associate(projected: Sequence[Box], detected: Sequence[Box],
              min_iou: float) -> list[tuple[int, int]]:
    """Pair projected boxes with detected boxes: least total 1 - IoU, gated at ``min_iou``.

    Returns (projected index, detected index) pairs, each index at most once, every pair with
    an IoU of at least ``min_iou``.
    """
    if not projected or not detected:
        return []
    overlap = iou_matrix(projected, detected)
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
    dts = [(image_stamp_ns - o.stamp_ns) * 1e-9 if o.stamp_ns else 0.0 for o in obstacles]
    projected = project_obstacles(obstacles, eta, camera, settings, dts)
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
