"""Helpers of the device driver tests: time passing without a start, and what a node sent.

A driver's constructor must open, write and publish nothing (``bringup --check`` builds every
node of a profile). The tests prove a negative, so they let the executor run the node's timers
for a while (``pass_time``: a bounded spin on a timer of the node's own, never a sleep) and
then look at what reached the bus, the pins and the topics.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray

from enbarr_interfaces import topics
from support.nodes import TIMEOUT

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
