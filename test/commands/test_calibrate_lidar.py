"""``calibrate lidar`` and ``calibrate reproject`` end to end on synthetic data (pure: bags are
written with the recorder's own writer, images rendered from the known geometry)."""

from __future__ import annotations

from pathlib import Path
import shutil

import cv2
import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores
from support import extrinsics_scene as S
import yaml

from enbarr_core.bringup.frame_write import write_frame
from enbarr_core.bringup.profile import load_profile
from enbarr_core.commands.calibrate_lidar import main, read_pairs
from enbarr_core.framework.errors import CalibrationError
from enbarr_core.recording.bag import BagWriter
from enbarr_core.vision import extrinsics as E

PARAMS = Path(__file__).resolve().parents[2] / 'params'
STORE = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture
def saucer(tmp_path: Path) -> Path:
    """A copy of saucer_sim.yaml and saucer_core.yaml (nominal frames), and a camera_info."""
    for name in ('saucer_core.yaml', 'saucer_sim.yaml'):
        shutil.copy(PARAMS / name, tmp_path / name)
    info = {
        'image_width': S.WIDTH, 'image_height': S.HEIGHT, 'camera_name': 'sim',
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': S.K.ravel().tolist()},
        'distortion_model': 'plumb_bob',
        'distortion_coefficients': {'rows': 1, 'cols': 5, 'data': S.DIST.tolist()},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': np.eye(3).ravel().tolist()},
        'projection_matrix': {'rows': 3, 'cols': 4,
                              'data': np.hstack([S.K, np.zeros((3, 1))]).ravel().tolist()},
    }
    (tmp_path / 'camera.yaml').write_text(yaml.safe_dump(info))
    return tmp_path


def _tree_transform(profile: Path) -> object:
    return E.optical_laser(load_profile(str(profile)).frames)


def _header(t_ns: int, frame: str) -> object:
    T = STORE.types
    return T['std_msgs/msg/Header'](T['builtin_interfaces/msg/Time'](
        t_ns // 1_000_000_000, t_ns % 1_000_000_000), frame)


def _image(t_ns: int, img: np.ndarray) -> bytes:
    h, w = img.shape[:2]
    msg = STORE.types['sensor_msgs/msg/Image'](_header(t_ns, 'camera_optical_frame'), h, w,
                                               'bgr8', 0, 3 * w, img.reshape(-1))
    return bytes(STORE.serialize_cdr(msg, 'sensor_msgs/msg/Image'))


def _scan(t_ns: int, angle_min: float, ranges: np.ndarray) -> bytes:
    inc = np.radians(S.ANGLE_STEP_DEG)
    msg = STORE.types['sensor_msgs/msg/LaserScan'](
        _header(t_ns, 'laser'), angle_min, angle_min + inc * (len(ranges) - 1), inc, 0.0,
        1 / 5.5, 0.15, 12.0, ranges.astype(np.float32), np.zeros(0, np.float32))
    return bytes(STORE.serialize_cdr(msg, 'sensor_msgs/msg/LaserScan'))


def write_board_bag(bag: Path, poses: list[S.BoardPose]) -> None:
    """Per pose: an image of the still board every 0.1 s and a scan between each two (so a
    pose of n scans is held n/10 s), then an image without the board (it is being moved)."""
    w = BagWriter(bag, flush_seconds=3600.0)
    t = 1_000_000_000_000
    step = 100_000_000
    for pose in poses:
        img = S.render_board(pose.rotation, pose.translation)
        for k in range(len(pose.ranges) + 1):
            w.write('/camera/image_raw', 'sensor_msgs/msg/Image', t, _image(t, img))
            if k < len(pose.ranges):
                a, r = pose.ranges[k]
                w.write('/scan', 'sensor_msgs/msg/LaserScan', t + step // 2,
                        _scan(t + step // 2, a, r))
            t += step
        blank = S.render_board(None, None)
        w.write('/camera/image_raw', 'sensor_msgs/msg/Image', t, _image(t, blank))
        t += step
    w.close()


# -- pairs ----------------------------------------------------------------------------------------
@pytest.mark.unit
def test_pairs_csv_skips_header_and_comments_and_names_a_bad_line(tmp_path: Path) -> None:
    p = tmp_path / 'pairs.csv'
    p.write_text('x,y,u,v\n# a comment\n1.0,0.5,320,240\n2.0,-0.5,300.5,250\n')
    xy, uv = read_pairs(str(p))
    assert xy.tolist() == [[1.0, 0.5], [2.0, -0.5]] and uv.tolist() == [[320, 240],
                                                                        [300.5, 250]]
    p.write_text('x,y,u,v\n1.0,0.5,320,240\n2.0,oops,300,250\n')
    with pytest.raises(CalibrationError, match=r'pairs.csv:3: expected numbers'):
        read_pairs(str(p))
    p.write_text('1.0,0.5,320\n')
    with pytest.raises(CalibrationError, match=r'pairs.csv:1: expected 4 finite numbers'):
        read_pairs(str(p))


@pytest.mark.unit
def test_lidar_pnp_from_pairs_writes_the_frame_tree(saucer: Path, capsys) -> None:
    T = S.true_transform()
    picked, px, _ = S.marks(T, 20, np.random.default_rng(21))
    pairs = saucer / 'pairs.csv'
    pairs.write_text('x,y,u,v\n' + ''.join(f'{a},{b},{u},{v}\n'
                                           for (a, b), (u, v) in zip(picked, px)))
    profile = saucer / 'saucer_sim.yaml'
    nominal = _tree_transform(profile)
    assert S.rotation_error_deg(nominal, T) > 2.0
    code = main(['lidar', '--method', 'pnp', '--pairs', str(pairs), '--profile', str(profile),
                 '--camera-info', str(saucer / 'camera.yaml'), '--write'])
    out = capsys.readouterr().out
    assert code == 0, out
    assert 'T_optical_laser (pnp)' in out and 'wrote frames.camera_link' in out
    found = _tree_transform(profile)
    assert S.rotation_error_deg(found, T) < 1.0 and S.translation_error(found, T) < 0.05
    assert '# calibrated ' in (saucer / 'saucer_core.yaml').read_text()


@pytest.mark.unit
def test_lidar_without_write_leaves_the_profile(saucer: Path, capsys) -> None:
    T = S.true_transform()
    picked, px, _ = S.marks(T, 8, np.random.default_rng(22))
    pairs = saucer / 'pairs.csv'
    pairs.write_text(''.join(f'{a},{b},{u},{v}\n' for (a, b), (u, v) in zip(picked, px)))
    before = (saucer / 'saucer_core.yaml').read_text()
    assert main(['lidar', '--method', 'pnp', '--pairs', str(pairs), '--profile',
                 str(saucer / 'saucer_sim.yaml'), '--camera-info',
                 str(saucer / 'camera.yaml')]) == 0
    assert 'not written' in capsys.readouterr().out
    assert (saucer / 'saucer_core.yaml').read_text() == before


@pytest.mark.unit
def test_lidar_fragment_is_an_include_that_carries_the_result(saucer: Path, capsys) -> None:
    T = S.true_transform()
    picked, px, true = S.marks(T, 8, np.random.default_rng(24), click_px=0.0, quantize=False)
    pairs = saucer / 'pairs.csv'
    pairs.write_text(''.join(f'{a:.17g},{b:.17g},{u:.17g},{v:.17g}\n'
                             for (a, b), (u, v) in zip(true, px)))
    profile = saucer / 'saucer_sim.yaml'
    before = (saucer / 'saucer_core.yaml').read_text()
    frag = saucer / 'saucer_extrinsics.yaml'
    assert main(['lidar', '--method', 'pnp', '--pairs', str(pairs), '--profile', str(profile),
                 '--camera-info', str(saucer / 'camera.yaml'), '--fragment', str(frag)]) == 0
    assert (saucer / 'saucer_core.yaml').read_text() == before
    profile.write_text(profile.read_text().replace(
        'include: [saucer_core.yaml]', 'include: [saucer_core.yaml, saucer_extrinsics.yaml]'))
    found = _tree_transform(profile)
    assert S.rotation_error_deg(found, T) < 1e-3 and S.translation_error(found, T) < 1e-4


@pytest.mark.unit
def test_a_users_mistake_is_one_line(saucer: Path, capsys) -> None:
    pairs = saucer / 'pairs.csv'
    pairs.write_text('1,0,300,240\n2,0.1,310,240\n3,-0.2,290,241\n')
    assert main(['lidar', '--method', 'pnp', '--pairs', str(pairs), '--profile',
                 str(saucer / 'saucer_sim.yaml'), '--camera-info',
                 str(saucer / 'camera.yaml')]) == 2
    err = capsys.readouterr().err
    assert err.startswith('calibrate lidar: error: 3 pairs') and 'Traceback' not in err
    assert main(['lidar', '--method', 'planes', '--profile', str(saucer / 'saucer_sim.yaml'),
                 '--camera-info', str(saucer / 'camera.yaml')]) == 2
    assert 'needs --bag' in capsys.readouterr().err


# -- planes from a bag --------------------------------------------------------------------------
@pytest.mark.sim
def test_lidar_planes_from_a_bag_writes_the_frame_tree(saucer: Path, capsys) -> None:
    T = S.true_transform()
    poses = S.board_poses(T, 8, np.random.default_rng(23), scans=6)
    bag = saucer / 'calib'
    write_board_bag(bag, poses)
    profile = saucer / 'saucer_sim.yaml'
    code = main(['lidar', '--method', 'planes', '--bag', str(bag), '--profile', str(profile),
                 '--camera-info', str(saucer / 'camera.yaml'), '--write'])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.count(' points on the board') == 8, out
    found = _tree_transform(profile)
    # 8 poses: short of the 25 docs/calibration_lidar.md asks for, so a looser bound
    assert S.rotation_error_deg(found, T) < 1.0, out
    assert S.translation_error(found, T) < 0.02, out


# -- reproject ------------------------------------------------------------------------------------
@pytest.mark.unit
def test_reproject_draws_the_scan_where_the_frame_tree_puts_it(saucer: Path, capsys) -> None:
    T = S.true_transform()
    profile = saucer / 'saucer_sim.yaml'
    tree = load_profile(str(profile)).frames
    write_frame(str(profile), 'camera_link', E.frame_pose_from(tree, T))
    # a wall 3 m ahead, seen on a grey image
    theta = np.radians(np.arange(-20.0, 20.0, 1.0))
    r = 3.0 / np.cos(theta)
    bag = saucer / 'wall'
    w = BagWriter(bag, flush_seconds=3600.0)
    t0 = 1_000_000_000_000
    w.write('/scan', 'sensor_msgs/msg/LaserScan', t0, _scan(t0, float(theta[0]), r))
    for k in range(3):
        t = t0 + (k + 1) * 100_000_000
        w.write('/camera/image_raw', 'sensor_msgs/msg/Image', t,
                _image(t, S.render_board(None, None)))
    w.close()
    png = saucer / 'wall.png'
    assert main(['reproject', '--bag', str(bag), '--profile', str(profile), '--camera-info',
                 str(saucer / 'camera.yaml'), '--output', str(png), '--index', '1']) == 0
    img = cv2.imread(str(png))
    drawn = np.any(img != 128, axis=2)
    pts = np.column_stack([r * np.cos(theta), r * np.sin(theta), np.zeros_like(r)])
    want, _ = cv2.projectPoints(pts, cv2.Rodrigues(T.rotation_matrix)[0],
                                np.asarray(T.translation), S.K, S.DIST)
    for u, v in want.reshape(-1, 2):
        assert drawn[int(round(v)), int(round(u))], (u, v)
    # and nothing far from the wall's line
    rows = np.flatnonzero(drawn.any(axis=1))
    assert rows.min() >= want[:, 0, 1].min() - 4 and rows.max() <= want[:, 0, 1].max() + 4
    avi = saucer / 'wall.avi'
    assert main(['reproject', '--bag', str(bag), '--profile', str(profile), '--camera-info',
                 str(saucer / 'camera.yaml'), '--output', str(avi)]) == 0
    cap = cv2.VideoCapture(str(avi))
    frames = 0
    while cap.read()[0]:
        frames += 1
    assert frames == 3
    assert 'wrote' in capsys.readouterr().out
