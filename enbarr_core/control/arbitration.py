"""Which of several named command sources drives: priority and timeout, free of ROS.

In the manner of ROS's ``twist_mux``: each source has a name, its own topic, a priority
(a larger number wins) and a timeout. A source is live while its last accepted command is
no older than its timeout (inclusive, as the command gate holds a goal). The highest-priority
live source drives; when it falls silent the next live one below takes over, and when it
comes back it drives again at once. With no live source nothing drives, and the node's
command-loss failsafe holds the goal at zero.

A stop (the station's stop, ``Arbiter.set_stop``) wins over every source: while it is set
nothing drives and the goal is zero, whatever any source sends. It holds until released;
it has no timeout, so a station that stops and then falls silent leaves the vessel stopped.

Two sources may not share a priority: which of two equal ones drives would depend on
message timing, so such a configuration is refused. Times are integer nanoseconds of one
clock; a clock that went back before a source's last command makes that source not live
(it says nothing about the command's age, so the arbiter fails safe, as the gate does).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

#: What ``Arbiter.label`` says while the stop is set.
STOPPED = 'stop'
#: What ``Arbiter.label`` says while no source is live.
NONE = 'none'
_RESERVED = (STOPPED, NONE)


@dataclass(frozen=True)
class CommandSource:
    """One named command source."""

    name: str        # shown as the driving source (``surface_command/active_source``)
    topic: str       # its own velocity command topic
    priority: int    # larger wins
    timeout: float   # live while its last accepted command is no older than this [s]


@dataclass(frozen=True)
class ArbiterSettings:
    """The sources of one arbiter; ``validate`` names the first bad field."""

    sources: tuple[CommandSource, ...]

    @classmethod
    def from_arrays(cls, names: Sequence[str], topics: Sequence[str],
                    priorities: Sequence[int], timeouts: Sequence[float],
                    prefix: str = 'sources') -> ArbiterSettings:
        """Build from parallel arrays (how ROS 2 parameters carry a list); validated.

        ``ValueError`` names the field (``<prefix>.topics`` ...) when the lengths differ or a
        value does not fit.
        """
        n = len(names)
        for field, values in (('topics', topics), ('priorities', priorities),
                              ('timeouts', timeouts)):
            if len(values) != n:
                raise ValueError(f'{prefix}.{field} has {len(values)} entries, '
                                 f'{prefix}.names has {n}: one per source')
        settings = cls(tuple(CommandSource(str(a), str(b), int(c), float(d))
                             for a, b, c, d in zip(names, topics, priorities, timeouts)))
        settings.validate(prefix)
        return settings

    def validate(self, prefix: str = 'sources') -> None:
        """Raise ValueError naming the first bad field (``<prefix>.names[i]`` ...)."""
        if not self.sources:
            raise ValueError(f'{prefix}.names is empty: at least one source is needed')
        seen: dict[str, dict[object, int]] = {'names': {}, 'topics': {}, 'priorities': {}}
        for i, s in enumerate(self.sources):
            if not s.name or s.name in _RESERVED:
                raise ValueError(f'{prefix}.names[{i}] = {s.name!r}: a source needs a name, '
                                 f'and {" and ".join(_RESERVED)} are reserved')
            if not s.topic:
                raise ValueError(f'{prefix}.topics[{i}] is empty (source {s.name!r})')
            if not (math.isfinite(s.timeout) and s.timeout > 0.0):
                raise ValueError(f'{prefix}.timeouts[{i}] = {s.timeout} must be finite and '
                                 f'> 0 (source {s.name!r})')
            for field, value in (('names', s.name), ('topics', s.topic),
                                 ('priorities', s.priority)):
                if value in seen[field]:
                    j = seen[field][value]
                    raise ValueError(f'{prefix}.{field}[{i}] = {value!r} repeats '
                                     f'{prefix}.{field}[{j}]: each source needs its own')
                seen[field][value] = i


class Arbiter:
    """Picks the driving source (see the module docstring)."""

    def __init__(self, settings: ArbiterSettings) -> None:
        settings.validate()
        self.settings = settings
        # Highest priority first: select takes the first live one.
        self._order = sorted(settings.sources, key=lambda s: -s.priority)
        self._timeout_ns = {s.name: round(s.timeout * 1e9) for s in settings.sources}
        self._last_ns: dict[str, int | None] = {s.name: None for s in settings.sources}
        self.stopped = False

    def offer(self, name: str, now_ns: int) -> None:
        """Record that source ``name`` had a command accepted at ``now_ns``."""
        if name not in self._last_ns:
            raise KeyError(f'no command source named {name!r}')
        self._last_ns[name] = now_ns

    def withdraw(self, name: str) -> None:
        """Make source ``name`` not live now; the next live one takes over at once.

        For a command refused for a reason of the node (two publishers on its topic).
        """
        if name not in self._last_ns:
            raise KeyError(f'no command source named {name!r}')
        self._last_ns[name] = None

    def set_stop(self, stop: bool) -> None:
        """Set (True) or release (False) the stop that wins over every source."""
        self.stopped = bool(stop)

    def live(self, name: str, now_ns: int) -> bool:
        """Whether source ``name``'s last accepted command is no older than its timeout."""
        last = self._last_ns[name]
        return last is not None and last <= now_ns and now_ns - last <= self._timeout_ns[name]

    def select(self, now_ns: int) -> str | None:
        """Name of the source that drives at ``now_ns``; None when stopped or none is live."""
        if self.stopped:
            return None
        for s in self._order:
            if self.live(s.name, now_ns):
                return s.name
        return None

    def label(self, now_ns: int) -> str:
        """Return what drives, to show: a source's name, ``STOPPED`` or ``NONE``."""
        if self.stopped:
            return STOPPED
        return self.select(now_ns) or NONE
