"""The live frame publisher where tf2_msgs is missing (a pip install): it says so once at
INFO and publishes nothing. (Where tf2_msgs exists it publishes /tf_static and /tf: this
process cannot import the tf2_msgs that the tests build, so test/e2e/test_frames_live_e2e.py
checks that path from processes started with it.)
"""

from __future__ import annotations

from typing import Any

import pytest

from enbarr_core.framework import frame_publisher_node
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.frame_publisher_node import FramePublisherNode
from enbarr_core.framework.frames import parse_frames
from enbarr_core.framework.node import install_frame_tree
from support.nodes import add

TREE = {'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'observer/odometry'},
        'laser': {'parent': 'base_link', 'xyz': [0.0, 0.0, 0.15]}}


def test_without_tf2_msgs_it_says_so_once_and_publishes_nothing(
        context, executor, monkeypatch: pytest.MonkeyPatch) -> None:
    assert frame_publisher_node.tf_message_class() is None  # this environment: pip wheels
    said: list[str] = []
    install_frame_tree(context, parse_frames(TREE))
    node = add(executor, FramePublisherNode(context=context))
    logger = node.get_logger()  # the node's own logger, its info recorded (public API only)
    monkeypatch.setattr(node, 'get_logger', lambda: type('Log', (), {
        'info': lambda self, m, **kw: said.append(m),
        'warn': lambda self, m, **kw: logger.warn(m),
        'error': lambda self, m, **kw: logger.error(m)})())
    assert said == []  # built only (bringup --check): nothing to say yet
    node.start()
    node.start()  # once
    executor.spin_once(timeout_sec=0.1)
    assert not node.live and node.published == 0
    assert said == ['tf2_msgs is not installed (a pip install has none): /tf and /tf_static '
                    'are not published live; recorded bags still hold them']
    published = {name for name, _ in node.get_publisher_names_and_types_by_node('frames', '/')}
    assert not published & {'/tf', '/tf_static'}
    assert node.get_subscriptions_info_by_topic('/observer/odometry') == []


def test_a_pose_topic_outside_the_contract_is_refused(context) -> None:
    install_frame_tree(context, parse_frames({
        'odom': {}, 'base_link': {'parent': 'odom', 'pose': 'nowhere'}}))
    with pytest.raises(ConfigurationError, match=r"frames\.base_link\.pose: 'nowhere'"):
        FramePublisherNode(context=context)


def test_the_module_finds_tf2_msgs_when_it_is_there(monkeypatch: pytest.MonkeyPatch) -> None:
    """The import is by name: a module that has the class is used (here a stand-in)."""
    import sys
    import types
    fake: Any = types.ModuleType('tf2_msgs.msg')
    fake.TFMessage = type('TFMessage', (), {})
    monkeypatch.setitem(sys.modules, 'tf2_msgs.msg', fake)
    assert frame_publisher_node.tf_message_class() is fake.TFMessage
