"""The time policy of stamped inputs: which sample may become a node's time base.

Every node that takes dt, an age or a deadline from a message's ``header.stamp`` (sensors,
poses, commands, the joystick) passes each sample through a ``StampGate`` first. A sample is
refused, counted and otherwise ignored when its stamp is

- further ahead of the node's clock than ``max_future`` (``FUTURE``): a sender whose clock
  runs ahead (another computer, a bad driver) must not drag the node's time base into the
  future, where every good sample after it would look old;
- not later than the last accepted stamp (``NOT_NEWER``): a repeat, or out of order;
- older than ``max_age`` when the input has one (``STALE``).

So one bad sample costs at most itself: only accepted stamps become the time base, and an
accepted stamp is at most ``max_future`` ahead of the clock, which bounds how long good
samples after it can be refused (``max_future``; choose it well under the input's period
when sender and receiver share a clock). When the node's clock itself goes back by more than
``max_future`` past the last accepted stamp (a simulation restarted, a bag played again) the
stream starts over (``clock_resets``): the clock is the reference, not the senders.

Times are integer nanoseconds of the node's clock; limits are whole nanoseconds. Pure: no
rclpy (``docs/architecture.md``, Time).
"""

from __future__ import annotations

from dataclasses import dataclass
import enum
import math


#: ``max_future`` of inputs whose sender shares the receiver's clock (one machine: the
#: vehicle's own sensors, drivers and chain) [s]. A good stamp is then never ahead of the
#: clock; 2 ms stays under the 2.5 ms period of a 400 Hz IMU, so that a sample accepted early
#: never hides the next good one.
SAME_CLOCK_MAX_FUTURE = 0.002


class StampVerdict(enum.Enum):
    """What the time policy made of one sample's stamp."""

    ACCEPTED = 'accepted'
    FUTURE = 'future'
    NOT_NEWER = 'not_newer'
    STALE = 'stale'

    # Members are singletons compared by identity: hash them as such, in C (Enum's own
    # ``__hash__`` hashes the name in Python, once per count on every sample).
    __hash__ = object.__hash__


_ACCEPTED, _FUTURE = StampVerdict.ACCEPTED, StampVerdict.FUTURE
_NOT_NEWER, _STALE = StampVerdict.NOT_NEWER, StampVerdict.STALE


@dataclass(frozen=True)
class StampPolicy:
    """Tolerances of one input [s]; ``max_age`` None: the input's age is judged elsewhere."""

    max_future: float = 0.02
    max_age: float | None = None

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        if not (math.isfinite(self.max_future) and self.max_future >= 0.0):
            raise ValueError(f'max_future must be finite and >= 0, got {self.max_future}')
        if self.max_age is not None and not (math.isfinite(self.max_age)
                                             and self.max_age > 0.0):
            raise ValueError(f'max_age must be finite and > 0, got {self.max_age}')


class StampGate:
    """Applies a ``StampPolicy`` to one stream of samples and counts what it refuses."""

    def __init__(self, policy: StampPolicy = StampPolicy()) -> None:
        self.policy = policy
        self.last_ns: int | None = None
        self.counts = {v: 0 for v in StampVerdict}
        self.clock_resets = 0

    @property
    def policy(self) -> StampPolicy:
        """Return the tolerances in use."""
        return self._policy

    @policy.setter
    def policy(self, policy: StampPolicy) -> None:
        """Swap the tolerances (validated first); the last accepted stamp is kept."""
        policy.validate()
        self._policy = policy
        self._max_future_ns = round(policy.max_future * 1e9)
        self._max_age_ns = None if policy.max_age is None else round(policy.max_age * 1e9)

    def check(self, stamp_ns: int, now_ns: int) -> StampVerdict:
        """Judge a sample stamped ``stamp_ns`` arriving at ``now_ns``, without taking it."""
        if stamp_ns - now_ns > self._max_future_ns:
            return _FUTURE
        last = self.last_ns
        if last is not None and stamp_ns <= last and now_ns >= last - self._max_future_ns:
            return _NOT_NEWER
        if self._max_age_ns is not None and now_ns - stamp_ns > self._max_age_ns:
            return _STALE
        return _ACCEPTED

    def offer(self, stamp_ns: int, now_ns: int) -> StampVerdict:
        """Judge and count a sample; an accepted stamp becomes the stream's last."""
        verdict = self.check(stamp_ns, now_ns)
        self.counts[verdict] += 1
        if verdict is _ACCEPTED:
            last = self.last_ns
            if last is not None and stamp_ns <= last:
                self.clock_resets += 1  # the clock went back past the last stamp: start over
            self.last_ns = stamp_ns
        return verdict

    def reset(self) -> None:
        """Forget the last accepted stamp (the next in-time sample starts the stream)."""
        self.last_ns = None

    @property
    def refused(self) -> int:
        """Return how many samples were refused, whatever the reason."""
        return sum(n for v, n in self.counts.items() if v is not StampVerdict.ACCEPTED)
