"""Conversions between messages and numbers (``enbarr_interfaces/convert.py``).

``all_finite`` is every node's per-sample input check: its fast path (floats one by one)
must refuse exactly what ``np.isfinite`` refuses, for every shape and kind it is given.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_interfaces import convert

BAD = (math.nan, math.inf, -math.inf)


@pytest.mark.parametrize('size', [1, 3, 6, 16, 17, 40])
def test_all_finite_refuses_each_non_finite_value_anywhere(size: int) -> None:
    rng = np.random.default_rng(size)
    good = rng.normal(0.0, 1e300, size)  # huge but finite: a sum of them would overflow
    assert convert.all_finite(good) and convert.all_finite(good.tolist())
    assert convert.all_finite(tuple(good), good.reshape(1, -1), good[::-1])
    for i in range(size):
        for bad in BAD:
            a = good.copy()
            a[i] = bad
            assert not convert.all_finite(a), (i, bad)
            assert not convert.all_finite(a.tolist())
            assert not convert.all_finite(good, a)     # a later array
            assert not convert.all_finite(a.reshape(1, -1))


def test_all_finite_takes_numbers_and_agrees_with_numpy() -> None:
    assert convert.all_finite(1.0, 2, np.float64(3.0), np.zeros((3, 3)), [], ())
    for bad in BAD:
        assert not convert.all_finite(bad)
        assert not convert.all_finite(1.0, bad)
        assert not convert.all_finite(np.float64(bad))
    rng = np.random.default_rng(3)
    for _ in range(500):
        a = rng.choice([0.0, 1.0, -2.5, 1e308, *BAD], size=rng.integers(0, 8))
        assert convert.all_finite(a) == bool(np.isfinite(a).all())
