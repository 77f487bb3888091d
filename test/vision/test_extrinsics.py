"""Camera to 2D lidar extrinsics on synthetic data with a known transform (pure).

The scenes (test/support/extrinsics_scene.py) use the manual's RPLidar figures and board;
the bounds of the issue (rotation within 0.5 deg, translation within 1 cm) are checked for the
checkerboard-plane method on the data set docs/calibration_lidar.md asks for, and what the
manual's mark method achieves with 20 pairs is pinned as measured.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support import extrinsics_scene as S

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.framework.frames import Transform
from enbarr_core.perception.scan_geometry import RangeNoise
from enbarr_core.vision import extrinsics as E

CAMERA = E.CameraModel.of(S.K, S.DIST, S.WIDTH, S.HEIGHT)
OBJ = E.board_object_points(S.BOARD_COLS, S.BOARD_ROWS, S.SQUARE)
# RPLidar A1, manual Table 1.1 (typed here, not read from the code under test).
A1_NOISE = RangeNoise((3.0, 5.0), (0.01, 0.02, 0.025))


def _planes_and_points(poses: list[S.BoardPose]) -> tuple[list[E.BoardPlane], list[np.ndarray]]:
    planes = [E.board_plane(p.corners, OBJ, CAMERA) for p in poses]
    pts = [np.concatenate([s[h] for s, h in zip(p.scans, p.on_board)]) for p in poses]
    return planes, pts


def _errors(found: Transform, true: Transform) -> tuple[float, float]:
    return S.rotation_error_deg(found, true), S.translation_error(found, true)


# -- the board and its plane ----------------------------------------------------------------
@pytest.mark.unit
def test_board_points_are_row_by_row_as_opencv_orders_corners():
    obj = E.board_object_points(3, 2, 0.04)
    assert obj == pytest.approx(np.array([[0, 0, 0], [0.04, 0, 0], [0.08, 0, 0],
                                          [0, 0.04, 0], [0.04, 0.04, 0], [0.08, 0.04, 0]]))


@pytest.mark.unit
def test_board_plane_is_the_board_pose_seen_by_the_camera():
    T = S.true_transform()
    pose = S.board_poses(T, 1, np.random.default_rng(1), scans=1, pixel_noise=0.0)[0]
    plane = E.board_plane(pose.corners, OBJ, CAMERA)
    n = pose.rotation[:, 2]
    assert plane.normal == pytest.approx(n, abs=1e-6)
    assert plane.distance == pytest.approx(float(n @ pose.translation), abs=1e-6)
    assert plane.distance > 0 and plane.rms_px < 1e-3


# -- (b) Zhang and Pless -----------------------------------------------------------------------
@pytest.mark.unit
def test_planes_recover_the_transform_exactly_without_noise():
    T = S.true_transform()
    rng = np.random.default_rng(2)
    saved = S.NOISE_FRACTIONS
    S.NOISE_FRACTIONS = (0.0, 0.0, 0.0)
    try:
        poses = S.board_poses(T, 6, rng, scans=2, pixel_noise=0.0)
    finally:
        S.NOISE_FRACTIONS = saved
    planes, pts = _planes_and_points(poses)
    result = E.solve_planes(planes, pts)
    rot, tr = _errors(result.transform, T)
    assert rot < 1e-4 and tr < 1e-6
    assert result.rms < 1e-6 and result.unit == 'm'
    assert len(result.per_board_rms) == 6


@pytest.mark.unit
def test_the_linear_start_alone_is_close():
    # Without noise the linear least squares in H = [r1 r2 t] is exact already.
    T = S.true_transform()
    saved = S.NOISE_FRACTIONS
    S.NOISE_FRACTIONS = (0.0, 0.0, 0.0)
    try:
        poses = S.board_poses(T, 6, np.random.default_rng(3), scans=2, pixel_noise=0.0)
    finally:
        S.NOISE_FRACTIONS = saved
    planes, pts = _planes_and_points(poses)
    n = np.concatenate([np.repeat(p.normal[None], len(a), 0) for p, a in zip(planes, pts)])
    d = np.concatenate([np.full(len(a), p.distance) for p, a in zip(planes, pts)])
    rot, tr = _errors(E._linear_planes(np.concatenate(pts), n, d), T)
    assert rot < 1e-3 and tr < 1e-5


@pytest.mark.unit
def test_planes_with_the_manuals_noise_and_the_joint_refinement():
    T = S.true_transform()
    poses = S.board_poses(T, 12, np.random.default_rng(4), scans=5)
    planes, pts = _planes_and_points(poses)
    result = E.solve_planes(planes, pts, camera=CAMERA, range_noise=A1_NOISE)
    rot, tr = _errors(result.transform, T)
    assert rot < 1.0 and tr < 0.02       # 12 poses: short of the bound (see the sim test)
    # the residual scatter is the range noise: about 1 % of 0.8 to 2 m
    assert 0.005 < result.rms < 0.025
    # the reported one-sigma covers the error (within 4 sigma, axis by axis)
    err = np.abs(np.subtract(result.transform.translation, T.translation))
    assert np.all(err < 4 * result.sigma_translation)


@pytest.mark.sim
def test_planes_meet_the_bound_on_the_documented_data_set():
    """40 poses of the manual's A3 board at 0.8 to 2 m, 10 revolutions each: 10 seeds.

    docs/calibration_lidar.md gives the spread over 40 seeds for 20, 30 and 40 poses: 40 is
    where every seed met the bound (30: 39 of 40).
    """
    T = S.true_transform()
    worst = np.zeros(2)
    for seed in range(10):
        poses = S.board_poses(T, 40, np.random.default_rng(100 + seed), scans=10)
        planes, pts = _planes_and_points(poses)
        result = E.solve_planes(planes, pts, camera=CAMERA, range_noise=A1_NOISE)
        worst = np.maximum(worst, _errors(result.transform, T))
    assert worst[0] < 0.5, f'rotation error {worst[0]:.3f} deg'
    assert worst[1] < 0.01, f'translation error {worst[1] * 1000:.1f} mm'


@pytest.mark.sim
def test_the_joint_refinement_beats_fixed_planes():
    T = S.true_transform()
    fixed, joint = [], []
    for seed in range(8):
        poses = S.board_poses(T, 15, np.random.default_rng(200 + seed), scans=5)
        planes, pts = _planes_and_points(poses)
        fixed.append(_errors(E.solve_planes(planes, pts).transform, T))
        joint.append(_errors(E.solve_planes(planes, pts, camera=CAMERA,
                                            range_noise=A1_NOISE).transform, T))
    f, j = np.mean(fixed, axis=0), np.mean(joint, axis=0)
    assert j[0] < f[0] and j[1] < f[1], (f, j)


@pytest.mark.unit
def test_too_few_boards_are_refused():
    T = S.true_transform()
    poses = S.board_poses(T, 4, np.random.default_rng(5), scans=1)
    planes, pts = _planes_and_points(poses)
    with pytest.raises(CalibrationError, match='2 board poses: at least 3'):
        E.solve_planes(planes[:2], pts[:2], initial=T)
    with pytest.raises(CalibrationError, match='the linear start needs 5'):
        E.solve_planes(planes, pts)
    # with a start, 4 will do
    E.solve_planes(planes, pts, initial=T)


@pytest.mark.unit
def test_parallel_boards_are_refused():
    T = S.true_transform()
    poses = S.board_poses(T, 6, np.random.default_rng(6), scans=1, parallel=True)
    planes, pts = _planes_and_points(poses)
    with pytest.raises(CalibrationError, match='all boards are parallel'):
        E.solve_planes(planes, pts)


@pytest.mark.unit
def test_boards_turned_about_one_axis_are_refused():
    T = S.true_transform()
    poses = S.board_poses(T, 6, np.random.default_rng(7), scans=1, one_axis=True)
    planes, pts = _planes_and_points(poses)
    with pytest.raises(CalibrationError, match='tilted about one axis'):
        E.solve_planes(planes, pts)


@pytest.mark.unit
def test_a_board_without_lidar_points_is_named():
    T = S.true_transform()
    poses = S.board_poses(T, 6, np.random.default_rng(8), scans=1)
    planes, pts = _planes_and_points(poses)
    pts[3] = pts[3][:1]
    with pytest.raises(CalibrationError, match='board 3: 1 lidar points on it'):
        E.solve_planes(planes, pts)


@pytest.mark.unit
def test_the_scan_points_on_a_board_are_found_from_a_rough_guess():
    T = S.true_transform()
    rough = S.true_transform(rot_deg=(0.0, 0.0, 0.0), offset=(0.0, 0.0, 0.0))
    assert S.rotation_error_deg(rough, T) > 2.0 and S.translation_error(rough, T) > 0.02
    poses = S.board_poses(T, 5, np.random.default_rng(9), scans=3)
    found = 0
    for pose in poses:
        plane = E.board_plane(pose.corners, OBJ, CAMERA)
        for scan, hit in zip(pose.scans, pose.on_board):
            fin = np.all(np.isfinite(scan), axis=1)
            mask = E.select_board_points(scan[fin], plane, rough, S.EXTENT)
            # every board ray, and no wall ray, but maybe a ray grazing an edge
            assert np.sum(mask != hit[fin]) <= 1
            found += int(mask.sum())
    assert found > 100


@pytest.mark.unit
def test_a_board_across_the_scans_first_ray_is_one_run():
    T = S.true_transform()
    pose = S.board_poses(T, 1, np.random.default_rng(14), scans=1)[0]
    plane = E.board_plane(pose.corners, OBJ, CAMERA)
    scan, hit = pose.scans[0], pose.on_board[0]
    fin = np.all(np.isfinite(scan), axis=1)
    scan, hit = scan[fin], hit[fin]
    board = np.flatnonzero(hit)
    assert len(board) >= 6
    # start the ring in the middle of the board's rays
    k = int(board[len(board) // 2])
    mask = E.select_board_points(np.roll(scan, -k, axis=0), plane, T, S.EXTENT)
    assert np.array_equal(mask, np.roll(hit, -k))


# -- (a) the manual's marks --------------------------------------------------------------------
@pytest.mark.unit
def test_pnp_recovers_the_transform_from_exact_marks():
    T = S.true_transform()
    _, px, true = S.marks(T, 8, np.random.default_rng(10), click_px=0.0, quantize=False)
    result = E.solve_pnp(true, px, CAMERA)
    rot, tr = _errors(result.transform, T)
    assert rot < 1e-4 and tr < 1e-5 and result.rms < 1e-3 and result.unit == 'px'


@pytest.mark.unit
def test_pnp_with_the_manuals_noise_and_20_pairs():
    T = S.true_transform()
    picked, px, _ = S.marks(T, 20, np.random.default_rng(11))
    result = E.solve_pnp(picked, px, CAMERA)
    rot, tr = _errors(result.transform, T)
    assert rot < 1.0 and tr < 0.05
    assert 0.5 < result.rms < 5.0


@pytest.mark.sim
def test_what_pnp_achieves_with_n_pairs():
    """The worst of 20 seeds, pinned a little above what was measured (docs/calibration_lidar.md
    gives the spread over 100 seeds): the rotation bound holds from 20 pairs, the translation
    bound does not."""
    T = S.true_transform()
    worst = {}
    for n in (10, 20, 40):
        w = np.zeros(2)
        for seed in range(20):
            picked, px, _ = S.marks(T, n, np.random.default_rng(300 + seed))
            w = np.maximum(w, _errors(E.solve_pnp(picked, px, CAMERA).transform, T))
        worst[n] = w
    assert worst[10][0] < 1.5 and worst[10][1] < 0.08
    assert worst[20][0] < 0.6 and worst[20][1] < 0.05
    assert worst[40][0] < 0.4 and worst[40][1] < 0.03


@pytest.mark.unit
def test_pnp_drops_a_misclick():
    T = S.true_transform()
    picked, px, _ = S.marks(T, 12, np.random.default_rng(12))
    px[5] += (40.0, -25.0)
    result = E.solve_pnp(picked, px, CAMERA)
    assert not result.used[5] and result.used.sum() == 11
    assert result.residuals[5] > 30.0
    rot, tr = _errors(result.transform, T)
    assert rot < 1.0 and tr < 0.05


@pytest.mark.unit
def test_pnp_refuses_too_few_pairs():
    T = S.true_transform()
    picked, px, _ = S.marks(T, 3, np.random.default_rng(13))
    with pytest.raises(CalibrationError, match='3 pairs: .* at least 4'):
        E.solve_pnp(picked, px, CAMERA)


@pytest.mark.unit
def test_pnp_refuses_marks_on_one_line():
    T = S.true_transform()
    xy = np.column_stack([np.full(6, 3.0), np.linspace(-1.0, 1.0, 6)])   # one wall
    px = CAMERA.project(T.apply(np.column_stack([xy, np.zeros(6)])))
    with pytest.raises(CalibrationError, match='on one line'):
        E.solve_pnp(xy, px, CAMERA)


@pytest.mark.unit
def test_pnp_refuses_mismatched_lists():
    with pytest.raises(CalibrationError, match='5 lidar points but 4 pixels'):
        E.solve_pnp(np.ones((5, 2)), np.ones((4, 2)), CAMERA)


# -- into the frame tree, and back onto the image ------------------------------------------
@pytest.mark.unit
def test_the_camera_link_pose_gives_the_calibrated_transform():
    from enbarr_core.bringup.profile import load_profile
    tree = load_profile('saucer_core', allow_fragment=True).frames
    T = S.true_transform()
    pose = E.frame_pose_from(tree, T)
    new = tree.with_transform('camera_link', pose)
    assert new.lookup('camera_optical_frame', 'laser').is_close(T, tol=1e-9)
    # the lidar stays where it was on the hull, and so does the optical frame's convention
    assert new.lookup('base_link', 'laser').is_close(tree.lookup('base_link', 'laser'))
    assert new.frame('camera_optical_frame') == tree.frame('camera_optical_frame')
    with pytest.raises(CalibrationError, match='root or dynamic'):
        E.frame_pose_from(tree, T, frame='base_link')
    with pytest.raises(CalibrationError, match='not .camera_optical_frame. or above it'):
        E.frame_pose_from(tree, T, frame='laser')
    # a mast carrying both sensors: writing it would move the lidar too
    from enbarr_core.framework.frames import Frame, FrameTree
    mast = FrameTree.of([Frame('base_link'), Frame('mast', 'base_link'),
                         Frame('laser', 'mast'), Frame('camera_optical_frame', 'mast')])
    with pytest.raises(CalibrationError, match='would move the lidar'):
        E.frame_pose_from(mast, T, frame='mast')
    # the optical frame itself can be written when there is no camera_link
    pose = E.frame_pose_from(mast, T, frame='camera_optical_frame')
    assert mast.with_transform('camera_optical_frame', pose).lookup(
        'camera_optical_frame', 'laser').is_close(T, tol=1e-9)


@pytest.mark.unit
def test_the_nominal_tree_is_the_manuals_mounting():
    # Manual 1.5: lidar x, y along surge, sway; camera z along surge, x along sway (to
    # starboard: REP-103 x right): so the laser's x is the optical z, its y the optical -x.
    from enbarr_core.bringup.profile import load_profile
    tree = load_profile('saucer_core', allow_fragment=True).frames
    R = E.optical_laser(tree).rotation_matrix
    assert R == pytest.approx(np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]]), abs=1e-12)


@pytest.mark.unit
def test_project_scan_matches_opencv_and_drops_points_behind():
    T = S.true_transform()
    xy = np.array([[2.0, 0.3], [3.0, -0.5], [-2.0, 0.0], [1.0, 5.0]])
    px, ok = E.project_scan(xy, T, CAMERA)
    assert ok.tolist() == [True, True, False, False]
    import cv2
    R = T.rotation_matrix
    want, _ = cv2.projectPoints(np.column_stack([xy[:2], np.zeros(2)]),
                                cv2.Rodrigues(R)[0], np.asarray(T.translation), S.K, S.DIST)
    assert px[:2] == pytest.approx(want.reshape(-1, 2), abs=1e-6)
    assert Rotation.from_quat(T.rotation).as_matrix() == pytest.approx(R)
