"""The shared coercions of settings and step inputs: errors name the field."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.framework.checks import floats, vector


def test_floats_coerces_integers():
    assert floats('gyro_bias', [0, 1, 2.5], 3) == (0.0, 1.0, 2.5)


@pytest.mark.parametrize('value, n, match', [
    ([1.0, 2.0], 3, r'^gyro_bias: expected 3 values, got 2$'),
    ([1.0, 'a', 2.0], 3, r'^gyro_bias\[1\]: expected a number'),
    ([1.0, True, 2.0], 3, r'^gyro_bias\[1\]: expected a number'),
    ([1.0, math.nan, 2.0], 3, r'^gyro_bias\[1\]: must be finite'),
    (1.0, 3, r'^gyro_bias: expected a list of numbers'),
    ('abc', 3, r'^gyro_bias: expected a list of numbers'),
    ([1.0] * 4, (3, 9), r'^gyro_bias: expected 3 or 9 values, got 4$'),
])
def test_floats_errors_name_the_field(value, n, match):
    with pytest.raises(ValueError, match=match):
        floats('gyro_bias', value, n)


def test_floats_may_allow_infinity_and_any_length():
    assert floats('tau_max', [math.inf], finite=False) == (math.inf,)


def test_vector_is_an_array_of_the_length():
    v = vector('nu', [1, 2, 3, 4, 5, 6], 6)
    assert isinstance(v, np.ndarray) and v.dtype == float and v.tolist() == [1, 2, 3, 4, 5, 6]
    assert vector('inertia', [1.0] * 9, (3, 9)).shape == (9,)


@pytest.mark.parametrize('value, match', [
    (np.zeros(5), r'^nu: expected shape \(6,\), got \(5,\)$'),
    (np.zeros((2, 3)), r'^nu: expected shape'),
    (['x'] * 6, r'^nu: expected numbers'),
    ([math.nan] * 6, r'^nu: values must be finite'),
])
def test_vector_errors_name_the_field(value, match):
    with pytest.raises(ValueError, match=match):
        vector('nu', value, 6, finite=True)


def test_vector_lets_nan_through_unless_asked():
    assert math.isnan(vector('nu', [math.nan] * 6, 6)[0])
