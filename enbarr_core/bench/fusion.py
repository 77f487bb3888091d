"""``enbarr bench --fusion``: the CPU one detections message costs the fusion node.

A scene of ``obstacles`` circle obstacles round the CS Saucer (every other one ahead, within
the camera's view, the rest astern or abeam) and a basin wall, the camera of
``saucer_core.yaml`` (its mount) with a 640 x 480 pinhole of 500 px focal length. Each
detections message holds a box on each obstacle in view (its projection, shifted a few pixels)
and one stray box; the obstacles drift so every message projects afresh. Timed by this
thread's CPU clock, as the node runs them (the executor and DDS are not in the figure):

- ``ms_per_detections_p50/p90/max``: decoding the detections message, projecting, assigning,
  voting;
- ``ms_per_obstacles_p50``: republishing an obstacles message with the classes (decode,
  classes, encode), at the lidar's rate;
- ``core_fraction``: p50 x 15 detections/s + republish p50 x 5.5 obstacles/s, and
  ``pi4_core_fraction_estimate`` x 6 (``docs/benchmarks.md``: a Raspberry Pi 4 core against
  this machine's);
- ``matched_last``: matches of the last message (to check the scene is the intended one).
"""

from __future__ import annotations

from dataclasses import replace
import math
import time
from typing import Any

import numpy as np

DETECTION_HZ = 15.0
SCAN_HZ = 5.5
#: Raspberry Pi 4 core time per core time here (docs/benchmarks.md, the Pi budget).
PI4_FACTOR = 6.0
DEFAULT_OBSTACLES = 10
DEFAULT_MESSAGES = 300


def measure(obstacles: int = DEFAULT_OBSTACLES,
            messages: int = DEFAULT_MESSAGES) -> dict[str, Any]:
    """Fuse ``messages`` detections messages against ``obstacles`` obstacles (docstring)."""
    from enbarr_core.framework.frames import Transform
    from enbarr_core.vision.fusion import (
        Camera, ClassMemory, detected_boxes, fuse, FusionSettings, project_obstacle)
    from enbarr_interfaces import detections as det
    from enbarr_interfaces.obstacles import (
        CIRCLE, from_cloud, Obstacle, SEGMENT, to_cloud)

    # saucer_core.yaml's camera: camera_link at (-0.08, 0, 0.25), REP-103's optical rotation
    mount = Transform.from_rpy((-0.08, 0.0, 0.25), (-math.pi / 2, 0.0, -math.pi / 2))
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    camera = Camera(k, np.array([-0.05, 0.01, 0.0, 0.0, 0.0]), 640, 480,
                    mount.inverse().matrix)
    settings = FusionSettings()
    memory = ClassMemory()
    eta = np.zeros(3)
    rng = np.random.default_rng(0)
    cpu_det, cpu_obs = [], []
    matched = 0
    for m in range(messages):
        stamp = round(m / DETECTION_HZ * 1e9)
        drift = 0.2 * math.sin(0.05 * m)
        scene = []
        for i in range(obstacles):
            ahead = i % 2 == 0
            bearing = (-0.4 + 0.8 * i / max(1, obstacles - 1)) if ahead else \
                math.pi - 0.5 + i * 0.1
            dist = 2.0 + 0.4 * i
            scene.append(Obstacle(i, CIRCLE, dist * math.cos(bearing),
                                  dist * math.sin(bearing) + drift, 0.15, vx=0.0, vy=0.1,
                                  stamp_ns=stamp))
        scene.append(Obstacle(obstacles, SEGMENT, -20.0, 3.2, 0.0, x2=20.0, y2=3.2,
                              stamp_ns=stamp))
        rows = []
        for o in scene:
            box = project_obstacle(o, eta, camera, settings)
            if box is not None:
                jx, jy = rng.normal(0.0, 2.0, 2)
                rows.append((3, 0.9, box.x_min + jx, box.y_min + jy, box.x_max + jx,
                             box.y_max + jy))
        rows.append((0, 0.5, 10.0, 10.0, 40.0, 40.0))
        det_msg = det.to_cloud(rows, stamp, 'camera_optical_frame')
        obs_msg = to_cloud(scene, stamp, 'odom')
        start = time.thread_time()
        out = fuse(scene, eta, stamp, camera, detected_boxes(det.from_cloud(det_msg)),
                   settings, memory)
        mid = time.thread_time()
        decoded = from_cloud(obs_msg)
        classed = []
        for o in decoded:
            voted = memory.of(o.id)
            classed.append(o if voted is None else
                           replace(o, class_id=voted[0], class_score=voted[1]))
        to_cloud(classed, stamp, 'odom', classes=True)
        end = time.thread_time()
        cpu_det.append(mid - start)
        cpu_obs.append(end - mid)
        matched = len(out.matches)
    ms = np.array(cpu_det[10:]) * 1e3
    obs_ms = np.array(cpu_obs[10:]) * 1e3
    p50 = float(np.median(ms))
    obs_p50 = float(np.median(obs_ms))
    core = p50 * 1e-3 * DETECTION_HZ + obs_p50 * 1e-3 * SCAN_HZ
    return {'benchmark': 'fusion', 'messages': messages, 'obstacles': obstacles,
            'ms_per_detections_p50': round(p50, 3),
            'ms_per_detections_p90': round(float(np.percentile(ms, 90)), 3),
            'ms_per_detections_max': round(float(ms.max()), 3),
            'ms_per_obstacles_p50': round(obs_p50, 3),
            'core_fraction': round(core, 5),
            'pi4_core_fraction_estimate': round(core * PI4_FACTOR, 4),
            'matched_last': matched}
