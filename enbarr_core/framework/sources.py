"""One command source at a time: the rule for operator command topics.

Surface commands (``surface_command/*``) and the joystick (``joy``) move the vessel, so two
publishers on one of them (a second ``bringup`` in the domain, a stray ``ros2 topic pub``, an
operator station started twice) must never take turns at driving it. The rule is exclusive
control: **while more than one publisher is matched on a command topic, no message from it
is executed**; the node refuses and counts them as ``contested`` (its failsafe then stops
the vessel: zero velocity goal, or manual with zero force), reports ERROR on ``/diagnostics``
naming every publisher (node and namespace), and takes commands again as soon as a single
publisher remains.

Why not "the first source keeps control": rclpy (Jazzy) does not say which publisher sent a
message (its ``MessageInfo`` has no publisher GID), so a receiver cannot keep one source's
messages and drop another's; any such rule would guess. The DDS reader does know how many
writers it is matched with, and asks for nothing but a counter per message, so the rule
costs nothing and cannot be fooled by messages that look alike. Stopping is also what an
operator wants when someone else grabs the vessel: take the other publisher down to resume.

The matched count can lag the first message of a new writer by a moment, so the guard also
reads each message's publication sequence number (``MessageInfo``) when it is given one:
every writer numbers its messages 1, 2, 3 ... on its own, so while one source is active
(a message within ``QUIET_S``), a number that does not go up is another writer's message
and is refused too. After ``QUIET_S`` of silence a restarted number is taken as the source
restarting (an operator station started again), not as a second one. A second writer whose
numbers happen to run above the first's, and whose first message beats the matched count,
still gets that one message through. Bringup's ``EventsExecutor`` (rclpy 7.1) hands
callbacks no ``MessageInfo`` at all, so there the nodes' guards judge by the matched count
alone: a second writer's messages that arrive before the count has caught up (a moment
after its discovery) are taken.
"""

from __future__ import annotations

from collections.abc import Mapping
import time
from typing import Any

from rclpy.node import Node

from enbarr_core.framework.health import ERROR


#: Silence after which a message numbered from the start again is a restarted source [s].
QUIET_S = 0.5


class SourceGuard:
    """Watches one command subscription for competing publishers (see the module doc)."""

    def __init__(self, node: Node, subscription: Any) -> None:
        if not callable(getattr(subscription, 'get_publisher_count', None)):
            # A link subscription (TopicSpec.fast) has no DDS reader to count writers: the rule
            # would crash at the first message. Command topics stay on DDS.
            raise TypeError(
                f'{getattr(subscription, "topic_name", subscription)!r}: the single-source rule '
                'needs a DDS subscription (it counts the matched writers); a command topic must '
                'not be fast in the topic contract')
        self._node = node
        self._sub = subscription
        self.topic = subscription.topic_name
        self.contested_count = 0
        self._last_seq: int | None = None
        self._last_seen = -float('inf')  # monotonic time of the last message taken [s]

    def contested(self, info: Mapping[str, Any] | None = None) -> bool:
        """Return True (and count it) when a message must be refused as from a second source.

        ``info``: the message's ``MessageInfo`` (a subscription callback of two arguments
        gets it); without it only the matched count is judged.
        """
        now = time.monotonic()
        seq = None if info is None else info.get('publication_sequence_number')
        if self._sub.get_publisher_count() > 1 or (
                seq is not None and self._last_seq is not None and seq <= self._last_seq
                and now - self._last_seen < QUIET_S):
            self.contested_count += 1
            return True
        if seq is not None:
            self._last_seq = seq
        self._last_seen = now
        return False

    def publishers(self) -> list[str]:
        """Name the publishers of the topic in the graph ('/ns/node'), sorted."""
        infos = self._node.get_publishers_info_by_topic(self.topic)
        return sorted(f'{i.node_namespace.rstrip("/")}/{i.node_name}' for i in infos)

    def status(self) -> tuple[int, str]:
        """(level, message) for ``/diagnostics``: ERROR naming the publishers when contested."""
        if self._sub.get_publisher_count() <= 1:
            return 0, 'ok'
        names = self.publishers()
        return ERROR, (f'{self.topic} has {len(names) or "several"} publishers '
                   f'({", ".join(names) or "not yet in the graph"}): commands from it are '
                   'refused until one remains')
