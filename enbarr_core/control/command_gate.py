"""The command receiver's rules, free of ROS: validation, staleness and the failsafe.

A surface velocity command is accepted only when it is finite, within the configured limits
and fresh (its stamp no older than ``max_age`` and not from the future). The goal falls to
zero when no command was accepted for ``timeout`` seconds: a lost tether or a crashed
operator station stops the vehicle instead of leaving it driving.
"""

from __future__ import annotations

from dataclasses import dataclass
import enum
import math

import numpy as np
from numpy.typing import NDArray


class Verdict(enum.Enum):
    """What the gate made of one command."""

    ACCEPTED = 'accepted'
    NON_FINITE = 'non_finite'
    OUT_OF_RANGE = 'out_of_range'
    STALE = 'stale'
    FUTURE = 'future'


@dataclass(frozen=True)
class GateSettings:
    """Limits, staleness and failsafe timeout of the gate."""

    max_linear: float = 1.0      # largest |u|, |v|, |w| accepted [m/s]
    max_angular: float = 1.0     # largest |p|, |q|, |r| accepted [rad/s]
    timeout: float = 0.5         # no accepted command for this long -> zero goal [s]
    max_age: float = 0.5         # older stamps are stale [s]
    max_future: float = 0.05     # stamps further in the future are refused [s]

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ('max_linear', 'max_angular', 'timeout', 'max_age', 'max_future'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')
        if self.timeout <= 0.0:
            raise ValueError(f'timeout must be > 0, got {self.timeout}')


class CommandGate:
    """Holds the current velocity goal; times in integer nanoseconds of one clock."""

    def __init__(self, settings: GateSettings = GateSettings()) -> None:
        settings.validate()
        self.settings = settings
        self.goal: NDArray[np.float64] = np.zeros(6)
        self.last_accept_ns: int | None = None
        self.counts = {v: 0 for v in Verdict}

    def check(self, nu: NDArray[np.float64], stamp_ns: int, now_ns: int) -> Verdict:
        """Judge ``nu`` stamped ``stamp_ns`` at ``now_ns`` without taking it."""
        s = self.settings
        if not np.all(np.isfinite(nu)):
            return Verdict.NON_FINITE
        if np.any(np.abs(nu[:3]) > s.max_linear) or np.any(np.abs(nu[3:]) > s.max_angular):
            return Verdict.OUT_OF_RANGE
        if now_ns - stamp_ns > s.max_age * 1e9:
            return Verdict.STALE
        if stamp_ns - now_ns > s.max_future * 1e9:
            return Verdict.FUTURE
        return Verdict.ACCEPTED

    def offer(self, nu: NDArray[np.float64], stamp_ns: int, now_ns: int) -> Verdict:
        """Take ``nu`` as the goal if it passes ``check``; count the verdict."""
        verdict = self.check(nu, stamp_ns, now_ns)
        self.counts[verdict] += 1
        if verdict is Verdict.ACCEPTED:
            self.goal = np.array(nu, dtype=float)
            self.last_accept_ns = now_ns
        return verdict

    def failsafe(self, now_ns: int) -> bool:
        """Return True when no command was accepted within ``timeout`` (the goal is then zero)."""
        return (self.last_accept_ns is None
                or now_ns - self.last_accept_ns > self.settings.timeout * 1e9)

    def current_goal(self, now_ns: int) -> NDArray[np.float64]:
        """Return the velocity goal now: the last accepted command, zero in failsafe."""
        if self.failsafe(now_ns):
            self.goal = np.zeros(6)
        return self.goal
