"""Declared parameters: overrides coerced as YAML users expect, errors that name the parameter."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from rclpy.parameter import Parameter

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec, validate_as_parameters

SPECS = [
    ParamSpec('gain', 1.0, 'A gain', '1/s', 0.0, 10.0),
    ParamSpec('bias', [0.0, 0.0, 0.0], 'A bias', 'm', -5.0, 5.0),
    ParamSpec('count', 3, 'A count', '', 0, 100),
    ParamSpec('fixed', 0.5, 'A read-only number', 's', 0.0, 1.0, read_only=True),
]


@dataclass(frozen=True)
class Settings:
    gain: float
    bias: tuple[float, ...]
    count: int
    fixed: float


def make(context, overrides=None, cli=None) -> tuple[EnbarrNode, list[Settings]]:
    node = EnbarrNode('tuned', context=context, parameter_overrides=overrides or [],
                      cli_args=cli)
    applied: list[Settings] = []
    node.bind_settings(SPECS, lambda v: Settings(v['gain'], tuple(v['bias']), v['count'],
                                                 v['fixed']), applied.append)
    return node, applied


def test_defaults_without_overrides(context):
    node, applied = make(context)
    assert applied == [Settings(1.0, (0.0, 0.0, 0.0), 3, 0.5)]
    node.destroy_node()


def test_integer_override_of_a_float_becomes_a_float(context):
    node, applied = make(context, [Parameter('gain', value=2), Parameter('fixed', value=1)])
    assert applied[-1].gain == 2.0 and isinstance(applied[-1].gain, float)
    assert node.get_parameter('gain').type_ == Parameter.Type.DOUBLE
    assert applied[-1].fixed == 1.0
    node.destroy_node()


def test_integer_list_override_of_a_float_array_becomes_floats(context):
    node, applied = make(context, [Parameter('bias', value=[1, 2, 3])])
    assert applied[-1].bias == (1.0, 2.0, 3.0)
    assert node.get_parameter('bias').type_ == Parameter.Type.DOUBLE_ARRAY
    node.destroy_node()


def test_integer_override_from_the_command_line(context):
    node, applied = make(context, cli=['--ros-args', '-p', 'gain:=4'])
    assert applied[-1].gain == 4.0
    node.destroy_node()


def test_coerced_value_keeps_its_range(context):
    with pytest.raises(ConfigurationError, match=r'parameter gain = 20.0 is outside') as info:
        make(context, [Parameter('gain', value=20)])
    assert info.value.parameter == 'gain'


def test_coerced_value_stays_read_only(context):
    node, _ = make(context, [Parameter('fixed', value=1)])
    result = node.set_parameters([Parameter('fixed', value=0.25)])[0]
    assert not result.successful
    node.destroy_node()


def test_wrong_type_names_parameter_expected_type_and_value(context):
    with pytest.raises(ConfigurationError,
                       match=r"^node 'tuned': parameter 'gain': expected a float, got 'fast'$"):
        make(context, [Parameter('gain', value='fast')])


def test_float_override_of_an_integer_is_refused(context):
    with pytest.raises(ConfigurationError,
                       match=r"parameter 'count': expected an integer, got 2.5"):
        make(context, [Parameter('count', value=2.5)])


def test_wrong_array_type_is_refused(context):
    with pytest.raises(ConfigurationError,
                       match=r"parameter 'bias': expected a list of floats, got \['a', 'b'\]"):
        make(context, [Parameter('bias', value=['a', 'b'])])


def test_a_settings_error_names_its_parameter(context):
    node = EnbarrNode('tuned', context=context)

    def build(v):
        raise ValueError('bias[1]: must be below gain')

    with pytest.raises(ConfigurationError, match=r"^node 'tuned': bias\[1\]: must be") as info:
        node.bind_settings(SPECS, build, lambda s: None)
    assert info.value.parameter == 'bias'
    node.destroy_node()


@pytest.mark.parametrize('override, message', [
    # Before: "parameter 'gain': Invalid parameter value (-0.3) for parameter. Reason:
    # Parameter gain out of range Min: 0.0, Max: 10.0, value: -0.3" (rclpy's words).
    (Parameter('gain', value=-0.3), "node 'tuned': parameter gain = -0.3 is outside [0.0, 10.0]"),
    (Parameter('gain', value=20), "node 'tuned': parameter gain = 20.0 is outside [0.0, 10.0]"),
    (Parameter('count', value=101), "node 'tuned': parameter count = 101 is outside [0, 100]"),
    (Parameter('gain', value=float('nan')), "node 'tuned': parameter gain = nan is not finite"),
])
def test_a_refused_value_is_named_in_our_words(context, override, message):
    with pytest.raises(ConfigurationError) as info:
        make(context, [override])
    assert str(info.value) == message and info.value.parameter == override.name


class Gains:
    """Settings whose own check names a field (as the algorithms' settings do)."""

    def __init__(self, problem: str | None) -> None:
        self.problem = problem

    def validate(self) -> None:
        if self.problem:
            raise ValueError(self.problem)


def test_validate_as_parameters_names_the_parameter_of_the_field():
    parameters = {'Kp': 'kp', 'M': 'vessel.inertia'}
    validate_as_parameters(Gains(None), parameters)  # fine: nothing raised
    with pytest.raises(ValueError, match=r'^kp: Kp: must be non-negative$') as info:
        validate_as_parameters(Gains('Kp: must be non-negative'), parameters)
    assert str(info.value.__cause__) == 'Kp: must be non-negative'
    with pytest.raises(ValueError, match=r'^vessel\.inertia: M: inertia must be > 0$'):
        validate_as_parameters(Gains('M: inertia must be > 0'), parameters)
    # A field that is its own parameter keeps its name.
    with pytest.raises(ValueError, match=r'^tau_max: tau_max: must be > 0$'):
        validate_as_parameters(Gains('tau_max: must be > 0'), parameters)
