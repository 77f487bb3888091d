"""The frame tree live on DDS, as RViz, Foxglove or a tf2 listener receives it.

``enbarr bringup --profile saucer_sim --duration 10`` runs in one process; a listener in
another (``support/tf_listener.py``) subscribes to ``/tf`` and, only after its first message,
to ``/tf_static`` with tf2_ros's listener QoS, so the static frames reach it only if they are
latched. Both processes import ``tf2_msgs``: where no ROS install provides it (a pip install:
PyPI has no tf2_msgs wheel), ``support.tf2_msgs_build`` builds ``TFMessage`` from the
ros-jazzy generator wheels with Debian's cmake and compilers, once per virtual environment
and set of inputs. The module skips only where that build's system tools are missing, and
says which.

Checked: both topics come from the ``frames`` node with tf2_msgs' own type (its type hash as
rosbags computes it from the Jazzy definitions, independently of the build) and tf2's QoS;
``/tf_static`` holds the profile's static frames, which composed give the numbers the profile
declares; ``/tf`` holds ``odom -> base_link`` once per estimate, with the estimate's stamp and
pose, at the estimate's rate, moving as the scripted joystick drives the vessel.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import signal
import statistics
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.frames import Frame, FrameTree, Transform
from support import tf2_msgs_build
from support.cli import enbarr
from support.processes import Output

pytestmark = pytest.mark.e2e

LISTENER = Path(__file__).resolve().parents[1] / 'support' / 'tf_listener.py'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
DURATION = 10.0  # [s] of the run; the script drives ahead for 4 s, then turns for 2 s
# The observer steps on every motion-capture pose: saucer_sim.yaml's mocap rate, 50 Hz.
ESTIMATE_PERIOD = 1.0 / 50.0  # [s]


@dataclass(frozen=True)
class LiveRun:
    """What the listener printed while the vessel ran, and the run's own output."""

    records: list[dict[str, Any]]
    bringup: subprocess.CompletedProcess[str]
    listener_stderr: str

    def kind(self, kind: str) -> list[dict[str, Any]]:
        return [r for r in self.records if r['kind'] == kind]

    def publishers(self, topic: str) -> list[dict[str, Any]]:
        [endpoints] = [r for r in self.kind('endpoints') if r['topic'] == topic]
        return list(endpoints['publishers'])


@pytest.fixture(scope='module')
def tf2_msgs() -> tf2_msgs_build.Built:
    """tf2_msgs where the processes can import it: a ROS install's, or built (cached)."""
    if not tf2_msgs_build.ros_installed():
        missing = tf2_msgs_build.missing_prerequisites()
        if missing:
            pytest.skip(f'tf2_msgs is not installed and cannot be built here: no '
                        f'{", ".join(missing)} (as root: apt-get install '
                        f'{" ".join(tf2_msgs_build.DEBIAN_PACKAGES)}; ./dev test does it)')
    built = tf2_msgs_build.tf2_msgs_environment()
    if built.seconds:
        print(f'tf2_msgs built in {built.seconds:.1f} s into {built.prefix}')
    return built


@pytest.fixture(scope='module')
def live(tf2_msgs: tf2_msgs_build.Built, tmp_path_factory: pytest.TempPathFactory) -> LiveRun:
    env = tf2_msgs.environ(os.environ)   # this module's private ROS_DOMAIN_ID
    err = tmp_path_factory.mktemp('listener') / 'stderr'
    with err.open('w') as stderr:
        listener = subprocess.Popen([sys.executable, str(LISTENER)], env=env, text=True,
                                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                    stderr=stderr)
        try:
            out = Output(listener)
            out.wait_for(r'"kind": "ready"', timeout=60)
            run = enbarr('bringup', '--profile', 'saucer_sim', '--duration', str(DURATION),
                         env=env, timeout=180)
            listener.send_signal(signal.SIGINT)
            listener.wait(timeout=30)
        finally:
            if listener.poll() is None:
                listener.kill()
                listener.wait()
    return LiveRun([json.loads(line) for line in out.lines], run, err.read_text())


def test_the_frames_node_publishes_tf2s_own_type_with_tf2s_qos(live: LiveRun) -> None:
    assert live.bringup.returncode == 0, live.bringup.stderr[-3000:]
    assert 'tf2_msgs is not installed' not in live.bringup.stderr
    real_hash = get_typestore(Stores.ROS2_JAZZY).hash_rihs01(TF_TYPE)
    [static] = live.publishers('/tf_static')
    [dynamic] = live.publishers('/tf')
    for pub in (static, dynamic):
        assert (pub['node'], pub['type'], pub['hash']) == ('frames', TF_TYPE, real_hash)
        assert pub['reliability'] == 'RELIABLE'
    assert static['durability'] == 'TRANSIENT_LOCAL'   # tf2's StaticBroadcasterQoS
    assert dynamic['durability'] == 'VOLATILE'


def received_tree(static: list[list[Any]]) -> FrameTree:
    """The tree a listener assembles: the static transforms under a moving base_link."""
    frames = [Frame('odom'), Frame('base_link', 'odom', pose='/tf')]
    frames += [Frame(child, parent, Transform(xyz, q)) for parent, child, _, xyz, q in static]
    return FrameTree.of(frames)


def test_a_late_listener_gets_the_static_frames_as_the_profile_declares(live: LiveRun) -> None:
    [subscribed] = live.kind('static_subscribed')
    assert subscribed['after_tf'] >= 1   # joined after the publisher had sent them
    messages = live.kind('tf_static')
    assert len(messages) == 1, live.listener_stderr
    static = messages[0]['transforms']
    declared = load_profile('saucer_sim').frames
    by_child = {child: (parent, Transform(xyz, q)) for parent, child, _, xyz, q in static}
    assert set(by_child) == {'laser', 'camera_link', 'camera_optical_frame', 'mocap_body'}
    for child, (parent, t) in by_child.items():
        assert parent == declared.frames[child].parent
        assert t.is_close(declared.frames[child].transform, tol=1e-12)
    tree = received_tree(static)
    for a, b in (('base_link', 'laser'), ('base_link', 'camera_optical_frame'),
                 ('laser', 'camera_optical_frame'), ('mocap_body', 'laser')):
        assert tree.lookup(a, b).is_close(declared.lookup(a, b), tol=1e-12), (a, b)
    # The numbers of params/saucer_core.yaml, typed here: the lidar 0.15 m above the CO; the
    # camera 0.08 m behind and 0.25 m above it, its optical frame (REP-103) looking ahead
    # with x to starboard (base_link's -y) and y down.
    assert np.allclose(tree.lookup('base_link', 'laser').apply([0.0, 0.0, 0.0]),
                       [0.0, 0.0, 0.15], atol=1e-12)
    optical = tree.lookup('base_link', 'camera_optical_frame')
    assert np.allclose(optical.apply([0.0, 0.0, 0.0]), [-0.08, 0.0, 0.25], atol=1e-12)
    assert np.allclose(optical.rotation_matrix, [[0.0, 0.0, 1.0],
                                                  [-1.0, 0.0, 0.0],
                                                  [0.0, -1.0, 0.0]], atol=1e-12)


def test_tf_carries_the_estimate_at_its_rate_and_the_vessel_moves(live: LiveRun) -> None:
    messages = [m['transforms'] for m in live.kind('tf')]
    assert all(len(m) == 1 for m in messages)
    tf = [m[0] for m in messages]
    assert {(parent, child) for parent, child, *_ in tf} == {('odom', 'base_link')}
    assert len(tf) > 0.5 * DURATION / ESTIMATE_PERIOD, len(tf)   # most of the run
    stamps = [stamp for _, _, stamp, _, _ in tf]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    # Each estimate the listener received is on /tf with its stamp and pose, exactly.
    by_stamp = {stamp: (xyz, q) for _, _, stamp, xyz, q in tf}
    odom = live.kind('odom')
    assert len(odom) > 0.5 * len(tf)   # best effort: a few may be lost, not most
    for o in odom:
        assert o['frame'] == 'odom'
        assert by_stamp[o['stamp_ns']] == (o['xyz'], o['quaternion'])
    period = statistics.median(np.diff(stamps) * 1e-9)
    assert period == pytest.approx(ESTIMATE_PERIOD, rel=0.05)
    assert statistics.median(np.diff([o['stamp_ns'] for o in odom]) * 1e-9) == \
        pytest.approx(period, rel=0.05)
    # The script's four seconds ahead and two of turning move the estimate.
    xy = np.array([xyz[:2] for _, _, _, xyz, _ in tf])
    assert float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) > 0.5   # [m] travelled
    yaw = [2.0 * math.atan2(q[2], q[3]) for _, _, _, _, q in tf]
    assert max(yaw) - min(yaw) > 0.1   # [rad]


def test_the_build_is_cached_on_its_inputs(tf2_msgs: tf2_msgs_build.Built,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    if tf2_msgs.prefix is None:
        pytest.skip('tf2_msgs comes from the ROS install: nothing was built')
    again = tf2_msgs_build.tf2_msgs_environment()
    assert again.prefix == tf2_msgs.prefix and again.seconds == 0.0
    key = tf2_msgs_build.cache_key()
    monkeypatch.setitem(tf2_msgs_build.SOURCES, 'msg/TFMessage.msg',
                        'geometry_msgs/TransformStamped[] transform\n')
    assert tf2_msgs_build.cache_key() != key
