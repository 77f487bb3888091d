"""The ROS 2 message schemas that bags and live viewers carry: ``ros2msg`` text from Jazzy.

A bag's MCAP channel and a Foxglove WebSocket channel describe a ROS 2 topic the same way:
message encoding ``cdr``, schema encoding ``ros2msg``, and as schema the full message
definition with every nested type appended after a ``====`` separator line (what
``ros2 bag record`` writes). Both take it from here, from rosbags' Jazzy type store, so that
a type is described once. Pure: no rclpy here.
"""

from __future__ import annotations

import functools
from typing import Any

from rosbags.typesys import get_typestore, Stores

#: Message encoding of serialized ROS 2 messages (little-endian XCDR1, as rmw_fastrtps).
MESSAGE_ENCODING = 'cdr'
#: Schema encoding of a concatenated ``.msg`` definition.
SCHEMA_ENCODING = 'ros2msg'


@functools.cache
def jazzy_typestore() -> Any:
    """Return rosbags' ROS 2 Jazzy type store (built once per process)."""
    return get_typestore(Stores.ROS2_JAZZY)


def ros2msg_definition(msgtype: str, typestore: Any = None) -> str | None:
    """Return the ``ros2msg`` schema of ``pkg/msg/Type``, or None for a type the store lacks."""
    store = jazzy_typestore() if typestore is None else typestore
    if msgtype not in store.types:
        return None
    text, _ = store.generate_msgdef(msgtype, ros_version=2)
    return str(text)
