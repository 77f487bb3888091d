"""Helpers of the device driver tests.

- A driver's constructor must open, write and publish nothing (``bringup --check`` builds
  every node of a profile). The tests prove a negative, so they let the executor run the
  node's timers for a while (``pass_time``: a bounded spin on a timer of the node's own,
  never a sleep) and then look at what reached the bus, the pins and the topics.
- What a driver did (faults, retry delays, diagnostics), and devices that are down or talk
  nonsense (lidar, motion capture, camera).
"""

from __future__ import annotations

from collections.abc import Callable
import os
import socket
import threading
import tty
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.parameter import Parameter
from support.nodes import probe, TIMEOUT

from enbarr_interfaces import topics

#: Long enough for a supervision timer (0.5 s) and a diagnostics report (1 s) to come due.
IDLE = 1.2  # [s]


def pass_time(executor: Any, spin: Callable[..., bool], node: Any, seconds: float = IDLE,
              period: float = 0.1) -> None:
    """Spin ``executor`` until a timer of ``node`` has ticked ``seconds`` worth of periods."""
    ticks = [0]
    timer = node.create_timer(period, lambda: ticks.__setitem__(0, ticks[0] + 1))
    try:
        assert spin(executor, lambda: ticks[0] * period >= seconds, TIMEOUT)
    finally:
        node.destroy_timer(timer)


def diagnostics_of(probe: Any, name: str) -> list[Any]:
    """Record the ``/diagnostics`` statuses of the node called ``name`` (the list fills)."""
    seen: list[Any] = []
    probe.create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS.name,
        lambda m: seen.extend(s for s in m.status if s.hardware_id == name),
        topics.DIAGNOSTICS.qos)
    return seen


class MockFactories:
    """Every gpiozero ``MockFactory`` made while installed (``monkeypatch`` undoes it).

    The drivers make their factory when they open their pins (``io/pins.make_factory``
    imports ``MockFactory`` at that moment), so an empty ``made`` means no pin was claimed.
    """

    def __init__(self, monkeypatch: Any) -> None:
        from gpiozero.pins import mock
        made: list[Any] = []
        self.made = made

        class Recording(mock.MockFactory):
            def __init__(self, *args: Any, **kwargs: Any) -> None:
                super().__init__(*args, **kwargs)
                made.append(self)

        monkeypatch.setattr(mock, 'MockFactory', Recording)

    def pins(self) -> list[Any]:
        """Every pin claimed on any recorded factory."""
        return [pin for factory in self.made for pin in factory.pins.values()]


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
    return diagnostics_of(probe(context, executor, name), hardware_id)


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
