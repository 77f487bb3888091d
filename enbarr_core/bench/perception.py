"""``enbarr bench --perception``: the CPU one lidar scan costs, scan -> tracked obstacles.

A synthetic basin seen by the CS Saucer's lidar (the manual's Table 1.1: 360 rays, 5.5 Hz,
0.15-12 m, range noise 1 % below 3 m, 2 % to 5 m, 2.5 % beyond): an L of walls, three buoys
(one drifting at up to 0.2 m/s), the vessel moving slowly and turning, poses at 50 Hz. The scans
are cast here, ahead of the measurement. Each scan goes through what the ``scan_obstacles``
node runs per scan: the pipeline (points, posing, breakpoints, fits, tracking) and the
encoding of ``obstacles`` and ``obstacles/markers``, timed by this thread's CPU clock
(the executor and DDS are not in the figure). One JSON line:

- ``ms_per_scan_p50/p90/max``: CPU per scan [ms], the pipeline and ``obstacles``;
- ``markers_ms_per_scan_p50``: the markers besides, built only while a viewer subscribes;
- ``core_fraction_at_5_5_hz``: p50 x 5.5 scans/s, and ``pi4_core_fraction_estimate`` x 6
  (``docs/benchmarks.md``: a Raspberry Pi 4 core against this machine's);
- ``obstacles``, ``clusters``: what the last scan saw (to check the scene is the intended one).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

RAYS = 360
RATE_HZ = 5.5
#: Raspberry Pi 4 core time per core time here (docs/benchmarks.md, the Pi budget).
PI4_FACTOR = 6.0
WALLS = ((-4.0, 6.0, 9.0, 6.0), (9.0, 6.0, 9.0, -6.0))
BUOYS = ((3.0, 1.0, 0.3), (-2.0, -2.0, 0.2), (5.0, -3.0, 0.5))


def scene(t: float) -> tuple[list[tuple[float, float, float]], tuple[float, float, float]]:
    """Return the buoys and the vessel's pose (x, y, psi) at time ``t`` [s]: all in view.

    The first buoy drifts north and back at up to 0.2 m/s; the vessel surges and yaws
    gently about the origin.
    """
    buoys = [(BUOYS[0][0], BUOYS[0][1] + 1.5 * math.sin(0.13 * t), BUOYS[0][2]), *BUOYS[1:]]
    return buoys, (0.5 * math.sin(0.05 * t), 0.0, 0.1 * math.sin(0.3 * t))


def cast(x: float, y: float, psi: float, buoys: list[tuple[float, float, float]],
         rng: np.random.Generator) -> np.ndarray:
    """Ranges of the rays from -pi of a lidar at (x, y) heading psi, with the manual's noise."""
    theta = -math.pi + np.arange(RAYS) * (2.0 * math.pi / RAYS) + psi
    d = np.column_stack((np.cos(theta), np.sin(theta)))
    t = np.full(RAYS, np.inf)
    for cx, cy, r in buoys:
        oc = np.array([x - cx, y - cy])
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        near = -b - np.sqrt(np.maximum(disc, 0.0))
        t = np.where((disc >= 0.0) & (near > 0.0), np.minimum(t, near), t)
    for x1, y1, x2, y2 in WALLS:
        e = np.array([x2 - x1, y2 - y1])
        ao = np.array([x1 - x, y1 - y])
        den = d[:, 0] * e[1] - d[:, 1] * e[0]
        with np.errstate(divide='ignore', invalid='ignore'):
            s = (ao[0] * d[:, 1] - ao[1] * d[:, 0]) / den
            u = (ao[0] * e[1] - ao[1] * e[0]) / den
        hit = (np.abs(den) > 1e-12) & (u > 0.0) & (s >= 0.0) & (s <= 1.0)
        t = np.where(hit, np.minimum(t, u), t)
    finite = np.isfinite(t)
    frac = np.where(t < 3.0, 0.01, np.where(t < 5.0, 0.02, 0.025))
    t[finite] *= 1.0 + frac[finite] * rng.standard_normal(int(finite.sum()))
    t[t > 12.0] = np.inf
    return t


def measure(scans: int = 500) -> dict[str, Any]:
    """Run ``scans`` scans of the scene; the JSON line's dict (module docstring)."""
    from enbarr_core.perception.pipeline import LidarMount, ScanObstacles
    from enbarr_core.perception.scan_geometry import PoseHistory
    from enbarr_core.perception.scan_obstacles_node import markers, ScanObstaclesSettings, SPECS
    from enbarr_interfaces.obstacles import to_cloud

    settings = ScanObstaclesSettings.from_params({s.name: s.default for s in SPECS})
    pipeline = ScanObstacles(settings.perception)
    poses = PoseHistory()
    mount = LidarMount(np.eye(3), np.zeros(3))
    rng = np.random.default_rng(0)
    period = 1.0 / RATE_HZ
    time_increment = period / RAYS
    inputs = []
    for k in range(scans):
        buoys, _ = scene(k * period)
        eta = scene(k * period + 0.5 * period)[1]   # the middle of the revolution
        inputs.append(cast(*eta, buoys, rng))
    cpu = []
    outcome = None
    pose_k = 0
    for k, ranges in enumerate(inputs):
        stamp = round(k * period * 1e9)
        while pose_k * 0.02 <= (k + 1) * period + 0.04:
            x, y, psi = scene(pose_k * 0.02)[1]
            poses.add(round(pose_k * 0.02 * 1e9), x, y, psi)
            pose_k += 1
        start = time.thread_time()
        outcome = pipeline.process(ranges, -math.pi, 2.0 * math.pi / RAYS, time_increment,
                                   stamp, mount, poses)
        to_cloud(outcome.obstacles, stamp, 'odom')
        mid = time.thread_time()
        markers(outcome.obstacles, [], stamp, 'odom')
        cpu.append((mid - start, time.thread_time() - mid))
    both = np.array(cpu[min(20, scans // 2):]) * 1e3   # after the tracks are confirmed
    ms = both[:, 0]
    p50 = float(np.median(ms))
    assert outcome is not None
    return {'benchmark': 'perception', 'scans': scans, 'rays': RAYS,
            'ms_per_scan_p50': round(p50, 3), 'ms_per_scan_p90': round(float(
                np.percentile(ms, 90)), 3), 'ms_per_scan_max': round(float(ms.max()), 3),
            'core_fraction_at_5_5_hz': round(p50 * 1e-3 * RATE_HZ, 5),
            'pi4_core_fraction_estimate': round(p50 * 1e-3 * RATE_HZ * PI4_FACTOR, 4),
            'markers_ms_per_scan_p50': round(float(np.median(both[:, 1])), 3),
            'obstacles': len(outcome.obstacles), 'clusters': outcome.clusters}
