"""Thruster failures: what an allocator is told is broken, and where it is told from.

An allocator (``fixed.ThrustAllocator``, ``azimuth.AzimuthAllocator``) drops a failed thruster
from its solution; this module is the vocabulary both the operator and a fault detector use
to say so, and it knows nothing of ROS.

An entry is a string, the same in the ``failed_thrusters`` parameter and in ``/diagnostics``:

- ``name`` or ``name:dead``: the thruster produces nothing (it is commanded zero);
- ``name:stuck:<deg>``: an azimuth whose servo is stuck at ``<deg>`` degrees (the thrust
  still works, along that fixed direction only).

A detector reports a failure on ``/diagnostics`` with a ``DiagnosticStatus`` at level ERROR
whose ``values`` hold one key ``failed_thruster`` (``DIAGNOSTIC_KEY``) per failed thruster,
its value an entry as above. The latest status of a source (``DiagnosticStatus.name``) is what
that source says: a later status from the same source at another level, or without the key,
clears what it reported before. The operator's list and every source's list are merged.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
import math

DEAD = 'dead'
STUCK = 'stuck'

DIAGNOSTIC_KEY = 'failed_thruster'
"""Key of a ``DiagnosticStatus`` value that names a failed thruster (its value: an entry)."""

DIAGNOSTIC_ERROR = 2
"""``diagnostic_msgs/DiagnosticStatus.ERROR``: only a status at this level reports failures."""


@dataclass(frozen=True)
class Failure:
    """How one thruster failed: ``mode`` is ``DEAD`` or ``STUCK`` (then at ``angle`` [rad])."""

    mode: str = DEAD
    angle: float = 0.0  # [rad] the stuck servo's angle, CCW from surge; 0 when dead

    def __post_init__(self) -> None:
        if self.mode not in (DEAD, STUCK):
            raise ValueError(f'failure mode must be {DEAD!r} or {STUCK!r}, got {self.mode!r}')
        if not math.isfinite(self.angle):
            raise ValueError(f'stuck angle must be finite, got {self.angle!r}')

    def entry(self, name: str) -> str:
        """Return the entry of thruster ``name`` failed this way (``parse_entry``'s inverse)."""
        if self.mode == DEAD:
            return f'{name}:{DEAD}'
        return f'{name}:{STUCK}:{math.degrees(self.angle):g}'


def parse_entry(entry: str, known: Sequence[str],
                allow_stuck: bool) -> tuple[str, Failure]:
    """``(name, Failure)`` of one entry (see the module docstring).

    Raises ValueError naming the entry when the thruster is not in ``known``, the mode is
    unknown, or a stuck angle is missing, not a number, or not allowed (fixed thrusters).
    """
    parts = [p.strip() for p in str(entry).split(':')]
    name = parts[0]
    if name not in known:
        raise ValueError(f'{entry!r}: unknown thruster {name!r}; expected one of '
                         f'{", ".join(known)}')
    mode = parts[1] if len(parts) > 1 else DEAD
    if mode == DEAD and len(parts) <= 2:
        return name, Failure()
    if mode == STUCK and allow_stuck and len(parts) == 3:
        try:
            deg = float(parts[2])
        except ValueError:
            deg = math.nan
        if not math.isfinite(deg):
            raise ValueError(f'{entry!r}: the stuck angle must be a number of degrees, '
                             f'got {parts[2]!r}')
        return name, Failure(STUCK, math.radians(deg))
    forms = f'{name}, {name}:{DEAD}' + (f' or {name}:{STUCK}:<deg>' if allow_stuck else '')
    raise ValueError(f'{entry!r}: expected {forms}')


def parse_entries(entries: Iterable[str], known: Sequence[str],
                  allow_stuck: bool) -> dict[str, Failure]:
    """Return the failures of ``entries`` (empty strings skipped), by thruster name.

    Raises ValueError naming the bad entry (see ``parse_entry``), or a thruster listed twice.
    """
    out: dict[str, Failure] = {}
    for entry in entries:
        if not str(entry).strip():
            continue
        name, failure = parse_entry(entry, known, allow_stuck)
        if name in out:
            raise ValueError(f'{entry!r}: thruster {name!r} is listed twice')
        out[name] = failure
    return out


class FailureBook:
    """The failures the operator set and those each ``/diagnostics`` source reports, merged.

    The operator's entry wins for a thruster both name (the operator can see it is stuck
    rather than dead). ``merged()`` is what the allocator should run with.
    """

    def __init__(self, known: Sequence[str], allow_stuck: bool) -> None:
        self.known = tuple(known)
        self.allow_stuck = allow_stuck
        self.operator: dict[str, Failure] = {}
        self.sources: dict[str, dict[str, Failure]] = {}

    def set_operator(self, failures: Mapping[str, Failure]) -> None:
        """Replace the operator's failures (already validated by ``parse_entries``)."""
        self.operator = dict(failures)

    def report(self, source: str, level: int,
               values: Iterable[tuple[str, str]]) -> list[str]:
        """Take one status of ``source``; return the problems with its entries (ignored).

        At ``DIAGNOSTIC_ERROR`` every ``DIAGNOSTIC_KEY`` value is a failure; any other
        status of the same source clears what it reported.
        """
        found: dict[str, Failure] = {}
        problems: list[str] = []
        if level == DIAGNOSTIC_ERROR:
            for key, value in values:
                if key != DIAGNOSTIC_KEY:
                    continue
                try:
                    name, failure = parse_entry(value, self.known, self.allow_stuck)
                except ValueError as err:
                    problems.append(f'{source}: {err}')
                    continue
                found[name] = failure
        if found:
            self.sources[source] = found
        else:
            self.sources.pop(source, None)
        return problems

    def merged(self) -> dict[str, Failure]:
        """Every failed thruster, in layout order, with how it failed."""
        out: dict[str, Failure] = {}
        for failures in self.sources.values():
            out.update(failures)
        out.update(self.operator)
        return {n: out[n] for n in self.known if n in out}
