"""Bounded waits for a condition: spinning an executor (node tests) or polling (e2e tests).

Never a fixed sleep standing in for a wait: a loaded 2-core machine takes its time, and
cross-process discovery alone can take 2.5 s. Light on purpose (no rclpy import): the test
``conftest`` imports it for every tier.
"""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any


def spin_until(executor: Any, condition: Callable[[], bool], timeout: float = 10.0,
               step: float = 0.05) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` [s] passes; whether it held.

    ``step`` [s] is the longest one spin waits for work.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=step)
    return condition()


def poll_until(condition: Callable[[], bool], timeout: float, step: float = 0.1) -> bool:
    """Check ``condition()`` every ``step`` [s] until it holds or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step)
    return condition()


def wait_until(condition: Callable[[], bool], timeout: float, what: str,
               step: float = 0.1) -> None:
    """``poll_until``, failing the test with ``what`` (what was awaited) when it times out."""
    if not poll_until(condition, timeout, step):
        raise AssertionError(f'timed out after {timeout} s waiting for {what}')
