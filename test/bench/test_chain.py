"""The chain benchmark's pure loops (``enbarr_core.bench.chain``): hot and paced.

Timing itself is a benchmark's business; these check what each measurement runs: how many
cycles, at what pacing, and that both chains' loops run.
"""

from __future__ import annotations

import time
from typing import Iterator

import pytest

from enbarr_core.bench import chain as bench


def counting() -> tuple[list[float], Iterator[None]]:
    calls: list[float] = []

    def loop() -> Iterator[None]:
        while True:
            calls.append(time.monotonic())
            yield
    return calls, loop()


def test_hot_runs_the_cycles_back_to_back() -> None:
    calls, loop = counting()
    assert bench.hot(loop, cycles=50) >= 0.0
    assert len(calls) == 50


class FakeClock:
    """Monotonic time that only sleeping moves: the pacing judged without the machine's
    load (a sleep that runs late on a busy machine makes the next cycle catch up)."""

    def __init__(self) -> None:
        self.t = 100.0

    def monotonic(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def test_paced_runs_one_cycle_per_period(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock()
    for name in ('monotonic', 'sleep'):
        monkeypatch.setattr(bench.time, name, getattr(clock, name))
    calls: list[float] = []

    def loop() -> Iterator[None]:
        while True:
            calls.append(clock.t)
            clock.t += 0.004      # a cycle's own work: the sleep makes up the rest
            yield
    bench.paced_cycles(loop(), rate=100.0, seconds=0.3)
    assert len(calls) == 30
    gaps = [b - a for a, b in zip(calls, calls[1:])]
    assert gaps == pytest.approx([0.01] * 29)


def test_paced_runs_at_least_twenty_cycles() -> None:
    calls, loop = counting()
    bench.paced_cycles(loop, rate=1000.0, seconds=0.001)
    assert len(calls) == 20


@pytest.mark.parametrize('make', [bench.pure_rov, bench.pure_saucer])
def test_the_pure_loops_run(make) -> None:
    loop = make(50.0)
    for _ in range(5):
        next(loop)
    assert 0.0 < bench.hot(loop, cycles=20) < 1.0
