"""The thread a driver talks to its device on: a serial stream, a network session.

A driver whose device streams (a lidar, a motion-capture server) reads it on a thread of
its own, so that neither the executor nor the control chain waits on the device. When the
device fails there, the thread must not close it or touch the node's state: it ends, and
keeps the failure for the node's supervision timer, which hands it to ``device_fault`` on
the executor thread (close, safe state, retry with backoff). ``DeviceThread`` is that
pattern once. Plain ``threading``; no ROS here.
"""

from __future__ import annotations

from collections.abc import Callable
import threading
from typing import Any

from enbarr_core.framework.errors import DeviceError


class DeviceThread:
    """Runs ``target(*args)`` on a thread named ``name``; see the module docstring.

    ``target`` returns when ``stopping`` (or raises). A ``DeviceError`` it raises is kept as
    it is; any other exception (a bug) is kept as a ``DeviceError`` naming ``where``, so that
    it too reaches ``/diagnostics``; nothing is kept once ``stop()`` was asked.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._failure: DeviceError | None = None

    @property
    def stopping(self) -> bool:
        """Whether the thread was asked to end."""
        return self._stop.is_set()

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds`` [s], less when asked to end; True when asked."""
        return self._stop.wait(seconds)

    def start(self, where: str, target: Callable[..., None], *args: Any) -> None:
        """Start ``target(*args)`` on a new thread (the previous one must be stopped)."""
        self._failure = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(where, target, args),
                                        name=self.name, daemon=True)
        self._thread.start()

    def _run(self, where: str, target: Callable[..., None], args: tuple[Any, ...]) -> None:
        try:
            target(*args)
        except DeviceError as err:
            if not self.stopping:
                self._failure = err
        except Exception as err:  # noqa: BLE001 - a bug must still reach /diagnostics
            if not self.stopping:
                self._failure = DeviceError(f'{where}: {self.name} failed: {err!r}')

    def stop(self, timeout: float) -> None:
        """Ask the thread to end and wait up to ``timeout`` [s] for it (not from itself)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)

    def failure(self) -> DeviceError | None:
        """Take the failure that ended the thread, if any (once)."""
        failure, self._failure = self._failure, None
        return failure
