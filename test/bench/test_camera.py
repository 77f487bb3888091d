"""``enbarr bench --camera``: what it measures (the ca_buoy scene from the CS Saucer's camera,
the JPEG it encodes, the PNG it writes), and its refusals. Timing itself is the benchmark's
business, not a test's.
"""

from __future__ import annotations

import math

import cv2
import pytest

from enbarr_core.bench import camera
from enbarr_core.commands.main import main

pytestmark = pytest.mark.unit


def test_the_scene_is_the_ca_buoy_scene_and_the_figures_add_up(tmp_path):
    png = tmp_path / 'frame.png'
    figures = camera.measure(12, 80, 'ca_buoy', str(png))
    assert figures['frames'] == 12 and figures['size'] == '640x480'
    # 640 x 480 x 3 bytes at 15 fps: 13.8 MB/s raw
    assert figures['raw_mb_per_s'] == pytest.approx(13.8, abs=0.05)
    assert 0.0 < figures['jpeg_mb_per_s'] < figures['raw_mb_per_s'] / 5
    for key in ('render_ms_p50', 'render_ms_p90', 'jpeg_ms_p50', 'jpeg_ms_p90'):
        assert math.isfinite(figures[key]) and figures[key] > 0.0
    assert figures['pi4_jpeg_core_fraction_estimate'] == pytest.approx(
        figures['jpeg_core_fraction_at_15_hz'] * 6.0, abs=0.01)
    image = cv2.imread(str(png))
    assert image.shape == (480, 640, 3)
    # the buoy of ca_buoy: 1 m ahead of the CO, orange (BGR: red high, blue low) at the
    # centre of the image
    b, g, r = image[200:280, 300:340].reshape(-1, 3).mean(axis=0)
    assert r > 120 and b < 60


@pytest.mark.parametrize('args, says', [
    (['--camera', '--frames', '5'], '--frames must be >= 10'),
    (['--camera', '--quality', '0'], '--quality 1..100'),
    (['--camera', '--rate', '5'], '--rate is not for --camera'),
    (['--perception', '--frames', '100'], '--frames is for --camera'),
    (['--chain', 'rov', '--png', 'x.png'], '--png is for --camera'),
])
def test_camera_options_are_refused_elsewhere(args, says, capsys):
    assert main(['bench', *args]) != 0
    assert says in capsys.readouterr().err
