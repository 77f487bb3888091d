"""filterpy's ``KalmanFilter`` without SciPy's statistics at import time.

``filterpy.kalman`` imports ``filterpy.stats`` for one function, ``logpdf`` (behind the
filters' ``log_likelihood`` and ``likelihood`` properties), and ``filterpy.stats`` imports
``scipy.stats`` at module level. That import costs a vessel process a large share of its
resident memory and of its start-up time (``docs/benchmarks.md``), for a likelihood the
attitude filter never asks for.

``import_kalman()`` imports the real ``filterpy.kalman`` while ``sys.modules`` holds a
stand-in for ``filterpy.stats`` whose ``logpdf`` imports the real module on its first call and
hands over to it. The stand-in leaves ``sys.modules`` as soon as the import is done, so every
later ``import filterpy.stats`` (ours or a user's) gets filterpy's own module. When
``filterpy.kalman`` is already imported (importing ``filterpy.stats`` imports it too), nothing
is stood in.
"""

from __future__ import annotations

import sys
import types
from typing import TYPE_CHECKING, Any

_STATS = 'filterpy.stats'


def _logpdf(*args: Any, **kwargs: Any) -> Any:
    """filterpy.stats.logpdf, imported (with SciPy's statistics) on first use."""
    from filterpy.stats import logpdf
    return logpdf(*args, **kwargs)


def import_kalman() -> types.ModuleType:
    """Return ``filterpy.kalman``, imported without importing ``scipy.stats``."""
    if 'filterpy.kalman' in sys.modules:
        import filterpy.kalman
        return filterpy.kalman
    stand_in = types.ModuleType(_STATS, 'Stand-in: logpdf imports filterpy.stats on first use.')
    stand_in.logpdf = _logpdf  # type: ignore[attr-defined]  # set, not declared
    sys.modules[_STATS] = stand_in
    try:
        import filterpy.kalman
    finally:
        if sys.modules.get(_STATS) is stand_in:
            del sys.modules[_STATS]
    return filterpy.kalman


if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter as KalmanFilter
else:
    KalmanFilter = import_kalman().KalmanFilter
