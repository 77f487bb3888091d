"""Small ONNX graphs for the detector's tests and its benchmark, built with ``onnx.helper``.

``yolo_graph(path, table, ...)`` writes a model whose output is ``table`` exactly, whatever the
image: ``images`` [1, 3, H, W] goes through a 1 x 1 convolution of stride ``stride`` with zero
weights (so the input is really read, the way a detector's backbone would), reshaped to
[1, C, N] and added to ``table``; ``layout='yolov5'`` transposes it to [1, N, C]. Run as a
script it writes the benchmark's graph (``docs/benchmarks.md``, vision)::

    .venv/bin/python test/support/onnx_graphs.py /tmp/yolo_bench.onnx
"""

from __future__ import annotations

from pathlib import Path
import sys

import numpy as np
import onnx
from onnx import helper, numpy_helper, TensorProto

OPSET = 13


def yolo_graph(path: Path | str, table: np.ndarray, input_size: tuple[int, int],
               stride: int, layout: str = 'yolov8') -> Path:
    """Write the model; ``table`` is [C, N] with N = (H / stride) x (W / stride)."""
    w, h = input_size
    c, n = table.shape
    assert n == (h // stride) * (w // stride), 'table columns must match the output grid'
    nodes = [
        helper.make_node('Conv', ['images', 'weight'], ['grid'], kernel_shape=[1, 1],
                         strides=[stride, stride]),
        helper.make_node('Reshape', ['grid', 'shape'], ['flat']),
        helper.make_node('Add', ['flat', 'table'], ['boxes' if layout == 'yolov8' else 'rows']),
    ]
    out_shape = [1, c, n]
    if layout == 'yolov5':
        nodes.append(helper.make_node('Transpose', ['rows'], ['boxes'], perm=[0, 2, 1]))
        out_shape = [1, n, c]
    inits = [
        numpy_helper.from_array(np.zeros((c, 3, 1, 1), np.float32), 'weight'),
        numpy_helper.from_array(np.array([1, c, n], np.int64), 'shape'),
        numpy_helper.from_array(table[None].astype(np.float32), 'table'),
    ]
    graph = helper.make_graph(
        nodes, 'yolo_table',
        [helper.make_tensor_value_info('images', TensorProto.FLOAT, [1, 3, h, w])],
        [helper.make_tensor_value_info('boxes', TensorProto.FLOAT, out_shape)], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', OPSET)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    path = Path(path)
    onnx.save(model, str(path))
    return path


def bench_graph(path: Path | str, classes: int = 80) -> Path:
    """A stand-in for a stock YOLOv8 export at 640 x 640: [1, 4 + 80, 6400].

    YOLOv8 has 8400 candidates from three strides; one 1 x 1 convolution of stride 8 gives
    80 x 80 = 6400, the same order. As a trained model does on a scene with ten objects, about
    a hundred candidates score above 0.25, ten around each object (for the suppression to
    merge), the rest below 0.1.
    """
    rng = np.random.default_rng(0)
    n = 80 * 80
    table = np.zeros((4 + classes, n), np.float32)
    table[0:2] = rng.uniform(20, 620, (2, n))
    table[2] = rng.uniform(10, 60, n)
    table[3] = rng.uniform(20, 120, n)
    table[4:] = rng.uniform(0.0, 0.1, (classes, n))
    picks = rng.choice(n, 100, replace=False)
    for k, i in enumerate(picks):
        obj = k % 10
        cx, cy = 60 + 55 * obj, 100 + 40 * obj
        table[0:4, i] = (cx + rng.normal(0, 3), cy + rng.normal(0, 3), 40 + rng.normal(0, 2),
                         90 + rng.normal(0, 4))
        table[4 + obj % classes, i] = rng.uniform(0.3, 0.95)
    return yolo_graph(path, table, (640, 640), 8)


if __name__ == '__main__':
    print(bench_graph(sys.argv[1]))
