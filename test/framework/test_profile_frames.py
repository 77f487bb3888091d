"""The frames the shipped profiles declare, against the contract and the CS Saucer manual;
a profile's frames section refused with the file and key that set it.
"""

from __future__ import annotations

from pathlib import Path
import textwrap

import numpy as np
import pytest

from enbarr_core.bringup.profile import load_profile, search_dirs
from enbarr_core.framework.errors import ProfileError
from enbarr_core.framework.frame_sources import pose_sources
from enbarr_core.framework.frames import Transform
from enbarr_interfaces import topics

SHIPPED = sorted(p.stem for d in search_dirs()[-1:] for p in d.glob('*.yaml'))
#: Fragments that only add nodes to a vessel's tree: checked in the profiles that include them.
ADD_ONS = {'saucer_ca_core': ('saucer_ca', 'saucer_ca_sim')}
#: Which node kind publishes each pose topic a tree may name.
POSE_PUBLISHERS = {'observer/odometry': {'dp_observer'}, 'imu/data': {'attitude_filter'},
                   'sim/odometry': {'vessel3dof_simulator'}}
LIDARS, CAMERAS = {'rplidar', 'sim_lidar'}, {'camera', 'sim_camera'}
IMUS = {'sim_imu', 'lsm9ds1_imu', 'fxos8700_imu'}


@pytest.mark.parametrize('name', [n for n in SHIPPED if n not in ADD_ONS])
def test_every_shipped_tree_names_what_its_nodes_publish(name: str) -> None:
    profile = load_profile(name, allow_fragment=True)
    tree, plugins = profile.frames, {n.plugin for n in profile.nodes}
    assert {topics.BODY_FRAME, topics.WORLD_FRAME} <= set(tree.names())
    for source in pose_sources(tree):  # each estimate is one this profile runs
        assert (source.frame.name, source.parent) == (topics.BODY_FRAME, topics.WORLD_FRAME)
        assert POSE_PUBLISHERS[source.spec.name] & plugins, source.spec.name
    if plugins & LIDARS:
        assert topics.LASER_FRAME in tree
    if plugins & CAMERAS:
        assert {topics.CAMERA_FRAME, topics.CAMERA_OPTICAL_FRAME} <= set(tree.names())
    if plugins & IMUS:
        assert topics.IMU_FRAME in tree


@pytest.mark.parametrize('fragment', sorted(ADD_ONS))
def test_an_add_on_fragment_declares_no_tree_and_shipped_profiles_include_it(
        fragment: str) -> None:
    text = (search_dirs()[-1] / f'{fragment}.yaml').read_text()
    assert 'frames:' not in text and 'include:' not in text  # nodes added to another's tree
    for name in ADD_ONS[fragment]:  # a tree with its lidar, checked above
        assert name in SHIPPED and fragment in {Path(f).stem for f in load_profile(name).files}


def test_the_contract_names_the_frames_the_drivers_stamp() -> None:
    assert topics.SCAN.frame == 'laser'  # a real driver publishes in its own frame
    assert topics.CAMERA_IMAGE.frame == topics.CAMERA_INFO.frame == 'camera_optical_frame'
    assert topics.IMU_RAW.frame == topics.IMU_MAG.frame == 'imu_link'
    assert topics.MOCAP_POSE.frame == 'odom'
    assert (topics.TF_TOPIC, topics.TF_STATIC_TOPIC) == ('/tf', '/tf_static')


def test_the_saucer_sensors_sit_where_the_manual_says() -> None:
    """Manual section 1.5: the lidar in the centre directly above the CO, x_l and y_l along
    surge and sway; the camera right behind it, z_c along surge and x_c along sway."""
    tree = load_profile('saucer').frames
    laser = tree.lookup('base_link', 'laser')
    assert laser.translation[:2] == (0.0, 0.0) and laser.translation[2] > 0.0
    assert laser.is_close(Transform(laser.translation))  # no rotation
    camera = tree.lookup('base_link', 'camera_optical_frame')
    assert camera.translation[0] < 0.0 and camera.translation[1] == 0.0  # behind the lidar
    assert Transform((0, 0, 0), camera.rotation).is_close(
        Transform((0, 0, 0), (-0.5, 0.5, -0.5, 0.5)))
    r = camera.rotation_matrix
    assert np.allclose(r @ [0, 0, 1], [1, 0, 0])   # z_c: surge
    assert np.allclose(r @ [1, 0, 0], [0, -1, 0])  # x_c: sway (starboard, the manual's +y)
    assert tree.lookup('base_link', 'mocap_body').is_close(Transform())


def test_the_rov_imu_keeps_the_body_axes() -> None:
    for name in ('enbarr_sim', 'enbarr_rov'):
        tree = load_profile(name).frames
        assert tree.lookup('base_link', 'imu_link').is_close(Transform())
        [source] = pose_sources(tree)
        assert source.spec.name == 'imu/data'


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def test_a_bad_frame_names_the_file_that_set_it(tmp_path: Path) -> None:
    child = write(tmp_path / 'mine.yaml', """
        include: [saucer_sim.yaml]
        frames:
          laser: {rpy: [0.0, 0.0, .nan]}
        """)
    with pytest.raises(ProfileError, match=r'mine\.yaml: frames\.laser\.rpy: expected finite '
                                           r'numbers') as info:
        load_profile(str(child))
    assert info.value.key == 'frames.laser.rpy'


def test_an_override_merges_into_the_included_frame(tmp_path: Path) -> None:
    child = write(tmp_path / 'tuned.yaml', """
        include: [saucer_sim.yaml]
        frames:
          laser: {xyz: [0.01, 0.0, 0.17]}
        """)
    tree = load_profile(str(child)).frames
    assert tree.frames['laser'].parent == 'base_link'  # from saucer_core.yaml
    assert np.allclose(tree.lookup('base_link', 'laser').translation, [0.01, 0.0, 0.17])


def test_a_frame_declared_twice_in_one_file_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path / 'twice.yaml', """
        nodes: {recorder: {plugin: recorder}}
        frames:
          base_link: {}
          laser: {parent: base_link}
          laser: {parent: base_link, xyz: [0.0, 0.0, 1.0]}
        """)
    with pytest.raises(ProfileError, match=r"twice\.yaml: line 6, column 3: duplicate key "
                                           r"'laser' \(first at line 5\)"):
        load_profile(str(path))


def test_a_profile_without_frames_has_base_link_alone(tmp_path: Path) -> None:
    path = write(tmp_path / 'bare.yaml', """
        nodes: {recorder: {plugin: recorder}}
        """)
    assert load_profile(str(path)).frames.names() == ['base_link']


def test_a_cycle_names_the_file(tmp_path: Path) -> None:
    path = write(tmp_path / 'loop.yaml', """
        nodes: {recorder: {plugin: recorder}}
        frames:
          odom: {}
          a: {parent: b}
          b: {parent: a}
        """)
    with pytest.raises(ProfileError, match=r"loop\.yaml: frames\.[ab]: frame '[ab]': its "
                                           r'parents form a cycle'):
        load_profile(str(path))
