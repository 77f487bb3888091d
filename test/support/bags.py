"""Read back what a run recorded, for tests (the project's own reader, plus stamps)."""

from __future__ import annotations

from typing import Any

from enbarr_core.recording.bag import read_bag

__all__ = ['read_bag', 'stamp']


def stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
