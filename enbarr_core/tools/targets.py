"""A scenario's targets and the verdict on a run (``enbarr scenario``).

Every scenario states what it must achieve in its ``scenario`` section, one bound per figure
of its JSON line (the figures a scenario of that kind reports: ``metrics.FIGURES``)::

    scenario:
      targets:
        position_error_rms_m: {max: 0.01}        # a number: at most (inclusive)
        path_time_s: {min: 35.0, max: 55.0}      # at least and at most (inclusive)
        mode_changes: {max: 1}
        settled_in_time: true                    # a yes/no figure: this answer

The verdict (:func:`judge`) adds to the JSON line ``verdict`` (``pass`` or ``fail``),
``failed`` (the figures whose target failed, in the order stated; ``error`` first when the run
reported one) and ``targets`` (each figure's bound, its ``value`` and ``pass``). A figure the run
did not produce (``null``, or absent after an ``error``) fails its target; a run with an
``error`` fails whatever its targets say. ``enbarr scenario`` exits with ``EXIT_FAILED`` on a
failed verdict.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import difflib
import math
from typing import Any

from enbarr_core.framework.errors import ProfileError

EXIT_FAILED = 1  # ``enbarr scenario``'s exit status when a target failed (2: a user error)
BOUND_KEYS = ('min', 'max')


@dataclass(frozen=True)
class Target:
    """One stated target: ``low <= figure <= high`` for a number, ``figure is expected``."""

    name: str                      # a figure of the JSON line (``metrics.FIGURES``)
    low: float | None = None       # inclusive lower bound of a number
    high: float | None = None      # inclusive upper bound of a number
    expected: bool | None = None   # the answer of a yes/no figure

    def bound(self) -> dict[str, Any]:
        """Return the bound as the YAML states it (``{min, max}`` or ``{expected}``)."""
        if self.expected is not None:
            return {'expected': self.expected}
        return {k: v for k, v in (('min', self.low), ('max', self.high)) if v is not None}

    def met_by(self, value: Any) -> bool:
        """Whether ``value`` (the run's figure; None: it has none) meets the target."""
        if self.expected is not None:
            return value is self.expected
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            return False
        return bool((self.low is None or value >= self.low)
                    and (self.high is None or value <= self.high))  # numpy's bool too


def parse_targets(raw: Any, kind: str, known: Mapping[str, bool],
                  path: Any = None) -> tuple[Target, ...]:
    """Read and check a ``scenario.targets`` mapping for a scenario of ``kind``.

    ``known``: the figures of that kind, name -> whether it is yes/no
    (``metrics.figures_of``). ProfileError (naming ``scenario.targets`` and the figure) on
    anything else than a non-empty mapping of known figures to a bound of the figure's type.
    """
    key = 'scenario.targets'
    example = 'e.g. targets: {position_error_rms_m: {max: 0.05}, settled_in_time: true}'
    if raw is None:
        raise ProfileError(f'required: the figures this scenario must achieve ({example}); '
                           f'figures of a {kind} scenario: {", ".join(known)}',
                           path=path, key=key)
    if not isinstance(raw, Mapping) or not raw:
        raise ProfileError(f'expected a mapping of figure -> bound ({example}), got {raw!r}',
                           path=path, key=key)
    out = []
    for name, bound in raw.items():
        if name not in known:
            close = difflib.get_close_matches(str(name), list(known), n=1)
            hint = f'did you mean {close[0]!r}? ' if close else ''
            raise ProfileError(f'{name!r} is not a figure of a {kind} scenario; {hint}its '
                               f'figures: {", ".join(known)}', path=path, key=key)
        out.append(_target(str(name), bound, known[name], path, f'{key}.{name}'))
    return tuple(out)


def _target(name: str, bound: Any, boolean: bool, path: Any, key: str) -> Target:
    if boolean:
        if not isinstance(bound, bool):
            raise ProfileError(f'a yes/no figure: expected true or false, got {bound!r}',
                               path=path, key=key)
        return Target(name, expected=bound)
    expected = 'expected {max: N}, {min: N} or {min: N, max: N} (inclusive)'
    if not isinstance(bound, Mapping) or not bound or set(bound) - set(BOUND_KEYS):
        raise ProfileError(f'{expected}, got {bound!r}', path=path, key=key)
    values = {}
    for k, v in bound.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ProfileError(f'{expected}: {k} must be a finite number, got {v!r}',
                               path=path, key=key)
        values[k] = float(v)
    low, high = values.get('min'), values.get('max')
    if low is not None and high is not None and low > high:
        raise ProfileError(f'min {low} is above max {high}', path=path, key=key)
    return Target(name, low=low, high=high)


def judge(figures: Mapping[str, Any], targets: tuple[Target, ...]) -> dict[str, Any]:
    """Judge a run's ``figures`` against ``targets`` (see the module docstring).

    Returns ``verdict``, ``failed`` and ``targets`` ({figure: {bound..., value, pass}}), to
    add to the run's JSON line.
    """
    judged: dict[str, Any] = {}
    failed = ['error'] if 'error' in figures else []
    for target in targets:
        value = figures.get(target.name)
        ok = target.met_by(value)
        judged[target.name] = {**target.bound(), 'value': value, 'pass': ok}
        if not ok:
            failed.append(target.name)
    return {'verdict': 'fail' if failed else 'pass', 'failed': failed, 'targets': judged}


def describe(name: str, result: Mapping[str, Any]) -> str:
    """One line for people: ``position_error_rms_m 0.0024 <= 0.01: pass``."""
    value = result['value']
    shown = 'none' if value is None else str(value).lower() if isinstance(value, bool) \
        else f'{value:g}'
    if 'expected' in result:
        bound = f'is {str(result["expected"]).lower()}'
    else:
        low, high = result.get('min'), result.get('max')
        bound = (f'in [{low:g}, {high:g}]' if low is not None and high is not None
                 else f'>= {low:g}' if low is not None else f'<= {high:g}')
    return f'{name} = {shown}, {bound}: {"pass" if result["pass"] else "FAIL"}'
