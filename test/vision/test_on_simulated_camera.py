"""The classical back end, with its default parameters, on the simulated camera's frames
(``enbarr_plugins.camera.sim_render``) of the ``ca_buoy`` scenario: the basin's grey walls and
the world's default buoy, orange, ahead; raw and through the camera's JPEG. The renderer's
label image gives each pixel's obstacle: the true box.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from enbarr_core.vision.detector_node import DetectorSettings, SPECS
from enbarr_plugins.camera import sim_render


def frames():
    from enbarr_core.bringup.profile import load_profile
    from enbarr_core.tools.scenario import resolve
    from enbarr_core.world.model import Circle
    from enbarr_interfaces import topics
    from enbarr_plugins.camera.common import encode_jpeg
    from enbarr_plugins.camera.sim import SPECS as CAMERA_SPECS

    p = load_profile(resolve('ca_buoy'))
    c = {s.name: s.default for s in CAMERA_SPECS}
    model = sim_render.PinholeModel.nominal(c['width'], c['height'], c['focal_length'],
                                            c['distortion'])
    camera = sim_render.SimulatedCamera(
        model, p.frames.lookup(topics.BODY_FRAME, topics.CAMERA_OPTICAL_FRAME),
        sim_render.Look(seed=c['seed']))
    buoys = [i for i, o in enumerate(p.world.obstacles) if isinstance(o.shape, Circle)]
    for k in range(0, 60, 10):
        t = k / 15.0
        frame = camera.render(p.world, 0.1 * t, 0.0, 0.15 * math.sin(0.4 * t), t, labels=True)
        truth = []
        for i in buoys:
            ys, xs = np.nonzero(frame.labels == i)
            truth.append((xs.min(), ys.min(), xs.max() + 1, ys.max() + 1))
        jpeg = cv2.imdecode(np.frombuffer(encode_jpeg(frame.image, c['jpeg_quality']), np.uint8),
                            cv2.IMREAD_COLOR)
        yield frame.image, jpeg, truth


def test_the_default_buoy_is_found_orange_in_raw_and_jpeg_frames():
    detector = DetectorSettings.from_params({s.name: s.default for s in SPECS}).detector
    orange = [s.default for s in SPECS if s.name == 'class_names'][0].index('orange_buoy')
    n = 0
    for raw, jpeg, truth in frames():
        assert len(truth) == 1
        for image in (raw, jpeg):
            found = detector.detect(image)
            assert [d.class_id for d in found] == [orange]
            box = (found[0].x_min, found[0].y_min, found[0].x_max, found[0].y_max)
            assert max(abs(a - b) for a, b in zip(box, truth[0])) <= 2, (box, truth[0])
            n += 1
    assert n == 12
