"""Shared validation of settings dataclasses: every error names the field (``ValueError``)."""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any, Literal, overload

import numpy as np

#: The longest time span anything is asked to last [s]: 365 days (a command's duration, a
#: scenario's). Beyond it a sleep or a timer overflows (threading's TIMEOUT_MAX, int64
#: nanoseconds), and no run means it: a run with no end is asked for by leaving it out.
MAX_SECONDS = 365 * 86_400.0


def check_gain_vectors(settings: Any, names: Sequence[str], size: int, labels: str, *,
                       may_be_infinite: Sequence[str] = (),
                       positive: Sequence[str] = ()) -> None:
    """Check that each named field is ``size`` non-negative numbers.

    ``labels`` names the entries in the message. Each is finite unless in ``may_be_infinite``
    (+inf: no limit), never NaN, and > 0 when in ``positive``.
    """
    for name in names:
        raw = getattr(settings, name)
        try:
            value = np.asarray(raw, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{name}: must be {size} numbers, got {raw!r}') from exc
        if value.shape != (size,):
            raise ValueError(f'{name}: must have {size} entries [{labels}], got {raw!r}')
        if np.isnan(value).any() or (
                name not in may_be_infinite and not np.isfinite(value).all()):
            raise ValueError(f'{name}: must be finite, got {raw!r}')
        if (value < 0.0).any():
            raise ValueError(f'{name}: must be non-negative, got {raw!r}')
        if name in positive and (value <= 0.0).any():
            raise ValueError(f'{name}: must be positive, got {raw!r}')


def check_non_negative(settings: Any, names: Sequence[str]) -> None:
    """Each named field is a finite number >= 0."""
    for name in names:
        raw = getattr(settings, name)
        try:
            value = float(raw)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{name}: must be a number, got {raw!r}') from exc
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f'{name}: must be finite and non-negative, got {raw!r}')


def number(name: str, value: Any, *, finite: bool = True) -> float:
    """``value`` (a number, not a boolean) as a float, else ``ValueError`` naming ``name``.

    ``finite`` refuses NaN and +/-inf.
    """
    if isinstance(value, bool):
        raise ValueError(f'{name}: expected a number, got {value!r}')
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name}: expected a number, got {value!r}') from None
    if finite and not math.isfinite(x):
        raise ValueError(f'{name}: must be finite, got {x}')
    return x


@overload
def floats(name: str, value: Any, n: Literal[3], *,
           finite: bool = True) -> tuple[float, float, float]: ...
@overload
def floats(name: str, value: Any, n: int | Sequence[int] | None = None, *,
           finite: bool = True) -> tuple[float, ...]: ...


def floats(name: str, value: Any, n: int | Sequence[int] | None = None, *,
           finite: bool = True) -> tuple[float, ...]:
    """``value`` (a sequence of numbers) as a tuple of floats, else ``ValueError`` naming ``name``.

    ``n`` is the required length, or the allowed lengths (``(3, 9)``), or None for any;
    ``finite`` refuses NaN and +/-inf. Booleans are not numbers here.
    """
    lengths = (n,) if isinstance(n, int) else tuple(n) if n is not None else None
    # Fast path for what models and controllers pass every step (float arrays, tuples and
    # lists of floats); anything else, or anything that fails a check, takes the careful path
    # below, which names the fault (a sum of finite values may overflow: it re-checks).
    out: tuple[float, ...] | None = None
    kind = type(value)
    if kind is np.ndarray and value.ndim == 1 and value.dtype.kind == 'f':
        out = tuple(value.tolist())
    elif (kind is tuple or kind is list) and all(type(v) is float for v in value):
        out = tuple(value)
    if (out is not None and (lengths is None or len(out) in lengths)
            and (not finite or math.isfinite(sum(out)))):
        return out
    if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
        raise ValueError(f'{name}: expected a list of numbers, got {value!r}')
    items = list(value)
    if lengths is not None and len(items) not in lengths:
        want = ' or '.join(str(k) for k in lengths)
        raise ValueError(f'{name}: expected {want} values, got {len(items)}')
    return tuple(number(f'{name}[{i}]', item, finite=finite) for i, item in enumerate(items))


def vector(name: str, value: Any, n: int | Sequence[int], *,
           finite: bool = False) -> np.ndarray:
    """``value`` as a 1-D float array of length ``n`` (or one of the lengths ``n``).

    The array twin of ``floats`` for the hot path (a model's or controller's step): one
    ``np.asarray`` and a shape test. ``ValueError`` names ``name``; ``finite`` also refuses
    NaN and +/-inf.
    """
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name}: expected numbers, got {value!r}') from None
    lengths = (n,) if isinstance(n, int) else n
    if a.ndim != 1 or a.shape[0] not in lengths:
        want = ' or '.join(f'({k},)' for k in lengths)
        raise ValueError(f'{name}: expected shape {want}, got {a.shape}')
    if finite and not np.isfinite(a).all():
        raise ValueError(f'{name}: values must be finite, got {a.tolist()}')
    return a
