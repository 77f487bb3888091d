"""Timed scripts, parsed once into typed steps; free of ROS.

The lines an operator stand-in (scripted surface commands, a scripted joystick) plays back.

A script is a list of lines ``'<time> <verb> <args...>'``, the time in seconds from the start,
blank lines and lines starting with ``#`` ignored; ``# text`` after a step is its note, which
the scripted surface logs when the step plays (a demo says what a step is there to show)::

    '0.0  twist 0.0 0.0 -0.2 0.0 0.0 0.0'
    '4.0  io gpio_12 true'
    '6.0  io manipulator true  # a refusal on purpose: a stepper takes steps'
    '9.0  stop'

The caller names its verbs, each with a function that turns the arguments into a typed value
(raising ``ValueError`` with the reason). ``parse_script`` returns the steps as a tuple in
time order; any error names the line (``script[3] '4.0 io gpio_12'``) and what is wrong.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
import re
from typing import Any

#: A step's note: ``#`` after white space, to the end of the line.
_NOTE = re.compile(r'\s#')

#: A verb's parser: its arguments -> the step's value; ``ValueError(reason)`` when they do not
#: fit (the reason is shown after the verb: ``'takes 6 numbers'``).
VerbParser = Callable[[Sequence[str]], Any]


@dataclass(frozen=True)
class Step:
    """One line of a script."""

    time: float   # from the start [s]
    verb: str
    value: Any    # what the verb's parser made of the arguments
    line: int     # index of the line in the script, for messages
    note: str = ''  # the line's '# ...' text, logged when the step plays


def parse_script(lines: Sequence[str], verbs: Mapping[str, VerbParser], *,
                 name: str = 'script') -> tuple[Step, ...]:
    """Parse ``lines`` with the ``verbs`` given; ``ValueError`` names the line.

    Times must be finite, >= 0 and must not decrease from one line to the next (a script is
    read top down; a time that goes back is a typo, not a request to reorder).
    """
    out: list[Step] = []
    expected = ', '.join(f'"{v}"' for v in verbs)
    for i, line in enumerate(lines):
        if line.lstrip().startswith('#'):
            continue
        text, note = line, ''
        found = _NOTE.search(line)
        if found:
            text, note = line[:found.start()], line[found.end():].strip()
        parts = text.split()
        if not parts:
            continue
        where = f'{name}[{i}] {line!r}'
        try:
            t = float(parts[0])
        except ValueError:
            raise ValueError(f'{where}: expected a time in seconds first') from None
        if not math.isfinite(t) or t < 0.0:
            raise ValueError(f'{where}: time must be finite and >= 0')
        if out and t < out[-1].time:
            raise ValueError(f'{where}: times must not decrease')
        verb = parts[1] if len(parts) > 1 else ''
        parser = verbs.get(verb)
        if parser is None:
            raise ValueError(f'{where}: expected {expected} after the time')
        try:
            value = parser(parts[2:])
        except ValueError as err:
            raise ValueError(f'{where}: {verb} {err}') from None
        out.append(Step(t, verb, value, i, note))
    return tuple(out)


def numbers(args: Sequence[str], n: int, what: str, low: float = -math.inf,
            high: float = math.inf) -> tuple[float, ...]:
    """``n`` finite numbers within [low, high]; the reason names ``what`` they are."""
    try:
        values = tuple(float(a) for a in args)
    except ValueError:
        raise ValueError(f'takes {n} numbers {what}') from None
    if len(values) != n or not all(math.isfinite(x) for x in values):
        raise ValueError(f'takes {n} finite numbers {what}')
    if not all(low <= x <= high for x in values):
        raise ValueError(f'takes {n} numbers {what} within {low}..{high}')
    return values


def no_arguments(args: Sequence[str]) -> None:
    """For a verb that takes nothing (``stop``)."""
    if args:
        raise ValueError('takes no arguments')
