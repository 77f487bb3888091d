"""The command receiver's rules, free of ROS: validation, staleness and the failsafe.

A surface velocity command is accepted only when it is finite, within the configured limits,
given in the body frame (``frame_id`` ``base_link``, or empty: a sender that names no frame
means the body frame the topic's contract states), and on time: its stamp no older than
``max_age``, no further ahead than ``max_future``, and later than the last accepted command's
(the time policy of ``framework.stamps``; verdicts ``stale``, ``future``, ``not_newer``). A
command the node refuses for a reason of its own (``contested``: two sources at once, see
``framework.sources``) is counted here with ``withdraw``, which also drops the goal to zero
at once. The goal falls to
zero when no command was accepted for ``timeout`` seconds: a lost tether or a crashed
operator station stops the vehicle instead of leaving it driving.

Boundaries (times are integer nanoseconds of one clock; the settings' seconds are rounded to
whole nanoseconds once): every limit is inclusive. A component of exactly ``max_linear`` /
``max_angular`` is accepted, a stamp exactly ``max_age`` old or exactly ``max_future`` ahead
is accepted, and the goal is held up to and including ``timeout`` after the last accepted
command; it is zero from ``timeout`` + 1 ns on. A node that publishes the goal every period
P therefore publishes zero at most ``timeout`` + P after the last accepted command.
"""

from __future__ import annotations

from dataclasses import dataclass
import enum
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict

#: The frame velocity commands are expressed in (``enbarr_interfaces.topics.BODY_FRAME``).
BODY_FRAME = 'base_link'


class Verdict(enum.Enum):
    """What the gate made of one command."""

    ACCEPTED = 'accepted'
    NON_FINITE = 'non_finite'
    OUT_OF_RANGE = 'out_of_range'
    STALE = 'stale'
    FUTURE = 'future'
    NOT_NEWER = 'not_newer'
    WRONG_FRAME = 'wrong_frame'
    CONTESTED = 'contested'


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


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


class CommandGate:
    """Holds the current velocity goal; times in integer nanoseconds of one clock."""

    _stamps: StampGate  # made by the first settings swap, kept (with its order) by later ones

    def __init__(self, settings: GateSettings = GateSettings()) -> None:
        self.settings = settings
        self.goal: NDArray[np.float64] = np.zeros(6)
        self.last_accept_ns: int | None = None
        self.counts = {v: 0 for v in Verdict}

    @property
    def settings(self) -> GateSettings:
        """Return the limits in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: GateSettings) -> None:
        """Swap the limits (validated first); the goal and the last acceptance are kept."""
        settings.validate()
        self._settings = settings
        self._timeout_ns = _ns(settings.timeout)
        self._max_age_ns = _ns(settings.max_age)
        self._max_future_ns = _ns(settings.max_future)
        # The order of accepted stamps (and a clock that went back) as the time policy has it;
        # age and future are judged above, with this gate's inclusive boundaries.
        policy = StampPolicy(max_future=settings.max_future)
        if hasattr(self, '_stamps'):
            self._stamps.policy = policy
        else:
            self._stamps = StampGate(policy)

    def check(self, nu: NDArray[np.float64], stamp_ns: int, now_ns: int,
              frame_id: str = BODY_FRAME) -> Verdict:
        """Judge ``nu`` stamped ``stamp_ns`` in ``frame_id`` at ``now_ns`` without taking it."""
        s = self.settings
        if not np.all(np.isfinite(nu)):
            return Verdict.NON_FINITE
        if np.any(np.abs(nu[:3]) > s.max_linear) or np.any(np.abs(nu[3:]) > s.max_angular):
            return Verdict.OUT_OF_RANGE
        if frame_id not in ('', BODY_FRAME):
            return Verdict.WRONG_FRAME
        if now_ns - stamp_ns > self._max_age_ns:
            return Verdict.STALE
        if stamp_ns - now_ns > self._max_future_ns:
            return Verdict.FUTURE
        if self._stamps.check(stamp_ns, now_ns) is StampVerdict.NOT_NEWER:
            return Verdict.NOT_NEWER
        return Verdict.ACCEPTED

    def offer(self, nu: NDArray[np.float64], stamp_ns: int, now_ns: int,
              frame_id: str = BODY_FRAME) -> Verdict:
        """Take ``nu`` as the goal if it passes ``check``; count the verdict."""
        verdict = self.check(nu, stamp_ns, now_ns, frame_id)
        self.counts[verdict] += 1
        if verdict is Verdict.ACCEPTED:
            self._stamps.offer(stamp_ns, now_ns)  # the order goes on from this stamp
            self.goal = np.array(nu, dtype=float)
            self.last_accept_ns = now_ns
        return verdict

    def withdraw(self, verdict: Verdict) -> None:
        """Count a command refused by the node (``verdict``) and drop the goal to zero now."""
        if verdict is Verdict.ACCEPTED:
            raise ValueError('withdraw takes the reason of a refusal, not accepted')
        self.counts[verdict] += 1
        self.goal = np.zeros(6)
        self.last_accept_ns = None

    def failsafe(self, now_ns: int) -> bool:
        """Return True when no command was accepted within ``timeout`` (the goal is then zero)."""
        # A clock that went back before the last acceptance (a restarted simulation, a bag
        # played again) says nothing about the command's age: fail safe too.
        return (self.last_accept_ns is None or now_ns < self.last_accept_ns
                or now_ns - self.last_accept_ns > self._timeout_ns)

    def current_goal(self, now_ns: int) -> NDArray[np.float64]:
        """Return the velocity goal now: the last accepted command, zero in failsafe."""
        if self.failsafe(now_ns):
            self.goal = np.zeros(6)
        return self.goal
