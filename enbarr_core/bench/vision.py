"""``enbarr bench --vision``: the CPU one camera frame costs the detector's back ends.

Frames: 640 x 480 scenes of ``enbarr_core.vision.synthetic`` (textured water, a wall, a boat,
one to four buoys), drawn ahead of the measurement. Each frame goes through what the
``detector`` node runs per frame, less the message conversion: the back end's ``detect`` and
the encoding of ``detections``, timed by this thread's CPU clock (the executor and DDS are not
in the figure). With ``--model PATH`` the same frames go through an ONNX model as well, at the
node's defaults (YOLOv8 layout, 640 x 640 input, 80 classes: a stock YOLOv8 export; the
stand-in graph of ``test/support/onnx_graphs.py`` has that shape, ``docs/benchmarks.md``).

One JSON line: for each back end, ``ms_per_frame_p50/p90/max``, ``core_fraction_at_15_hz``
(p50 x 15, the camera driver's default rate) and ``pi4_core_fraction_estimate`` (x 6,
``docs/benchmarks.md``: a Raspberry Pi 4 core against this machine's); ``detections``: the
boxes of all frames (to check the scene is the intended one). The ONNX entry adds
``stages_ms_p50``: the letterbox and blob, the forward pass, decoding and suppression.

CPU is the process's (``time.process_time``), not this thread's: OpenCV runs its resize,
colour conversion and dnn layers on a pool of worker threads (``cv2.getNumThreads()``),
whose work a thread clock would leave out. Run it alone.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from enbarr_core.bench.perception import PI4_FACTOR

RATE_HZ = 15.0
SCENES = 20
#: The model a stock YOLOv8 export is: what --model is run with.
MODEL_INPUT = (640, 640)
MODEL_CLASSES = 80


def _run(detect: Any, frames: list[np.ndarray], count: int) -> dict[str, Any]:
    from enbarr_interfaces.detections import to_cloud
    cpu = []
    found = 0
    for k in range(count):
        start = time.process_time()
        boxes = detect(frames[k % len(frames)])
        to_cloud([(d.class_id, d.score, d.x_min, d.y_min, d.x_max, d.y_max) for d in boxes],
                 k, 'camera_optical_frame')
        cpu.append(time.process_time() - start)
        found += len(boxes)
    ms = np.array(cpu[min(5, count // 2):]) * 1e3      # after the first calls' allocations
    p50 = float(np.median(ms))
    return {'ms_per_frame_p50': round(p50, 3),
            'ms_per_frame_p90': round(float(np.percentile(ms, 90)), 3),
            'ms_per_frame_max': round(float(ms.max()), 3),
            'core_fraction_at_15_hz': round(p50 * 1e-3 * RATE_HZ, 4),
            'pi4_core_fraction_estimate': round(p50 * 1e-3 * RATE_HZ * PI4_FACTOR, 3),
            'detections': found}


def measure(frames: int = 200, model: str | None = None) -> dict[str, Any]:
    """Run ``frames`` frames through the back ends; the JSON line's dict (module docstring)."""
    from enbarr_core.vision.detector_node import DetectorSettings, SPECS
    from enbarr_core.vision.onnx_model import OnnxDetector, OnnxSettings
    from enbarr_core.vision.synthetic import scene

    rng = np.random.default_rng(0)
    images = [scene(rng)[0] for _ in range(SCENES)]
    defaults = {s.name: s.default for s in SPECS}
    classical = DetectorSettings.from_params(defaults).detector
    out: dict[str, Any] = {'benchmark': 'vision', 'frames': frames, 'width': 640,
                           'height': 480, 'classical': _run(classical.detect, images, frames)}
    if model is not None:
        onnx = OnnxDetector(OnnxSettings(
            model_path=model, layout=defaults['layout'], classes=MODEL_CLASSES,
            input_size=MODEL_INPUT, score_threshold=defaults['score_threshold'],
            iou_threshold=defaults['iou_threshold'],
            max_detections=defaults['max_detections']))
        out['onnx'] = {'model': model, **_run(onnx.detect, images, frames),
                       'stages_ms_p50': _stages(onnx, images, frames)}
    return out


def _stages(onnx: Any, frames: list[np.ndarray], count: int) -> dict[str, float]:
    """Median CPU [ms] of each stage of ``OnnxDetector.detect``, taken apart."""
    from enbarr_core.vision.detection import decode, detections, suppress
    from enbarr_core.vision.onnx_model import preprocess
    s = onnx.settings
    cpu = []
    for k in range(count):
        image = frames[k % len(frames)]
        t0 = time.process_time()
        blob, letterbox = preprocess(image, s.input_size)
        t1 = time.process_time()
        output = onnx.forward(blob)
        t2 = time.process_time()
        c = decode(output, s.layout, s.classes, s.score_threshold)
        detections(c, suppress(c, s.score_threshold, s.iou_threshold, s.max_detections),
                   letterbox, (image.shape[1], image.shape[0]))
        cpu.append((t1 - t0, t2 - t1, time.process_time() - t2))
    ms = np.median(np.array(cpu[min(5, count // 2):]) * 1e3, axis=0)
    return {'preprocess': round(float(ms[0]), 3), 'forward': round(float(ms[1]), 3),
            'decode_nms': round(float(ms[2]), 3)}
