"""How the station lists a parameter and types an edited value (pure: no node, no context)."""

from __future__ import annotations

import pytest
from rcl_interfaces.msg import ParameterType

from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.station.node import describe, typed_value

pytestmark = pytest.mark.unit


def listed(spec: ParamSpec) -> dict[str, object]:
    return describe(spec.name, spec.default, spec.descriptor())


def test_a_scalar_gain_with_units_and_range():
    got = listed(ParamSpec('gain_ramp_time', 1.0, 'Time a gain change takes', 's', 0.0, 60.0))
    assert (got['unit'], got['low'], got['high'], got['type']) == ('s', 0.0, 60.0, 'double')
    assert got['description'] == 'Time a gain change takes [s]' and got['read_only'] is False


def test_an_array_gain_has_its_element_range_and_units():
    got = listed(ParamSpec('kp', [1.0, 2.0, 3.0], 'Proportional gains (surge, sway, yaw)',
                           'N/m, N m/rad', 0.0, 1e4))
    assert (got['unit'], got['low'], got['high'], got['type']) == (
        'N/m, N m/rad', 0.0, 1e4, 'double[]')
    assert got['value'] == [1.0, 2.0, 3.0]


def test_an_array_without_units_takes_no_range_for_a_unit():
    got = listed(ParamSpec('force_max', [2.0, 2.0], 'Force box', '', 1e-3, None))
    assert (got['unit'], got['low'], got['high']) == ('', 1e-3, None)


def test_an_unbounded_string_is_read_only_when_declared_so():
    got = listed(ParamSpec('layout', 'enbarr_ds4', 'Joystick layout', read_only=True))
    assert (got['unit'], got['low'], got['high'], got['read_only']) == ('', None, None, True)


def test_an_integer_range():
    got = listed(ParamSpec('port', 8080, 'TCP port', '', 0, 65535))
    assert (got['low'], got['high'], got['type']) == (0, 65535, 'int')


@pytest.mark.parametrize('kind, value, expected', [
    (ParameterType.PARAMETER_DOUBLE, 2, 2.0),
    (ParameterType.PARAMETER_INTEGER, 3.0, 3),
    (ParameterType.PARAMETER_BOOL, False, False),
    (ParameterType.PARAMETER_STRING, 'x', 'x'),
    (ParameterType.PARAMETER_DOUBLE_ARRAY, [1, 2.5], [1.0, 2.5]),
])
def test_an_edited_value_takes_the_parameter_type(kind, value, expected):
    got = typed_value(kind, value)
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize('kind, value', [
    (ParameterType.PARAMETER_DOUBLE, 'fast'), (ParameterType.PARAMETER_DOUBLE, True),
    (ParameterType.PARAMETER_INTEGER, 2.5), (ParameterType.PARAMETER_BOOL, 1),
    (ParameterType.PARAMETER_DOUBLE_ARRAY, 1.0), (ParameterType.PARAMETER_DOUBLE_ARRAY, [1, 'a']),
])
def test_a_value_of_another_type_is_refused(kind, value):
    with pytest.raises(ValueError, match='is not a'):
        typed_value(kind, value)
