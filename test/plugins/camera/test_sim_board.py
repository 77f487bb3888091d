"""The simulated camera's checkerboard scene (sim_board): the lens it draws through, the poses
of a calibration run held in turn on the clock, and the frames (render_board at the pose of
the moment)."""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_core.vision.board import Board, calibration_poses, Camera, render_board
from enbarr_plugins.camera.sim_board import board_camera, board_run, BoardScene
from enbarr_plugins.camera.sim_render import PinholeModel

pytestmark = pytest.mark.unit

# The CS Saucer manual's board (4.1): 9x7 squares of 40 mm, 8x6 inner corners.
MANUAL_BOARD = Board(8, 6, 0.040)
LENS = PinholeModel(320, 240, (250.0, 0.0, 160.5, 0.0, 252.0, 119.0, 0.0, 0.0, 1.0),
                    (-0.1, 0.01, 0.001, -0.002, 0.0))
CAMERA = Camera(320, 240, 250.0, 252.0, 160.5, 119.0, (-0.1, 0.01, 0.001, -0.002, 0.0))
S = 10**9


def test_the_lens_is_drawn_as_render_boards_camera():
    assert board_camera(LENS) == CAMERA
    four = PinholeModel(320, 240, LENS.k, (-0.1, 0.01, 0.0, 0.0))
    assert board_camera(four).d == (-0.1, 0.01, 0.0, 0.0, 0.0)


@pytest.mark.parametrize('model, message', [
    (PinholeModel(320, 240, LENS.k, (0.0,) * 8, 'rational_polynomial'),
     'drawn through a plumb_bob lens, not rational_polynomial'),
    (PinholeModel(320, 240, (250.0, 1.0, 160.0, 0.0, 250.0, 120.0, 0.0, 0.0, 1.0)),
     'K: the checkerboard is drawn through a camera matrix without skew'),
])
def test_a_lens_it_cannot_draw_is_refused_by_name(model, message):
    with pytest.raises(ValueError, match=message):
        board_camera(model)


def test_each_pose_is_held_for_its_time_in_turn_and_the_run_starts_over():
    run = board_run(LENS, MANUAL_BOARD, 4, 0.5, seed=3)
    assert run.poses == tuple(calibration_poses(CAMERA, MANUAL_BOARD, 4, 3))
    half = S // 2
    t0 = 1_700_000_000 * S   # a clock's epoch time: the schedule is the clock's, not a start's
    times = [t0, t0 + half - 1, t0 + half, t0 + 2 * half, t0 + 3 * half, t0 + 4 * half,
             t0 + 4 * half + half - 1, t0 + 5 * half]
    # t0 is a whole number of seconds: pose 0 starts there
    assert [run.index_at(t) for t in times] == [0, 0, 1, 2, 3, 0, 0, 1]
    assert run.pose_at(t0 + 2 * half) == run.poses[2]
    with pytest.raises(ValueError, match='hold: expected a positive time'):
        board_run(LENS, MANUAL_BOARD, 4, 0.0, seed=3)


def test_a_frame_is_the_board_at_the_pose_of_the_moment_drawn_once():
    run = board_run(LENS, MANUAL_BOARD, 3, 1.0, seed=1)
    scene = BoardScene(run)
    frame = scene.render(7 * S + 123)   # pose 7 mod 3 = 1
    assert np.array_equal(frame, render_board(CAMERA, MANUAL_BOARD, run.poses[1], color=True))
    assert frame.shape == (240, 320, 3) and not frame.flags.writeable
    assert scene.render(7 * S + S - 1) is frame   # held: the same image, not drawn again
    assert not np.array_equal(scene.render(8 * S), frame)
    scene.prepare()
    assert scene.render(7 * S) is frame
