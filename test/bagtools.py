"""Read back what a run recorded, for tests: messages by topic, deserialized by rosbags."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def read_bag(path: str | Path) -> dict[str, list[tuple[int, Any]]]:
    """``{topic: [(receive time ns, message), ...]}`` in time order."""
    out: dict[str, list[tuple[int, Any]]] = {}
    with Reader(path) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append(
                (t, TYPESTORE.deserialize_cdr(raw, conn.msgtype)))
    return out


def stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
