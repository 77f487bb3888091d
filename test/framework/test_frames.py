"""The frame tree (pure): transforms against scipy, lookups against a matrix walk, the
profile section's refusals, and the NED/ENU/compass conventions with numbers worked by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from enbarr_core.framework.errors import FrameError, ProfileError
from enbarr_core.framework.frames import (
    compass_error_deg, compass_heading_deg, DEFAULT_TREE, enu_to_ned, format_heading, Frame,
    FrameTree, ned_to_enu, parse_frames, Transform)

HALF_PI = math.pi / 2

SAUCER_LIKE = {
    'odom': {},
    'base_link': {'parent': 'odom', 'pose': 'observer/odometry'},
    'laser': {'parent': 'base_link', 'xyz': [0.0, 0.0, 0.12]},
    'camera_link': {'parent': 'base_link', 'xyz': [-0.06, 0.0, 0.2]},
    'camera_optical_frame': {'parent': 'camera_link', 'rpy': [-HALF_PI, 0.0, -HALF_PI]},
    'mocap_body': {'parent': 'base_link'},
}


def random_transform(rng: np.random.Generator) -> Transform:
    return Transform.from_rpy(rng.uniform(-2, 2, 3), rng.uniform(-math.pi, math.pi, 3))


def as_scipy(t: Transform) -> tuple[Rotation, np.ndarray]:
    return Rotation.from_quat(t.rotation), np.asarray(t.translation)


# -- Transform against scipy -------------------------------------------------------------------

def test_rpy_is_the_fixed_axis_xyz_rotation_of_scipy() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        rpy = rng.uniform(-math.pi, math.pi, 3)
        t = Transform.from_rpy((0, 0, 0), rpy)
        expected = Rotation.from_euler('xyz', rpy)  # lower case: extrinsic (fixed) axes
        assert np.allclose(t.rotation_matrix, expected.as_matrix(), atol=1e-12)


def test_compose_inverse_and_apply_agree_with_scipy() -> None:
    rng = np.random.default_rng(11)
    for _ in range(50):
        a, b = random_transform(rng), random_transform(rng)
        ra, ta = as_scipy(a)
        rb, tb = as_scipy(b)
        points = rng.uniform(-5, 5, (4, 3))
        # T_ab @ T_bc applied to p: R_a (R_b p + t_b) + t_a
        expected = ra.apply(rb.apply(points) + tb) + ta
        assert np.allclose((a @ b).apply(points), expected, atol=1e-12)
        assert np.allclose(a.inverse().apply(a.apply(points)), points, atol=1e-12)
        assert np.allclose(a.inverse().matrix, np.linalg.inv(a.matrix), atol=1e-12)


def test_rpy_round_trips() -> None:
    t = Transform.from_rpy((1, 2, 3), (0.1, -0.2, 0.3))
    assert np.allclose(t.rpy, (0.1, -0.2, 0.3))


def test_is_close_takes_q_and_minus_q_as_one_rotation() -> None:
    t = Transform((1.0, 0.0, 0.0), (0.0, 0.0, 0.6, 0.8))
    assert t.is_close(Transform((1.0, 0.0, 0.0), (0.0, 0.0, -0.6, -0.8)))
    assert not t.is_close(Transform((1.0, 0.0, 0.0), (0.0, 0.0, 0.8, 0.6)))


# -- the tree ----------------------------------------------------------------------------------

def matrix_walk(tree: FrameTree, name: str, poses: dict[str, Transform]) -> np.ndarray:
    """The pose of ``name`` in the root as a 4x4 product (a second formulation)."""
    m = np.eye(4)
    while tree.frames[name].parent is not None:
        f = tree.frames[name]
        step = poses[name] if f.dynamic else f.transform
        rot, trans = as_scipy(step)
        h = np.eye(4)
        h[:3, :3] = rot.as_matrix()
        h[:3, 3] = trans
        m = h @ m
        name = f.parent
    return m


def test_lookup_composes_as_a_matrix_walk_does() -> None:
    rng = np.random.default_rng(3)
    frames = [Frame('world'), Frame('odom', 'world', random_transform(rng)),
              Frame('base_link', 'odom', pose='observer/odometry')]
    for i in range(4):
        frames.append(Frame(f's{i}', 'base_link', random_transform(rng)))
        frames.append(Frame(f's{i}_optical', f's{i}', random_transform(rng)))
    tree = FrameTree.of(frames)
    poses = {'base_link': random_transform(rng)}
    for target in tree.names():
        for source in tree.names():
            expected = np.linalg.inv(matrix_walk(tree, target, poses)) @ matrix_walk(
                tree, source, poses)
            assert np.allclose(tree.lookup(target, source, poses).matrix, expected,
                               atol=1e-10), (target, source)


def test_sensors_on_a_moving_body_relate_without_its_pose() -> None:
    tree = parse_frames(SAUCER_LIKE)
    t = tree.lookup('laser', 'camera_optical_frame')
    # 1 m straight out of the lens: 0.94 m ahead of the lidar, 0.08 m above it (by hand)
    assert np.allclose(t.apply([0.0, 0.0, 1.0]), [0.94, 0.0, 0.08])
    with pytest.raises(FrameError, match=r'odom -> base_link is dynamic \(its pose comes from '
                                         r'observer/odometry\)'):
        tree.lookup('odom', 'laser')


def test_lookup_through_the_dynamic_frame_with_its_pose() -> None:
    tree = parse_frames(SAUCER_LIKE)
    pose = Transform.planar(1.0, 2.0, HALF_PI)  # at (1, 2) facing north
    # a return 1 m ahead of the lidar is 1 m north of the vessel, 0.12 m up (by hand)
    assert np.allclose(tree.transform_points('odom', 'laser', [1.0, 0.0, 0.0],
                                             {'base_link': pose}), [1.0, 3.0, 0.12])


def test_the_optical_frame_looks_along_surge_with_x_right_and_y_down() -> None:
    """REP-103 optical frame: z forward, x right, y down; the standard camera_link ->
    camera_optical_frame rotation is the quaternion (-0.5, 0.5, -0.5, 0.5)."""
    t = parse_frames(SAUCER_LIKE).lookup('camera_link', 'camera_optical_frame')
    assert t.is_close(Transform((0.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5)))
    r = t.rotation_matrix
    assert np.allclose(r @ [0, 0, 1], [1, 0, 0])    # optical z: forward (surge)
    assert np.allclose(r @ [1, 0, 0], [0, -1, 0])   # optical x: right (starboard)
    assert np.allclose(r @ [0, 1, 0], [0, 0, -1])   # optical y: down


def test_edges_and_order() -> None:
    tree = parse_frames(SAUCER_LIKE)
    assert tree.root == 'odom'
    assert tree.names()[:2] == ['odom', 'base_link']
    assert [f.name for f in tree.dynamic_frames()] == ['base_link']
    assert {f.name for f in tree.static_edges()} == {
        'laser', 'camera_link', 'camera_optical_frame', 'mocap_body'}


def test_default_tree_is_base_link_alone() -> None:
    assert parse_frames(None) is DEFAULT_TREE
    assert parse_frames({}) is DEFAULT_TREE
    assert DEFAULT_TREE.names() == ['base_link']
    assert DEFAULT_TREE.lookup('base_link', 'base_link').is_close(Transform())
    assert DEFAULT_TREE.static_edges() == [] and DEFAULT_TREE.dynamic_frames() == []


def test_a_calibration_writes_back_and_the_section_round_trips() -> None:
    tree = parse_frames(SAUCER_LIKE)
    calibrated = tree.with_transform('laser', Transform.from_rpy((0.01, 0.0, 0.13),
                                                                 (0.0, 0.0, 0.02)))
    assert calibrated.lookup('base_link', 'laser').is_close(
        Transform.from_rpy((0.01, 0.0, 0.13), (0.0, 0.0, 0.02)))
    again = parse_frames(calibrated.to_profile())
    for name in tree.names():
        assert again.frames[name].parent == calibrated.frames[name].parent
        assert again.frames[name].transform.is_close(calibrated.frames[name].transform)
    with pytest.raises(FrameError, match='dynamic'):
        tree.with_transform('base_link', Transform())


def test_unknown_frame_lists_the_frames() -> None:
    with pytest.raises(FrameError, match=r"no frame 'lidar' in the tree; frames: odom, "):
        parse_frames(SAUCER_LIKE).lookup('base_link', 'lidar')


# -- refusals (each names the file and the key) --------------------------------------------------

def refused(section: dict, match: str, key: str) -> None:
    with pytest.raises(ProfileError, match=match) as info:
        parse_frames(section, lambda k: f'file-of-{k}')
    assert info.value.key == key
    assert info.value.path == f'file-of-{key}'


@pytest.mark.parametrize('section, match, key', [
    ({'a': {}, 'b': {'parent': 'c'}, 'c': {'parent': 'b'}},
     r"frame '[bc]': its parents form a cycle: ([bc]) -> [bc] -> \1", None),
    ({'a': {'parent': 'a'}}, 'no root frame', 'frames'),
    ({'a': {}, 'b': {'parent': 'nowhere'}}, "frame 'b': unknown parent 'nowhere'", 'frames.b'),
    ({'a': {}, 'b': {}}, 'two roots: a, b have no parent', 'frames'),
    ({'a': {}, 'b': {'parent': 'a', 'xyz': [0.0, float('nan'), 0.0]}},
     'expected finite numbers', 'frames.b.xyz'),
    ({'a': {}, 'b': {'parent': 'a', 'rpy': [0.0, 0.0, float('inf')]}},
     'expected finite numbers', 'frames.b.rpy'),
    ({'a': {}, 'b': {'parent': 'a', 'quaternion': [0.0, 0.0, 0.0, 2.0]}},
     r'not a unit quaternion \[x, y, z, w\]: its norm is 2', 'frames.b.quaternion'),
    ({'a': {}, 'b': {'parent': 'a', 'quaternion': [0.0, 0.0, 1.0]}},
     'expected a list of 4 numbers', 'frames.b.quaternion'),
    ({'a': {}, 'b': {'parent': 'a', 'rpy': [0, 0, 0], 'quaternion': [0, 0, 0, 1]}},
     'rpy or as quaternion, not both', 'frames.b.rpy'),
    ({'a': {}, 'b': {'parent': 'a', 'pose': 'odom', 'xyz': [0, 0, 1]}},
     'a dynamic frame', 'frames.b.pose'),
    ({'a': {}, 'b': {'parent': 'a', 'yaw': 1.0}}, 'unknown key; expected one of: parent',
     'frames.b.yaw'),
    ({'/a': {}}, 'no leading slash', 'frames./a'),
    ({'a': {}, 'b': {'parent': 'a', 'xyz': [0, True, 0]}}, 'list of 3 numbers',
     'frames.b.xyz'),
    ({'a': [1, 2]}, 'expected a mapping', 'frames.a'),
])
def test_refusals_name_file_and_key(section: dict, match: str, key: str | None) -> None:
    with pytest.raises(ProfileError, match=match) as info:
        parse_frames(section, lambda k: f'file-of-{k}')
    if key is not None:
        assert info.value.key == key
        assert info.value.path == f'file-of-{key}'
    else:
        assert info.value.key in ('frames.b', 'frames.c')


def test_a_nearly_unit_quaternion_is_normalized() -> None:
    tree = parse_frames({'a': {}, 'b': {'parent': 'a', 'quaternion': [0, 0, 0.7071, 0.7071]}})
    assert np.isclose(np.linalg.norm(tree.frames['b'].transform.rotation), 1.0)


def test_the_tree_itself_refuses_duplicates_and_bad_names() -> None:
    with pytest.raises(FrameError, match="frame 'a' is declared twice"):
        FrameTree.of([Frame('a'), Frame('a')])
    with pytest.raises(FrameError, match='the root cannot have a pose source'):
        FrameTree.of([Frame('a', pose='x')])


# -- NED, ENU and the compass, by hand -----------------------------------------------------------

@pytest.mark.parametrize('eta_ned, eta_enu', [
    ([3.0, 4.0, 0.0], [4.0, 3.0, HALF_PI]),                 # facing north
    ([3.0, 4.0, HALF_PI], [4.0, 3.0, 0.0]),                 # facing east
    ([-1.0, 2.0, math.pi], [2.0, -1.0, -HALF_PI]),          # facing south
    ([0.0, 0.0, -HALF_PI], [0.0, 0.0, -math.pi]),           # facing west (wrapped to -pi)
    ([2.0, 1.0, math.radians(30)], [1.0, 2.0, math.radians(60)]),
])
def test_ned_and_enu(eta_ned: list[float], eta_enu: list[float]) -> None:
    assert np.allclose(ned_to_enu(eta_ned), eta_enu)
    back = enu_to_ned(eta_enu)
    assert np.allclose(back[:2], eta_ned[:2])
    assert math.isclose(math.cos(back[2]), math.cos(eta_ned[2]), abs_tol=1e-12)
    assert math.isclose(math.sin(back[2]), math.sin(eta_ned[2]), abs_tol=1e-12)


@pytest.mark.parametrize('yaw, compass', [
    (0.0, 90.0), (HALF_PI, 0.0), (-HALF_PI, 180.0), (math.pi, 270.0),
    (math.radians(45), 45.0), (math.radians(100), 350.0),
])
def test_compass_heading(yaw: float, compass: float) -> None:
    assert math.isclose(float(compass_heading_deg(yaw)), compass, abs_tol=1e-9)


def test_a_left_turn_lowers_the_compass_heading() -> None:
    north = HALF_PI
    assert math.isclose(float(compass_heading_deg(north + math.radians(10))), 350.0)
    # the error is clockwise-positive: 10 deg to port of a northward reference is -10
    assert math.isclose(float(compass_error_deg(north + math.radians(10), north)), -10.0)
    # facing east (090) against north (000): +90; facing north against east: -90
    assert np.allclose(compass_error_deg(np.array([0.0, HALF_PI]), np.array([HALF_PI, 0.0])),
                       [90.0, -90.0])


def test_format_heading() -> None:
    assert format_heading(math.radians(45)) == 'heading 045 deg (compass)'
    assert format_heading(0.0) == 'heading 090 deg (compass)'
    assert format_heading(HALF_PI + 0.001) == 'heading 000 deg (compass)'  # 359.94 rounds up
