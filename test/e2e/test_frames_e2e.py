"""The frame tree in a recorded run, as a user records one: ``enbarr bringup --profile
saucer_sim --duration 8 --record DIR``; the bag read back with rosbags alone.

The bag holds the profile's frames on /tf_static (first in the file), the observer's pose as
odom -> base_link on /tf, and the latched states from their first message; odom -> laser is
composed from the bag's transforms and checked against the observer's own pose. The same
holds when the recorder runs in a process of its own (a split profile), which re-reads the
profile for its tree. A topic asked for that never appears fails the run, naming it.
"""

from __future__ import annotations

from pathlib import Path
import textwrap
from typing import Any

import numpy as np
import pytest
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.frames import Transform
from enbarr_core.recording.tf import read_transforms
from support.cli import enbarr

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def bag_topics(bag: Path) -> tuple[dict[str, list[tuple[int, bytes]]], dict[str, Any], str]:
    """Raw messages by topic, each topic's offered QoS, and the file's first topic."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(bag) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        first = None
        for conn, t, raw in reader.messages():
            first = first or conn.topic
            out.setdefault(conn.topic, []).append((t, raw))
    return out, qos, first or ''


def check_frames_in(bag: Path) -> None:
    raw, qos, first = bag_topics(bag)
    assert first == '/tf_static'
    tree = load_profile('saucer_sim').frames
    static = {s.child: s for s in read_transforms(raw['/tf_static'])}
    assert set(static) == {'laser', 'camera_link', 'camera_optical_frame', 'mocap_body'}
    for child, s in static.items():
        assert s.parent == tree.frames[child].parent
        assert s.transform.is_close(tree.frames[child].transform, tol=1e-9)
    [tf_static_qos] = qos['/tf_static']
    assert tf_static_qos.durability == QosDurability.TRANSIENT_LOCAL
    dynamic = read_transforms(raw['/tf'])
    assert len(dynamic) > 50  # seconds of estimates at the observer's rate
    assert {(s.parent, s.child) for s in dynamic} == {('odom', 'base_link')}
    # odom -> laser from the bag's transforms alone, against the observer's own last pose
    odom = [TYPESTORE.deserialize_cdr(d, 'nav_msgs/msg/Odometry')
            for _, d in raw['/observer/odometry']]
    last = odom[-1]
    stamp = last.header.stamp.sec * 1_000_000_000 + last.header.stamp.nanosec
    [pose] = [s.transform for s in dynamic if s.stamp_ns == stamp][-1:]
    p, q = last.pose.pose.position, last.pose.pose.orientation
    laser_in_odom = pose @ static['laser'].transform
    expected = Transform((p.x, p.y, p.z), (q.x, q.y, q.z, q.w)) @ tree.lookup('base_link',
                                                                               'laser')
    assert laser_in_odom.is_close(expected, tol=1e-9)
    assert np.allclose(laser_in_odom.apply([0.0, 0.0, 0.0])[:2], [p.x, p.y])


@pytest.fixture(scope='module')
def saucer_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag = tmp_path_factory.mktemp('frames') / 'bag'
    result = enbarr('bringup', '--profile', 'saucer_sim', '--duration', '8', '--record',
                    str(bag), timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    return bag


def test_the_bag_shows_the_vessel_and_its_sensors_in_place(saucer_bag: Path) -> None:
    check_frames_in(saucer_bag)


def test_latched_states_are_recorded_from_their_first_message(saucer_bag: Path) -> None:
    """Before the fix a 10 s saucer_sim bag held no guidance/path_available and its /mode
    began at 'automatic' (the starting 'manual' was missing)."""
    raw, qos, _ = bag_topics(saucer_bag)
    modes = [TYPESTORE.deserialize_cdr(d, 'std_msgs/msg/String').data for _, d in raw['/mode']]
    assert modes[0] == 'manual' and 'automatic' in modes  # the script presses triangle at 7 s
    assert raw['/guidance/path_available']
    assert qos['/mode'][0].durability == QosDurability.TRANSIENT_LOCAL


def test_a_recorder_in_its_own_process_writes_the_same_frames(tmp_path: Path) -> None:
    split = tmp_path / 'split.yaml'
    split.write_text(textwrap.dedent("""
        include: [saucer_sim.yaml]
        nodes:
          observer: {group: estimation}
        """))
    bag = tmp_path / 'bag'
    # Longer: the supervisor's duration includes starting three processes (seconds each on
    # a loaded machine) and each group's three seconds of watching for a namesake.
    result = enbarr('bringup', '--profile', str(split), '--duration', '20', '--record',
                    str(bag), timeout=180)
    assert result.returncode == 0, result.stderr[-3000:]
    assert 'group recorder started' in result.stderr
    check_frames_in(bag)


def test_a_topic_that_never_appears_fails_the_run(tmp_path: Path) -> None:
    """Before the fix: an empty bag directory and exit 0 without a word."""
    bag = tmp_path / 'bag'
    result = enbarr('bringup', '--profile', 'saucer_sim', '--duration', '3', '--record',
                    str(bag), '--record-topic', '/nonexistent', timeout=120)
    assert result.returncode == 3, result.stderr[-3000:]
    assert ('recording: topic /nonexistent was asked for but never appeared; the bag has '
            'none of it') in result.stderr
    with Reader(bag) as reader:
        assert reader.message_count == 0
