"""Declared, validated, live-tunable parameters (what replaces the seeds' gain server).

A node lists its parameters as ``ParamSpec``s and gives a ``build`` function that turns the
values into an immutable settings object (raising ``ValueError`` with a reason when they do
not fit together). ``declare_settings`` declares them with a ``ParameterDescriptor``
(description, units, range), refuses any ``set_parameters`` (what ``ros2 param set`` calls)
whose result ``build`` rejects, with the reason and the old value kept, and otherwise swaps
the new settings object into the node with ``apply`` after the set succeeded.

The one pattern every node follows::

    SPECS = [ParamSpec('time_constant', 0.05, 'Motor lag', 's', 0.0, 5.0), ...]

    @dataclass(frozen=True)
    class SimThrustersSettings:
        time_constant: float  # [s]

        @classmethod
        def from_params(cls, v: Mapping[str, Any]) -> SimThrustersSettings:
            return cls(time_constant=v['time_constant'])   # ValueError with a reason

    # in the node's __init__:
    self.bind_settings(SPECS, SimThrustersSettings.from_params, self._apply)

and the node reads typed attributes (``self.settings.time_constant``), never string keys.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
import re
from typing import Any, Generic, Protocol, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult)
from rclpy.exceptions import (
    InvalidParameterTypeException, InvalidParameterValueException,
    ParameterUninitializedException)
from rclpy.node import Node
from rclpy.parameter import Parameter

from enbarr_core.framework.errors import ConfigurationError

S = TypeVar('S')

_TYPES: dict[type, int] = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}
_ARRAY_TYPES: dict[type, int] = {
    bool: ParameterType.PARAMETER_BOOL_ARRAY,
    int: ParameterType.PARAMETER_INTEGER_ARRAY,
    float: ParameterType.PARAMETER_DOUBLE_ARRAY,
    str: ParameterType.PARAMETER_STRING_ARRAY,
}


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter.

    ``default`` fixes the type: a float (``0.0``, never ``0``) for gains, a list for arrays
    (``element`` then names the element type, needed when the default list is empty).
    ``low``/``high`` bound a number or every element of a number array. A ``required``
    parameter (vessel data: geometry, calibration) takes no value from ``default``, which then
    only gives the type: a node started without it is refused, naming it.
    """

    name: str
    default: Any
    description: str
    units: str = ''
    low: float | None = None
    high: float | None = None
    read_only: bool = False
    element: type | None = None
    required: bool = False

    @property
    def is_array(self) -> bool:
        """Whether the parameter is a list."""
        return isinstance(self.default, (list, tuple))

    @property
    def ros_type(self) -> int:
        """Return the ``ParameterType`` the default fixes."""
        if self.is_array:
            element = self.element or type(self.default[0])
            return _ARRAY_TYPES[element]
        return _TYPES[type(self.default)]

    def descriptor(self) -> ParameterDescriptor:
        """Return the descriptor: description with units, type, range, read-only."""
        text = self.description + (f' [{self.units}]' if self.units else '')
        if self.is_array and (self.low is not None or self.high is not None):
            text += f' (each element in [{self.low}, {self.high}])'
        d = ParameterDescriptor(description=text, type=self.ros_type, read_only=self.read_only)
        # rclpy enforces these ranges itself for scalars; arrays are checked in check().
        if not self.is_array and isinstance(self.default, float) and self._bounded:
            d.floating_point_range = [FloatingPointRange(
                from_value=self._low, to_value=self._high, step=0.0)]
        elif (not self.is_array and isinstance(self.default, int)
              and not isinstance(self.default, bool) and self._bounded):
            d.integer_range = [IntegerRange(
                from_value=int(self._low), to_value=int(self._high), step=1)]
        return d

    @property
    def _bounded(self) -> bool:
        return self.low is not None or self.high is not None

    @property
    def _low(self) -> float:
        return float(self.low) if self.low is not None else -1.7976931348623157e308

    @property
    def _high(self) -> float:
        return float(self.high) if self.high is not None else 1.7976931348623157e308

    def check(self, value: Any) -> str | None:
        """Why ``value`` is out of range or not finite, or ``None`` when it is fine."""
        values = list(value) if self.is_array else [value]
        for i, v in enumerate(values):
            if isinstance(v, float) and not math.isfinite(v):
                where = f'{self.name}[{i}]' if self.is_array else self.name
                return f'{where} = {v} is not finite'
            if isinstance(v, (int, float)) and not isinstance(v, bool) and self._bounded:
                if not self._low <= v <= self._high:
                    where = f'{self.name}[{i}]' if self.is_array else self.name
                    return f'{where} = {v} is outside [{self.low}, {self.high}]'
        return None


class SettingsBinding(Generic[S]):
    """The parameters of one node bound to its immutable settings object."""

    def __init__(self, node: Node, specs: Sequence[ParamSpec],
                 build: Callable[[dict[str, Any]], S], apply: Callable[[S], None]) -> None:
        self.node = node
        self.specs = {s.name: s for s in specs}
        self._build = build
        self._apply = apply
        self._pending: S | None = None
        for spec in specs:
            _declare(node, spec)
        values = self.values()
        for spec in specs:
            reason = spec.check(values[spec.name])
            if reason:
                raise ConfigurationError(f'node {node.get_name()!r}: parameter {reason}',
                                         parameter=spec.name)
        try:
            self.settings: S = build(values)
        except ValueError as err:
            raise ConfigurationError(f'node {node.get_name()!r}: {err}',
                                     parameter=_named(str(err), self.specs)) from err
        apply(self.settings)
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)

    def values(self) -> dict[str, Any]:
        """Return the current values of the bound parameters (arrays as lists)."""
        return {name: _plain(self.node.get_parameter(name).value) for name in self.specs}

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        ours = [p for p in params if p.name in self.specs]
        if not ours:
            return SetParametersResult(successful=True)
        values = self.values()
        for p in ours:
            value = _plain(p.value)
            reason = self.specs[p.name].check(value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            values[p.name] = value
        try:
            self._pending = self._build(values)
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _post_set(self, params: list[Parameter]) -> None:
        if self._pending is not None and any(p.name in self.specs for p in params):
            self.settings, self._pending = self._pending, None
            self._apply(self.settings)


class Validated(Protocol):
    """Settings that check themselves: ``validate`` raises a ValueError starting 'field: '."""

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the settings do not hold together."""


def validate_as_parameters(settings: Validated, parameters: Mapping[str, str]) -> None:
    """``settings.validate()``, its ``ValueError`` naming the parameter of the field it is about.

    ``parameters`` maps a field to its parameter (``{'Kp': 'kp', 'M': 'vessel.inertia'}``); a
    field it does not list is named as it is.
    """
    try:
        settings.validate()
    except ValueError as err:
        field = str(err).split(':')[0]
        raise ValueError(f'{parameters.get(field, field)}: {err}') from err


def refuse_live_value(name: str, problem: Callable[[float], str | None]
                      ) -> Callable[[list[Parameter]], SetParametersResult]:
    """Return an on-set-parameters callback that refuses a float ``name`` with a reason.

    ``problem(value)`` gives the reason, or None for a value that fits: a check against what
    the node measures at run time, beside what ``build`` checks.
    """
    def check(params: list[Parameter]) -> SetParametersResult:
        for p in params:
            if p.name == name and isinstance(p.value, float):
                reason = problem(p.value)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)
    return check


def _plain(value: Any) -> Any:
    """Rclpy hands arrays back as ``array.array``; make them lists."""
    if value is not None and not isinstance(value, (bool, int, float, str, list)):
        return list(value)
    return value


def _named(message: str, specs: Mapping[str, ParamSpec]) -> str | None:
    """Return the parameter a settings error names first (``'kp[5]: ...'`` -> ``'kp'``)."""
    head = re.split(r'[\[:\s]', message, maxsplit=1)[0]
    return head if head in specs else None


#: How a refusal names a type: 'expected an integer, got 2.5'.
_TYPE_NAMES = {bool: ('a boolean', 'booleans'), int: ('an integer', 'integers'),
               float: ('a float', 'floats'), str: ('a string', 'strings')}


def _type_text(spec: ParamSpec) -> str:
    if spec.is_array:
        return f'a list of {_TYPE_NAMES[spec.element or type(spec.default[0])][1]}'
    return _TYPE_NAMES[type(spec.default)][0]


def _declare(node: Node, spec: ParamSpec) -> None:
    """Declare ``spec`` on ``node``, taking the override the node was given, if any.

    A profile may write ``kp: 2`` for a float gain, as YAML users expect: when the declaration
    refuses an INTEGER (array) override of a DOUBLE (array) parameter, the override is read
    through a dynamically typed declaration (public calls only: ``declare_parameter``,
    ``get_parameter``, ``undeclare_parameter``), turned into a DOUBLE and declared again with
    ``ignore_override``. Any other type is refused with a ``ConfigurationError`` naming the
    parameter, the expected type and the value given.
    """
    where = f'node {node.get_name()!r}: parameter {spec.name!r}'
    # A required parameter is declared statically typed with no value: it has one only when
    # the node was given an override (a profile value).
    value = Parameter.Type(spec.ros_type) if spec.required else spec.default
    try:
        try:
            node.declare_parameter(spec.name, value, spec.descriptor())
            if spec.required:
                try:
                    node.get_parameter(spec.name)
                except ParameterUninitializedException:
                    raise ConfigurationError(f'{where} is not set; the profile must give it '
                                             '(it has no default)', parameter=spec.name)
            return
        except InvalidParameterTypeException as err:
            given = _given_value(node, spec)
            coerced = _coerce(spec, given)
            if coerced is None:
                raise ConfigurationError(f'{where}: expected {_type_text(spec)}, got {given!r}',
                                         parameter=spec.name) from err
        node.declare_parameter(spec.name, coerced, spec.descriptor(), ignore_override=True)
    except ConfigurationError:
        raise
    except InvalidParameterValueException as err:
        # rclpy refused the value against the descriptor's range, in its own words ('Invalid
        # parameter value (-0.3) for parameter. Reason: ...'): say it as every refusal here
        # says it, naming the node, the parameter, the value and the range.
        given = _given_value(node, spec)
        value = _coerce(spec, given)
        value = given if value is None else value
        reason = spec.check(value) or f'{spec.name} = {value!r} is refused'
        raise ConfigurationError(f'node {node.get_name()!r}: parameter {reason}',
                                 parameter=spec.name) from err
    except Exception as err:  # any other refusal of rclpy's: its reason is all there is
        raise ConfigurationError(f'{where}: {err}', parameter=spec.name) from err


def _given_value(node: Node, spec: ParamSpec) -> Any:
    """Return the override of ``spec.name`` as given, whatever its type.

    The parameter is left undeclared.
    """
    node.declare_parameter(spec.name, spec.default, ParameterDescriptor(dynamic_typing=True))
    try:
        return _plain(node.get_parameter(spec.name).value)
    finally:
        node.undeclare_parameter(spec.name)


def _coerce(spec: ParamSpec, value: Any) -> Any:
    """``value`` as the float (list) ``spec`` wants when it is an int (list), else None."""
    if spec.ros_type == ParameterType.PARAMETER_DOUBLE:
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
    elif spec.ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, list):
        if value and all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            return [float(v) for v in value]
    return None
