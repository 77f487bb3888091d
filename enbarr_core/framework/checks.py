"""Shared validation of settings dataclasses: every error names the field (``ValueError``)."""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any

import numpy as np


def check_gain_vectors(settings: Any, names: Sequence[str], size: int, labels: str, *,
                       may_be_infinite: Sequence[str] = (),
                       positive: Sequence[str] = ()) -> None:
    """Each named field is ``size`` non-negative numbers (``labels`` names the entries in the
    message), finite unless in ``may_be_infinite`` (+inf: no limit), never NaN, and > 0 when
    in ``positive``."""
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
