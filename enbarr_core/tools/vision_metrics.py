"""Figures of the camera's detector and of the fusion, from a run's bag and the true world.

The ground truth of a frame is the simulated camera's own label image (``sim_render``: which
obstacle every pixel shows, occlusion included) re-rendered at the truth pose of the image's
stamp (``sim/odometry``: the camera stamps a frame with the truth it was drawn at), with the
true lens (the ``sim_camera`` node's parameters in the profile) and mount (the frame tree's
``base_link -> camera_optical_frame``). An obstacle's true box is the pixel bounding box of
its labels, in the detections' convention (corners at pixel edges). An obstacle is a target
of the detector when its colour falls in one of the classical back end's HSV boxes (that is
its class); it counts in a frame when it shows at least ``min_pixels`` pixels (the
detector's ``min_area``: a blob smaller than that is not meant to be found). Definitions
(every figure is ``None`` when the run has nothing to compute it from):

- ``detection_precision``, ``detection_recall``: over every ``detections`` message, each
  true box matched one-to-one with a detection of its class (greedy, largest intersection
  over union first) when their IoU is at least ``MATCH_IOU``; precision = matches /
  detections, recall = matches / counted true boxes. A detection matching the box of a
  target shown by fewer than ``min_pixels`` pixels is neither right nor wrong (left out).
  ``detection_frames``: the frames judged.
- ``fusion_position_error_rms_m``: each classed circle of ``obstacles/fused`` against the
  nearest true circle (centre within ``MATCH_RADIUS``) at the obstacle's stamp.
- ``fusion_latency_p50_ms``, ``fusion_latency_p99_ms``: from the stamp of an image with
  detections to the first ``obstacles/fused`` message recorded at or after the
  ``detections`` message (the bag's receive times, simulated time in a scenario) that carries
  a classed obstacle: the fusion takes each image's classes into its votes when the
  detections arrive and publishes them with the next obstacles, so this is the age of an
  image when its classes first reach the avoidance.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from enbarr_core.world.model import Circle, World
from enbarr_interfaces import convert
from enbarr_interfaces import detections as detection_msg
from enbarr_interfaces import obstacles as obstacle_msg

#: What the vision figures read besides the truth.
VISION_TOPICS = ('/detections', '/obstacles/fused')
MATCH_IOU = 0.5        # a detection is a true box's when their IoU is at least this
MATCH_RADIUS = 1.0     # a fused circle is that true circle when its centre is this close [m]
STAMP_TOL_NS = 1000    # an image's truth: the truth stamped within this of it [ns]
VISION_FIGURES = ('detection_precision', 'detection_recall', 'detection_frames',
                  'fusion_position_error_rms_m', 'fusion_latency_p50_ms',
                  'fusion_latency_p99_ms')
#: The plugins whose node draws the world, and the detector's.
CAMERA_PLUGIN, DETECTOR_PLUGIN = 'sim_camera', 'detector'

Messages = dict[str, list[tuple[int, Any]]]
Box = tuple[float, float, float, float]  # x_min, y_min, x_max, y_max [px], pixel edges


class TruthBox(NamedTuple):
    """One obstacle's box in a frame: its index in the world, class, box and pixels shown."""

    index: int
    class_id: int
    box: Box
    pixels: int


class Tally(NamedTuple):
    """Matches, detections and counted true boxes (``precision_recall``'s counts)."""

    matched: int
    detections: int
    truths: int


def label_boxes(labels: NDArray[Any]) -> dict[int, tuple[Box, int]]:
    """Return each obstacle's pixel bounding box and pixel count in a label image.

    ``labels``: (H, W) obstacle indices (negative: water or sky). The box's corners are at
    pixel edges: a box of the top-left pixel alone is (0, 0, 1, 1).
    """
    out: dict[int, tuple[Box, int]] = {}
    for index in np.unique(labels):
        if index < 0:
            continue
        rows, cols = np.nonzero(labels == index)
        out[int(index)] = ((float(cols.min()), float(rows.min()), float(cols.max() + 1),
                            float(rows.max() + 1)), len(rows))
    return out


def iou(a: Box, b: Box) -> float:
    """Intersection over union of two boxes (0 when either is empty)."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(0.0, w) * max(0.0, h)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0.0 else 0.0


def match_frame(truths: Sequence[TruthBox], found: Sequence[tuple[int, Box]],
                min_pixels: int, min_iou: float = MATCH_IOU) -> Tally:
    """Match one frame's detections ``(class_id, box)`` with its true boxes, one to one.

    Pairs of one class with IoU at least ``min_iou`` are taken greedily, largest IoU first.
    True boxes of fewer than ``min_pixels`` pixels are not counted, and a detection paired
    with one is left out (neither a match nor a false detection).
    """
    pairs = sorted(((iou(t.box, box), i, j) for i, t in enumerate(truths)
                    for j, (cls, box) in enumerate(found) if cls == t.class_id),
                   reverse=True)
    used_t: set[int] = set()
    used_d: set[int] = set()
    matched = ignored = 0
    for score, i, j in pairs:
        if score < min_iou:
            break
        if i in used_t or j in used_d:
            continue
        used_t.add(i)
        used_d.add(j)
        if truths[i].pixels >= min_pixels:
            matched += 1
        else:
            ignored += 1
    counted = sum(t.pixels >= min_pixels for t in truths)
    return Tally(matched, len(found) - ignored, counted)


def precision_recall(tallies: Sequence[Tally]) -> tuple[float | None, float | None]:
    """Precision and recall over frames (None where nothing was detected, or nothing shown)."""
    m = sum(t.matched for t in tallies)
    d = sum(t.detections for t in tallies)
    n = sum(t.truths for t in tallies)
    return (m / d if d else None), (m / n if n else None)


def colour_classes(world: World, classes: Sequence[Any]) -> list[int]:
    """Return each obstacle's class: the first HSV box its colour falls in (-1: none).

    ``classes``: the classical back end's ``ColourClass``es, in ``class_names`` order.
    """
    import cv2

    from enbarr_core.vision.classical import mask
    out = []
    for o in world.obstacles:
        bgr = np.array([[o.colour[::-1]]], dtype=np.uint8)
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        out.append(next((k for k, c in enumerate(classes) if mask(hsv, c)[0, 0]), -1))
    return out


def _node_values(profile: Any, plugin: str, specs: Sequence[Any]) -> dict[str, Any] | None:
    """Return a plugin's node's parameter values in the profile (defaults filled), or None."""
    for n in profile.nodes:
        if n.plugin == plugin:
            merged = {**profile.parameters, **n.parameters}
            return {s.name: merged.get(s.name, s.default) for s in specs}
    return None


def sees(profile: Any) -> bool:
    """Whether the profile has a simulated camera drawing the world and a classical detector."""
    return any(n.plugin == CAMERA_PLUGIN for n in profile.nodes) and \
        any(n.plugin == DETECTOR_PLUGIN for n in profile.nodes)


def vision_figures(msgs: Messages, profile: Any, t: np.ndarray, eta: np.ndarray,
                   epoch_s: float) -> dict[str, Any]:
    """Compute the vision figures (module docstring) of a run.

    ``t``, ``eta``: the truth's stamps [s] and poses; ``epoch_s``: the world's time 0 on that
    clock.
    """
    from enbarr_core.vision.detector_node import DetectorSettings
    from enbarr_core.vision.detector_node import SPECS as DETECTOR_SPECS
    from enbarr_interfaces import topics
    from enbarr_plugins.camera.sim import SimCameraSettings
    from enbarr_plugins.camera.sim import SPECS as CAMERA_SPECS
    from enbarr_plugins.camera.sim_render import Look, SimulatedCamera

    out: dict[str, Any] = dict.fromkeys(VISION_FIGURES)
    world: World = profile.world
    cam_v = _node_values(profile, CAMERA_PLUGIN, CAMERA_SPECS)
    det_v = _node_values(profile, DETECTOR_PLUGIN, DETECTOR_SPECS)
    detections = msgs.get('/detections', [])
    if cam_v is not None and det_v is not None and det_v['backend'] == 'classical' \
            and detections and len(t):
        cam_s = SimCameraSettings.from_params(cam_v)
        det_s = DetectorSettings.from_params(det_v)
        classes = colour_classes(world, det_s.detector.classes)  # type: ignore[attr-defined]
        camera = SimulatedCamera(cam_s.model, profile.frames.lookup(topics.BODY_FRAME,
                                                                    cam_s.frame_id),
                                 Look(seed=cam_s.seed))
        t_ns = np.round(t * 1e9).astype(np.int64)
        tallies = []
        for _, m in detections:
            stamp = convert.stamp_to_ns(m.header.stamp)
            k = int(np.clip(np.searchsorted(t_ns, stamp), 0, len(t_ns) - 1))
            if abs(int(t_ns[k]) - stamp) > STAMP_TOL_NS:
                continue  # no truth for this image: not judged
            x, y, psi = eta[k]
            labels = camera.render(world, x, y, psi, stamp * 1e-9 - epoch_s).labels
            truths = [TruthBox(i, classes[i], box, px)
                      for i, (box, px) in label_boxes(labels).items() if classes[i] >= 0]
            rows = detection_msg.from_cloud(m)
            found = [(int(r['class_id']), (float(r['x_min']), float(r['y_min']),
                                           float(r['x_max']), float(r['y_max'])))
                     for r in rows]
            tallies.append(match_frame(truths, found, int(math.ceil(det_v['min_area']))))
        precision, recall = precision_recall(tallies)
        out['detection_precision'] = None if precision is None else round(precision, 4)
        out['detection_recall'] = None if recall is None else round(recall, 4)
        out['detection_frames'] = len(tallies)
    fused = msgs.get('/obstacles/fused', [])
    out['fusion_position_error_rms_m'] = fusion_position_error(
        [o for _, m in fused for o in obstacle_msg.from_cloud(m)], world, epoch_s)
    lat = fusion_latencies(detections, fused)
    if lat:
        out['fusion_latency_p50_ms'] = round(float(np.percentile(lat, 50)) * 1e3, 3)
        out['fusion_latency_p99_ms'] = round(float(np.percentile(lat, 99)) * 1e3, 3)
    return out


def fusion_position_error(fused: Sequence[obstacle_msg.Obstacle], world: World,
                          epoch_s: float) -> float | None:
    """RMS distance [m] of each classed circle to the nearest true circle at its stamp."""
    circles = [i for i, o in enumerate(world.obstacles) if isinstance(o.shape, Circle)]
    err: list[float] = []
    for o in fused:
        if o.class_id == obstacle_msg.NO_CLASS or o.kind != obstacle_msg.CIRCLE:
            continue
        shapes = world.shapes_at(o.stamp_ns * 1e-9 - epoch_s)
        best = MATCH_RADIUS
        for i in circles:
            centre = shapes[i].center  # type: ignore[union-attr]
            best = min(best, math.hypot(o.x - centre[0], o.y - centre[1]))
        if best < MATCH_RADIUS:
            err.append(best)
    return round(float(np.sqrt(np.mean(np.square(err)))), 4) if err else None


def fusion_latencies(detections: Sequence[tuple[int, Any]],
                     fused: Sequence[tuple[int, Any]]) -> list[float]:
    """Ages [s] of the images with detections when their classes were first published.

    ``detections``, ``fused``: ``(receive time ns, message)`` in receive order.
    """
    times = np.array([tr for tr, m in fused if any(
        o.class_id != obstacle_msg.NO_CLASS for o in obstacle_msg.from_cloud(m))],
        dtype=np.int64)
    out: list[float] = []
    for tr, m in detections:
        if not m.width:
            continue
        k = int(np.searchsorted(times, tr))
        if k < len(times):
            out.append((int(times[k]) - convert.stamp_to_ns(m.header.stamp)) * 1e-9)
    return out
