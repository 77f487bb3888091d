"""How a bringup process hears that it must stop.

SIGINT and SIGTERM set a flag; a supervised group gets its parent's death as a signal.
"""

from __future__ import annotations

import signal
import time
from typing import Any

#: The longest slice of any wait of bringup [s]: a stop request is served within it.
STOP_POLL = 0.1


class StopRequest:
    """SIGINT/SIGTERM set a flag that the spin loop and every wait of the supervisor check.

    rclpy's own handlers are off so that the context still works while thrusters are put in
    their safe state. ``count`` counts the requests: a second one while children are being
    stopped ends their grace period.
    """

    #: The stop of the run in progress in this process, if any (``VesselGuard`` waits on it).
    active: StopRequest | None = None

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None
        self.count = 0
        self._old: dict[int, Any] = {}
        self._outer: StopRequest | None = None

    def __enter__(self) -> StopRequest:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        self._outer, StopRequest.active = StopRequest.active, self
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        self.signal = signum
        self.count += 1

    def sleep(self, seconds: float) -> bool:
        """Sleep ``seconds`` or until a stop is requested; True when one was."""
        deadline = time.monotonic() + seconds
        while not self.requested:
            left = deadline - time.monotonic()
            if left <= 0.0:
                break
            time.sleep(min(left, STOP_POLL))
        return self.requested

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        StopRequest.active = self._outer


def die_with_parent(signum: int = signal.SIGTERM) -> None:
    """In a child process: get ``signum`` when the parent dies (Linux; 0: no signal)."""
    try:
        import ctypes
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(1, int(signum))  # PR_SET_PDEATHSIG
    except OSError:
        pass
