"""What the station's node tests share: an executor spinning on its own thread (the station's
server has its own, and a test speaks to it from asyncio) and an awaitable bounded wait."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
import threading
from typing import Any


class SpinningExecutor:
    """Spin ``executor`` on a daemon thread until :meth:`stop`."""

    def __init__(self, executor: Any) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, args=(executor,), daemon=True)
        self._thread.start()

    def _spin(self, executor: Any) -> None:
        while not self._stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    def stop(self) -> None:
        """Stop spinning and wait for the thread (bounded)."""
        self._stop.set()
        self._thread.join(5.0)


async def until(condition: Callable[[], bool], timeout: float = 15.0) -> None:
    """Await ``condition()``, failing the test after ``timeout`` [s] (never a timing claim)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, 'condition not met in time'
        await asyncio.sleep(0.02)
