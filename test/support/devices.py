"""Helpers of the device driver tests (lidar, motion capture, camera): what a driver did
(faults, retry delays, diagnostics) and devices that are down or talk nonsense.
"""

from __future__ import annotations

import os
import socket
import threading
import tty
from typing import Any

import numpy as np
from rclpy.parameter import Parameter
from support.nodes import probe

from enbarr_interfaces import topics

#: Reconnect fast, so that a test sees several retries.
FAST_RECONNECT = [Parameter('reconnect.initial_delay', value=0.05),
                  Parameter('reconnect.max_delay', value=0.2)]


def record_faults(driver: Any) -> list[str]:
    """Every fault message of ``driver`` from now on, in order (retries included)."""
    seen: list[str] = []
    fail = driver._fail

    def recording(err: Any) -> None:
        seen.append(str(err))
        fail(err)
    driver._fail = recording
    return seen


def record_delays(driver: Any) -> list[float]:
    """Every retry delay [s] ``driver`` schedules from now on, in order."""
    delays: list[float] = []
    schedule = driver._backoff.schedule

    def recording(now_ns: int) -> float:
        delay = schedule(now_ns)
        delays.append(round(delay, 6))
        return delay
    driver._backoff.schedule = recording
    return delays


def statuses(context: Any, executor: Any, hardware_id: str, name: str = 'listener') -> list:
    """The ``/diagnostics`` statuses of node ``hardware_id`` from now on (a probe listens)."""
    seen: list = []
    probe(context, executor, name).create_subscription(
        topics.DIAGNOSTICS.msg_type, topics.DIAGNOSTICS.name,
        lambda m: seen.extend(s for s in m.status if s.hardware_id == hardware_id),
        topics.DIAGNOSTICS.qos)
    return seen


def values(status: Any) -> dict[str, str]:
    """The key/value pairs of a diagnostic status."""
    return {kv.key: kv.value for kv in status.values}


def free_tcp_port() -> int:
    """A loopback TCP port where nothing listens (bound and released at once)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class NoisyPort:
    """A pseudo-terminal whose far end sends only noise and never answers (a wrong device or
    a wrong baud rate on the port): seeded random bytes, none of them 0xA5, every 10 ms.
    """

    def __init__(self, seed: int = 7) -> None:
        self._rng = np.random.default_rng(seed)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='noisy_port', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.01):
            noise = self._rng.integers(0, 256, 40, dtype=np.uint8)
            noise[noise == 0xA5] = 0x5A
            try:
                os.read(self._master, 4096)   # what the driver asked: ignored
            except (BlockingIOError, OSError):
                pass
            try:
                os.write(self._master, noise.tobytes())
            except (BlockingIOError, OSError):
                pass  # nobody reads: the line drops it

    def close(self) -> None:
        """Stop the noise and close the pty."""
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self._master, self._slave):
            os.close(fd)
