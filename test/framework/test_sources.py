"""The single-source rule for command topics (``framework/sources.py``), on real DDS matching.

Two publisher nodes in this process are two writers on the topic, exactly as a second
``bringup`` or a ``ros2 topic pub`` would be: the guard counts matched writers.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TwistStamped
from support.nodes import probe

from enbarr_core.framework.health import ERROR, OK
from enbarr_core.framework.sources import SourceGuard
from enbarr_interfaces import topics


def test_a_second_publisher_contests_the_topic_until_it_goes(context: Any, executor: Any,
                                                             spin: Any) -> None:
    receiver = probe(context, executor, 'receiver')
    sub = receiver.create_subscription(TwistStamped, topics.SURFACE_TWIST.name, lambda m: None,
                                       topics.SURFACE_TWIST.qos)
    guard = SourceGuard(receiver, sub)
    assert guard.topic == '/surface_command/twist'
    assert not guard.contested() and guard.status() == (OK, 'ok')

    first = probe(context, executor, 'operator')
    first.create_publisher(TwistStamped, topics.SURFACE_TWIST.name, topics.SURFACE_TWIST.qos)
    assert spin(executor, lambda: sub.get_publisher_count() == 1)
    assert not guard.contested()

    second = probe(context, executor, 'intruder')
    pub2 = second.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                   topics.SURFACE_TWIST.qos)
    assert spin(executor, lambda: sub.get_publisher_count() == 2)
    assert spin(executor, lambda: len(guard.publishers()) == 2)
    assert guard.contested() and guard.contested_count == 1
    level, message = guard.status()
    assert level == ERROR
    assert message.startswith('/surface_command/twist has 2 publishers (/intruder, /operator)')

    second.destroy_publisher(pub2)
    assert spin(executor, lambda: sub.get_publisher_count() == 1)
    assert not guard.contested() and guard.status() == (OK, 'ok')
