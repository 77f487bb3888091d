"""``enbarr bench --vision``: what it measures (the frames it draws give the buoys they should;
the stand-in model's boxes survive suppression as ten objects), and its refusals. Timing
itself is the benchmark's business, not a test's.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.onnx_graphs import bench_graph, yolo_graph

from enbarr_core.bench import vision
from enbarr_core.commands.main import main
from enbarr_core.vision.synthetic import scene



def test_the_frames_and_the_model_are_what_the_benchmark_claims_to_measure(tmp_path):
    figures = vision.measure(20, str(bench_graph(tmp_path / 'bench.onnx')))
    rng = np.random.default_rng(0)   # the benchmark's first frames: it finds their buoys
    buoys = [len(scene(rng)[1]) for _ in range(vision.SCENES)]
    assert figures['classical']['detections'] == sum(buoys)
    assert figures['onnx']['detections'] == 20 * 10       # ten objects in every frame
    for backend in ('classical', 'onnx'):
        f = figures[backend]
        for key in ('ms_per_frame_p50', 'ms_per_frame_p90', 'ms_per_frame_max'):
            assert math.isfinite(f[key]) and f[key] > 0.0
        assert f['pi4_core_fraction_estimate'] == pytest.approx(
            f['core_fraction_at_15_hz'] * 6.0, rel=2e-2, abs=1e-3)  # printed to 0.001


def test_the_command_prints_one_json_line(capsys):
    assert main(['bench', '--vision', '--frames', '10']) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures['benchmark'] == 'vision' and 'onnx' not in figures


def test_a_model_of_another_shape_is_refused_naming_it(tmp_path, capsys):
    path = yolo_graph(tmp_path / 'small.onnx', np.zeros((7, 64), np.float32), (64, 64), 8)
    assert main(['bench', '--vision', '--frames', '10', '--model', str(path)]) != 0
    err = capsys.readouterr().err
    assert '--model: ' in err and 'small.onnx' in err


@pytest.mark.parametrize('args, says', [
    (['--vision', '--frames', '5'], '--frames must be >= 10'),
    (['--vision', '--scans', '100'], '--scans is not for --vision'),
    (['--perception', '--frames', '100'], '--frames is for --camera, --vision and --fusion'),
    (['--camera', '--model', 'x.onnx'], '--model is for --vision'),
    (['--chain', 'rov', '--model', 'x.onnx'], '--model is for --vision'),
])
def test_vision_options_are_refused_elsewhere(args, says, capsys):
    assert main(['bench', *args]) != 0
    assert says in capsys.readouterr().err
