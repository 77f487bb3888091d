"""The emulated camera's test video: a pattern that survives Motion-JPEG, written by OpenCV.

``write_test_video`` writes a test pattern (colour bars, a moving bar and the frame number,
in digits and as 16 black/white blocks along the top edge that survive JPEG compression)
with ``cv2.VideoWriter`` (Motion-JPEG in AVI, which every OpenCV build reads back).
``read_counter`` decodes the blocks: a test checks which frame it got.

``write_in_child`` writes it from a child process (``python -m enbarr_plugins.camera.pattern_video
DIR WIDTH HEIGHT RATE FRAMES``): the encoder leaves memory behind in the process that ran it
(FFmpeg's encoder, OpenCV's worker threads; ``malloc_trim`` gives little of it back:
``docs/benchmarks.md``), which the camera emulator must not add to a vessel process: a real camera
adds nothing of the kind. This module imports OpenCV and numpy only.
"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

import cv2
import numpy as np

BITS = 16       # frame counter bits along the top edge
BLOCK = 16      # [px] per bit


def test_pattern(index: int, width: int, height: int) -> np.ndarray:
    """Return frame ``index`` of the test pattern (bgr8)."""
    bars = np.array([[255, 255, 255], [0, 255, 255], [255, 255, 0], [0, 255, 0],
                     [255, 0, 255], [0, 0, 255], [255, 0, 0], [0, 0, 0]], dtype=np.uint8)
    columns = (np.arange(width) * len(bars) // width)
    frame = np.repeat(bars[columns][np.newaxis], height, axis=0)
    x = (index * 8) % max(1, width)
    frame[height // 2:, x:x + 8] = 128
    cv2.putText(frame, str(index), (width // 8, height * 3 // 4), cv2.FONT_HERSHEY_SIMPLEX,
                max(1.0, height / 160), (255, 255, 255), 3)
    frame[:BLOCK, :BITS * BLOCK] = 0
    for bit in range(BITS):
        if index >> bit & 1:
            frame[:BLOCK, bit * BLOCK:(bit + 1) * BLOCK] = 255
    return frame


def read_counter(frame: np.ndarray) -> int:
    """Return the frame number the top-edge blocks of ``frame`` encode."""
    value = 0
    for bit in range(BITS):
        block = frame[2:BLOCK - 2, bit * BLOCK + 2:(bit + 1) * BLOCK - 2]
        if block.mean() > 127:
            value |= 1 << bit
    return value


def write_test_video(directory: str, width: int, height: int, frame_rate: float,
                     frames: int) -> str:
    """Write ``frames`` test-pattern frames to ``directory``/test_pattern.avi; return the path.

    Written beside and renamed into place, so a reader never opens a half-written file.
    """
    path = os.path.join(directory, 'test_pattern.avi')
    partial = os.path.join(directory, 'test_pattern.partial.avi')
    writer = cv2.VideoWriter(partial, cv2.VideoWriter_fourcc(*'MJPG'), frame_rate,
                             (width, height))
    if not writer.isOpened():
        raise OSError(f'{partial}: OpenCV cannot write Motion-JPEG AVI')
    try:
        for i in range(frames):
            writer.write(test_pattern(i, width, height))
    finally:
        writer.release()
    os.replace(partial, path)
    return path


def child_environment() -> dict[str, str]:
    """Return this environment with the copy of the package running here first on the path.

    The child then runs this very code even where another copy is installed (a source tree
    run beside an installed one, pytest's root directory on ``sys.path``).
    """
    root = str(Path(__file__).resolve().parents[2])  # the directory holding enbarr_plugins
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (root, env.get('PYTHONPATH')) if p)
    return env


def write_in_child(directory: str, width: int, height: int, frame_rate: float,
                   frames: int, timeout: float = 120.0) -> str:
    """``write_test_video`` in a child process; return the path. ``OSError`` names a failure."""
    args = [sys.executable, '-m', __name__, directory, str(width), str(height),
            repr(float(frame_rate)), str(frames)]
    try:
        done = subprocess.run(args, env=child_environment(), capture_output=True, text=True,
                              timeout=timeout, check=False)
    except subprocess.TimeoutExpired as err:
        raise OSError(f'{directory}: writing the test video took over {timeout:g} s') from err
    if done.returncode != 0:
        lines = (done.stderr or '').strip().splitlines()
        raise OSError(lines[-1] if lines else
                      f'{directory}: the test video writer exited with {done.returncode}')
    return done.stdout.strip().splitlines()[-1]


def main(argv: list[str]) -> int:
    """Write the test video (arguments: DIR WIDTH HEIGHT RATE FRAMES); print its path."""
    if len(argv) != 5:
        print('usage: python -m enbarr_plugins.camera.pattern_video '
              'DIR WIDTH HEIGHT RATE FRAMES', file=sys.stderr)
        return 2
    directory, width, height, rate, frames = argv
    try:
        path = write_test_video(directory, int(width), int(height), float(rate), int(frames))
    except (OSError, ValueError) as err:
        print(f'OSError: {err}', file=sys.stderr)
        return 1
    print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
