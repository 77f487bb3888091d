"""The simulated camera's checkerboard scene: a board waved in front of the lens (no ROS).

For rehearsing the CS Saucer manual's camera calibration (4.1) without hardware: what the
camera sees is the printed board alone, drawn by ``enbarr_core.vision.board.render_board``
through the camera's TRUE lens (its intrinsics and plumb_bob distortion, whatever camera_info
it publishes), at the poses of a calibration run (``calibration_poses``: across the image,
near and far, tilted). A person holds the board still for a moment, then moves it on: pose
``i`` is held for ``hold`` seconds of the clock, and the run starts over after the last.

The pose of a moment is a function of the clock alone, ``(t // hold) mod n`` with ``t`` the
stamp in nanoseconds: a frame's pose is known from its stamp, whenever the node started.
A held pose gives the same image every frame (no noise), so each is drawn once and kept;
the node draws them all before its first frame, so that a new pose is never late.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from enbarr_core.vision.board import Board, calibration_poses, Camera, Pose, render_board
from enbarr_plugins.camera.sim_render import PinholeModel

#: Scenes the simulated camera draws: the profile's world, or a checkerboard.
SCENES = ('world', 'checkerboard')


@dataclass(frozen=True)
class BoardRun:
    """A board waved in front of the camera: ``poses`` each held ``hold_ns`` in turn."""

    camera: Camera
    board: Board
    poses: tuple[Pose, ...]
    hold_ns: int

    def index_at(self, t_ns: int) -> int:
        """Return the number of the pose held at clock time ``t_ns`` [ns]."""
        return (t_ns // self.hold_ns) % len(self.poses)

    def pose_at(self, t_ns: int) -> Pose:
        """Return the pose held at clock time ``t_ns`` [ns]."""
        return self.poses[self.index_at(t_ns)]


def board_camera(model: PinholeModel) -> Camera:
    """Return the ``render_board`` camera of a lens; ``ValueError`` when it cannot draw it.

    ``render_board`` draws a pinhole without skew and with plumb_bob distortion (five
    coefficients, OpenCV's order; four are k3 = 0).
    """
    if model.distortion_model != 'plumb_bob':
        raise ValueError(f'the checkerboard is drawn through a plumb_bob lens, not '
                         f'{model.distortion_model}')
    k = model.k
    if k[1] != 0.0 or k[3] != 0.0 or k[6:] != (0.0, 0.0, 1.0):
        raise ValueError(f'K: the checkerboard is drawn through a camera matrix without skew '
                         f'([fx, 0, cx, 0, fy, cy, 0, 0, 1]), got {list(k)}')
    d = tuple(model.d) + (0.0,) * (5 - len(model.d))
    if len(d) != 5:
        raise ValueError(f'D: plumb_bob has 4 or 5 coefficients, got {len(model.d)}')
    return Camera(model.width, model.height, k[0], k[4], k[2], k[5],
                  (d[0], d[1], d[2], d[3], d[4]))


def board_run(model: PinholeModel, board: Board, n: int, hold: float, seed: int) -> BoardRun:
    """Return the run of ``n`` poses held ``hold`` [s] each, seeded by ``seed``.

    ``ValueError`` when the lens cannot be drawn or no pose of the board fits the image.
    """
    if not hold > 0:
        raise ValueError(f'hold: expected a positive time, got {hold}')
    camera = board_camera(model)
    poses = tuple(calibration_poses(camera, board, n, seed))
    return BoardRun(camera, board, poses, max(1, round(hold * 1e9)))


class BoardScene:
    """Frames of a ``BoardRun``: BGR images, each pose drawn once."""

    def __init__(self, run: BoardRun) -> None:
        self.run = run
        self._images: dict[int, NDArray[np.uint8]] = {}

    def prepare(self) -> None:
        """Draw every pose now (tens of milliseconds to a second each)."""
        for i in range(len(self.run.poses)):
            self.render(i * self.run.hold_ns)

    def render(self, t_ns: int) -> NDArray[np.uint8]:
        """Return the frame at clock time ``t_ns`` [ns] (H, W, 3) uint8 BGR; do not modify it."""
        i = self.run.index_at(t_ns)
        image = self._images.get(i)
        if image is None:
            r = self.run
            image = render_board(r.camera, r.board, r.poses[i], color=True)
            image.flags.writeable = False
            self._images[i] = image
        return image
