"""``enbarr bench --camera``: the CPU one camera frame costs, rendered and encoded.

The scene is a scenario's or a profile's (default the scenario ``ca_buoy``: the CS Saucer's
frame tree, so the camera's mount of ``saucer_core.yaml``, and its world: the basin walls and
the buoy ahead), seen by ``sim_camera``'s default camera (640 x 480, 500 px, the mild barrel)
from the vessel turning slowly at the start of the path, one frame per 1/15 s of scene time.
Each frame is timed by this thread's CPU clock (the executor and DDS are not in the figure),
in three parts:

- ``render_ms_p50/p90``: ``SimulatedCamera.render`` (what only the simulation pays);
- ``jpeg_ms_p50/p90``: ``common.encode_jpeg`` at ``--quality`` (what the real camera pays on
  the Pi for camera/image_raw/compressed); ``jpeg_kb_mean``: its size;
- ``raw_copy_ms_p50``: the ``tobytes`` copy of a raw bgr8 Image message;
- ``*_core_fraction_at_15_hz``: p50 x 15 frames/s, and the Raspberry Pi 4 estimates x 6
  (``docs/benchmarks.md``: a Pi 4 core against this machine's);
- ``jpeg_mb_per_s`` and ``raw_mb_per_s``: the two streams' rates at 15 frames/s.

``--png PATH`` writes the first frame as a PNG (the picture in ``docs/``).
"""

from __future__ import annotations

import math
import time
from typing import Any

import cv2
import numpy as np

from enbarr_interfaces import topics

#: Raspberry Pi 4 core time per core time here (docs/benchmarks.md, the Pi budget).
PI4_FACTOR = 6.0
RATE_HZ = 15.0
DEFAULT_FRAMES = 150
DEFAULT_QUALITY = 80
DEFAULT_PROFILE = 'ca_buoy'


def measure(frames: int = DEFAULT_FRAMES, quality: int = DEFAULT_QUALITY,
            profile: str = DEFAULT_PROFILE, png: str | None = None) -> dict[str, Any]:
    """Render and encode ``frames`` frames of ``profile``'s scene; return the figures."""
    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.tools.scenario import known_scenarios, resolve
    from enbarr_plugins.camera.common import encode_jpeg
    from enbarr_plugins.camera.sim import SPECS
    from enbarr_plugins.camera.sim_render import Look, PinholeModel, SimulatedCamera

    p = load_profile(resolve(profile) if profile in known_scenarios() else profile)
    default = {s.name: s.default for s in SPECS}
    model = PinholeModel.nominal(default['width'], default['height'],
                                 default['focal_length'], default['distortion'])
    mount = p.frames.lookup(topics.BODY_FRAME, topics.CAMERA_OPTICAL_FRAME)
    camera = SimulatedCamera(model, mount, Look(seed=default['seed']))
    render_ms, jpeg_ms, copy_ms, sizes = [], [], [], []
    for k in range(frames):
        t = k / RATE_HZ
        psi = 0.15 * math.sin(0.4 * t)  # turning gently: the water and the buoy move
        c0 = time.thread_time_ns()
        frame = camera.render(p.world, 0.1 * t, 0.0, psi, t, labels=False)
        c1 = time.thread_time_ns()
        data = encode_jpeg(frame.image, quality)
        c2 = time.thread_time_ns()
        frame.image.tobytes()
        c3 = time.thread_time_ns()
        render_ms.append((c1 - c0) * 1e-6)
        jpeg_ms.append((c2 - c1) * 1e-6)
        copy_ms.append((c3 - c2) * 1e-6)
        sizes.append(len(data))
        if k == 0 and png:
            if not cv2.imwrite(png, frame.image, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
                raise OSError(f'{png}: cannot write the PNG')
    render, jpeg = float(np.median(render_ms)), float(np.median(jpeg_ms))
    raw_bytes = model.width * model.height * 3
    return {
        'profile': profile, 'frames': frames, 'size': f'{model.width}x{model.height}',
        'quality': quality,
        'render_ms_p50': round(render, 2),
        'render_ms_p90': round(float(np.percentile(render_ms, 90)), 2),
        'jpeg_ms_p50': round(jpeg, 2),
        'jpeg_ms_p90': round(float(np.percentile(jpeg_ms, 90)), 2),
        'raw_copy_ms_p50': round(float(np.median(copy_ms)), 3),
        'jpeg_kb_mean': round(float(np.mean(sizes)) / 1024.0, 1),
        'render_core_fraction_at_15_hz': round(render * 1e-3 * RATE_HZ, 3),
        'jpeg_core_fraction_at_15_hz': round(jpeg * 1e-3 * RATE_HZ, 3),
        'pi4_render_core_fraction_estimate': round(render * 1e-3 * RATE_HZ * PI4_FACTOR, 2),
        'pi4_jpeg_core_fraction_estimate': round(jpeg * 1e-3 * RATE_HZ * PI4_FACTOR, 2),
        'jpeg_mb_per_s': round(float(np.mean(sizes)) * RATE_HZ / 1e6, 2),
        'raw_mb_per_s': round(raw_bytes * RATE_HZ / 1e6, 1),
    }
