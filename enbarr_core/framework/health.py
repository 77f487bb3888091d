"""How a node tells ``/diagnostics`` the truth about its inputs.

``InputHealth`` counts, per input, the samples a node accepted and those it refused or dropped
(by reason), and the resets its inputs caused (a filter re-initialized, an integrator
cleared). Each diagnostics report closes a window: the node is *degraded* (WARN) when in that
window an input lost more than ``degraded_fraction`` of its samples, or anything was reset,
and says which and why; totals since start travel in the status values. A node whose inputs
are fine but which is failing in its own way (failsafe, stale) combines both with ``worst``.

``IntervalMeter`` measures the period at which an input really arrives (the median of recent
intervals), so that a setting that only makes sense against that period (a gap tolerance, a
timeout) can be refused with the measured figure as its reason.

Pure: no rclpy.
"""

from __future__ import annotations

from collections import Counter, deque

import numpy as np

OK = 0
DEGRADED = 1   # diagnostic_msgs/DiagnosticStatus.WARN
ERROR = 2


class InputHealth:
    """Windowed and total counts of accepted, refused and reset inputs of one node."""

    def __init__(self, degraded_fraction: float = 0.05) -> None:
        if not 0.0 <= degraded_fraction < 1.0:
            raise ValueError(f'degraded_fraction must be in [0, 1), got {degraded_fraction}')
        self.degraded_fraction = degraded_fraction
        # Counts of closed windows; the open window's are added when it closes (``totals``
        # adds them on the fly), so that a sample costs one count, not two.
        self._closed: Counter[tuple[str, str]] = Counter()
        self._window: dict[tuple[str, str], int] = {}
        self._inputs: dict[str, None] = {}  # insertion-ordered set

    @property
    def totals(self) -> Counter[tuple[str, str]]:
        """Return the counts since start per (input, reason): a copy."""
        totals = Counter(self._closed)
        totals.update(self._window)
        return totals

    def accepted(self, name: str, n: int = 1) -> None:
        """Count ``n`` samples of input ``name`` that the node used."""
        # The hot path (every sample of every input): one dict update once the key exists.
        key = (name, 'accepted')
        window = self._window
        if key in window:
            window[key] += n
        else:
            self._count(name, 'accepted', n)

    def refused(self, name: str, reason: str, n: int = 1) -> None:
        """Count ``n`` samples of input ``name`` refused or dropped for ``reason``."""
        if reason == 'accepted':
            raise ValueError("'accepted' is not a reason to refuse")
        self._count(name, reason, n)

    def reset(self, what: str) -> None:
        """Count a reset the inputs caused (``what``: e.g. 'filter', 'integrator')."""
        self._count('reset', what, 1)

    def _count(self, name: str, reason: str, n: int) -> None:
        self._inputs.setdefault(name, None)
        key = (name, reason)
        self._window[key] = self._window.get(key, 0) + n

    def report(self, window_s: float) -> tuple[int, str, dict[str, int]]:
        """Close the window (``window_s`` long, for the message): (level, message, totals).

        The level is ``DEGRADED`` when an input lost more than ``degraded_fraction`` of its
        samples in the window or anything was reset; the message names each such input with
        its figures ('imu/data_raw: refused 12 of 412 in 1.0 s (future 12)').
        """
        findings: list[str] = []
        for name in self._inputs:
            counts = {r: n for (i, r), n in self._window.items() if i == name and n}
            if name == 'reset':
                if counts:
                    findings.append('reset ' + ', '.join(
                        f'{what} {n}x' for what, n in counts.items()) + f' in {window_s:g} s')
                continue
            lost = sum(n for r, n in counts.items() if r != 'accepted')
            total = lost + counts.get('accepted', 0)
            if lost and lost > self.degraded_fraction * total:
                why = ', '.join(f'{r} {n}' for r, n in counts.items() if r != 'accepted')
                findings.append(f'{name}: refused {lost} of {total} in {window_s:g} s ({why})')
        self._closed.update(self._window)
        self._window.clear()
        values = {f'{i}.{r}': n for (i, r), n in self._closed.items()}
        if findings:
            return DEGRADED, 'degraded: ' + '; '.join(findings), values
        return OK, 'ok', values


def worst(*statuses: tuple[int, str]) -> tuple[int, str]:
    """Combine (level, message) pairs: the highest level; messages of the non-ok ones."""
    level = max(s[0] for s in statuses)
    if level == OK:
        return OK, 'ok'
    return level, '; '.join(m for lv, m in statuses if lv != OK)


#: A tolerance of lost input (a gap, a timeout) must cover this many measured input periods:
#: one lost sample is not a gap.
COVER_PERIODS = 2.0


def too_short_for_rate(name: str, value: float, topic: str, period: float | None,
                       consequence: str) -> str | None:
    """Say why tolerance ``name`` [s] is too short for ``topic``'s measured ``period`` [s].

    None when ``value`` covers ``COVER_PERIODS`` periods, or nothing is measured yet.
    """
    if period is None or value >= COVER_PERIODS * period:
        return None
    return (f'{name} {value:g} s is shorter than {COVER_PERIODS:g} periods of {topic} '
            f'(period measured {period:.3g} s): {consequence}')


def future_tolerance_problem(max_future: float, period: float | None,
                             topic: str) -> str | None:
    """Say why ``max_future`` [s] is not under the period of ``topic`` (None when it is).

    Under one period, a sample accepted early by up to ``max_future`` never hides the next
    good one: a bad sample costs at most itself.
    """
    if period is None or max_future < period:
        return None
    return (f'max_future {max_future:g} s is not under the period of {topic} (period '
            f'measured {period:.3g} s): one early sample could hide the next good one')


class IntervalMeter:
    """The period at which an input arrives: median of the last ``size`` stamp intervals."""

    def __init__(self, size: int = 64) -> None:
        self._intervals: deque[int] = deque(maxlen=size)
        self._last: int | None = None

    def add(self, stamp_ns: int) -> None:
        """Note an accepted sample's stamp [ns] (stamps that do not advance are ignored)."""
        if self._last is not None and stamp_ns > self._last:
            self._intervals.append(stamp_ns - self._last)
        if self._last is None or stamp_ns > self._last:
            self._last = stamp_ns

    def reset(self) -> None:
        """Forget the stream (a new one starts; the measured period is kept)."""
        self._last = None

    @property
    def period(self) -> float | None:
        """Median interval [s] of the recent samples; None before 8 intervals were seen."""
        if len(self._intervals) < 8:
            return None
        return float(np.median(np.fromiter(self._intervals, dtype=np.int64))) * 1e-9
