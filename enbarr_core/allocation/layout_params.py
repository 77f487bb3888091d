"""Actuator layouts and PWM calibration as parameters, declared one way by every node.

The allocation nodes, the PWM mapper, the simulators and the thruster and Arduino plugins
declare them here. A layout is a list of names, then the same parameters per name. A profile
gives it once in its common ``parameters``::

    thruster_names: [front_right, front_left, ...]
    thrusters:
      front_right: {position: [0.2, -0.15, 0.0], direction: [0.707, 0.707, 0.0],
                    max_forward: 40.0, max_reverse: 30.0}

    azimuth_names: [az1, az2, az3]
    azimuths:
      az1: {position: [0.0, 0.1375], max_forward: 1.5, max_reverse: 1.0, angle_min: -1.99,
            angle_max: 1.99, time_constant: 0.1, max_angle_rate: 3.0}
    pwm:
      duty_min_percent: 4.3             duty_max_percent: 9.4
      thrust_duty_percent: [4.3, ...]   thrust_newton: [-1.0, ...]
      angle_duty_percent: [4.3, ...]    angle_rad: [-1.99, ...]

Every number is vessel data, so none has a default: a missing one is a
``ConfigurationError`` naming the parameter. Thruster positions are in ``base_link`` (FLU)
[m], a direction is the thrust direction of a positive command (normalized on use), limits
are the thrust [N] at command +1 and -1. Azimuth positions are (x, y) in ``base_link`` [m];
angles [rad] are the direction of positive thrust, counter-clockwise from surge. Layouts and
calibration are read only: geometry is fixed while the vehicle runs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any, Generic, TypeVar

from rclpy.node import Node

from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.allocation.fixed import Thruster
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.params import ParamSpec, SettingsBinding
from enbarr_core.models.vessel3dof import AzimuthSpec

T = TypeVar('T')


@dataclass(frozen=True)
class Layout(Generic[T]):
    """A named layout: a list of names, then the same parameters per name.

    ``names_param`` lists the members, in the order of every per-member array; member ``n``
    has the parameters ``<section>.<n>.<key>`` of ``fields``, all required;
    ``build(name, {key: value})`` makes one member (raising ``ValueError`` or
    ``ConfigurationError`` when it does not make sense).

    A node that needs only the layout calls ``declare``; a node whose settings hold the
    layout beside other values declares ``names`` first, then adds ``specs(node, names)`` to
    its own specs and calls ``from_params(names, values)`` in its settings' ``from_params``.
    """

    names_param: str
    section: str
    kind: str
    fields: tuple[ParamSpec, ...]  # per-member templates: name = the key
    build: Callable[[str, Mapping[str, Any]], T]

    def names(self, node: Node) -> tuple[str, ...]:
        """Declare ``names_param`` and return the names (ConfigurationError when unset)."""
        names = list(SettingsBinding(node, [ParamSpec(
            self.names_param, [''], f'{self.kind.capitalize()} names, in the order of every '
            f'per-{self.kind} array', read_only=True, element=str)],
            lambda v: v[self.names_param], lambda _: None).settings)
        if names == [''] or not names:
            raise ConfigurationError(
                f'node {node.get_name()!r}: parameter {self.names_param} is not set; the '
                f'profile must list the {self.kind}s', parameter=self.names_param)
        if len(set(names)) != len(names):
            raise ConfigurationError(f'node {node.get_name()!r}: {self.names_param} has '
                                     f'duplicates: {names}', parameter=self.names_param)
        return tuple(names)

    def specs(self, node: Node, names: Sequence[str]) -> list[ParamSpec]:
        """Return the per-member parameters of ``names`` (required: vessel data)."""
        specs = [replace(f, name=f'{self.section}.{n}.{f.name}',
                         description=f'{f.description} of {self.kind} {n}')
                 for n in names for f in self.fields]
        return specs

    def from_params(self, names: Sequence[str], v: Mapping[str, Any]) -> tuple[T, ...]:
        """Build the members of ``names`` from the parameter values ``v`` (ValueError)."""
        out = []
        for n in names:
            try:
                out.append(self.build(n, {f.name: v[f'{self.section}.{n}.{f.name}']
                                          for f in self.fields}))
            except ConfigurationError as err:  # the member names itself
                raise ValueError(str(err)) from err
        return tuple(out)

    def declare(self, node: Node) -> tuple[T, ...]:
        """Declare the names and every member's parameters; return the layout."""
        names = self.names(node)
        return SettingsBinding(node, self.specs(node, names),
                               lambda v: self.from_params(names, v), lambda _: None).settings


def _field(key: str, default: Any, description: str, units: str, low: float,
           high: float) -> ParamSpec:
    """Make a per-member parameter template: vessel data, so required and read only."""
    return ParamSpec(key, default, description, units, low, high, read_only=True,
                     required=True)


THRUSTER_FIELDS = (
    _field('position', [0.0, 0.0, 0.0], 'Position in base_link', 'm', -100.0, 100.0),
    _field('direction', [0.0, 0.0, 0.0], 'Thrust direction for a positive command '
          '(base_link; normalized on use)', '', -1e3, 1e3),
    _field('max_forward', 0.0, 'Thrust at command +1', 'N', 1e-6, 1e6),
    _field('max_reverse', 0.0, 'Thrust magnitude at command -1', 'N', 1e-6, 1e6),
)


THRUSTERS: Layout[Thruster] = Layout(
    'thruster_names', 'thrusters', 'thruster', THRUSTER_FIELDS,
    lambda n, v: Thruster(n, tuple(v['position']), tuple(v['direction']), v['max_forward'],
                          v['max_reverse']))
"""Fixed thrusters (``fixed.Thruster``)."""


def declare_thrusters(node: Node) -> tuple[Thruster, ...]:
    """Declare ``thruster_names`` and each thruster's parameters; return the layout."""
    return THRUSTERS.declare(node)


AZIMUTH_FIELDS = (
    _field('position', [0.0, 0.0], '(x, y) in base_link', 'm', -100.0, 100.0),
    _field('max_forward', 0.0, 'Largest forward thrust', 'N', 1e-6, 1e5),
    _field('max_reverse', 0.0, 'Largest reverse thrust magnitude', 'N', 1e-6, 1e5),
    _field('angle_min', 0.0, 'Servo travel limit (lower)', 'rad', -math.pi, math.pi),
    _field('angle_max', 0.0, 'Servo travel limit (upper)', 'rad', -math.pi, math.pi),
    _field('time_constant', 0.0, 'First-order thrust response', 's', 0.0, 10.0),
    _field('max_angle_rate', 0.0, 'Servo slew rate', 'rad/s', 1e-3, 1e3),
)


AZIMUTHS: Layout[AzimuthSpec] = Layout(
    'azimuth_names', 'azimuths', 'azimuth', AZIMUTH_FIELDS,
    lambda n, v: AzimuthSpec(n, tuple(v['position']), v['max_forward'], v['max_reverse'],
                             v['angle_min'], v['angle_max'], v['time_constant'],
                             v['max_angle_rate']))
"""Azimuth thrusters (``models.vessel3dof.AzimuthSpec``)."""


def declare_azimuths(node: Node) -> tuple[AzimuthSpec, ...]:
    """Declare ``azimuth_names`` and each azimuth's parameters; return the layout."""
    return AZIMUTHS.declare(node)


PWM_SPECS = [
    ParamSpec('pwm.duty_min_percent', 0.0, 'Lowest duty cycle the PWM board accepts', '%',
              0.0, 100.0, read_only=True, required=True),
    ParamSpec('pwm.duty_max_percent', 0.0, 'Highest duty cycle the PWM board accepts', '%',
              0.0, 100.0, read_only=True, required=True),
    ParamSpec('pwm.thrust_duty_percent', [0.0], 'Thrust calibration: duty cycles, increasing',
              '%', 0.0, 100.0, read_only=True, required=True),
    ParamSpec('pwm.thrust_newton', [0.0],
              'Thrust calibration: thrust at each duty (0 N entries = dead band)', 'N', -1e4,
              1e4, read_only=True, required=True),
    ParamSpec('pwm.angle_duty_percent', [0.0], 'Servo calibration: duty cycles, increasing',
              '%', 0.0, 100.0, read_only=True, required=True),
    ParamSpec('pwm.angle_rad', [0.0], 'Servo calibration: angle at each duty', 'rad',
              -math.pi, math.pi, read_only=True, required=True),
]


def pwm_specs(node: Node) -> list[ParamSpec]:
    """``PWM_SPECS`` (required: vessel data has no default)."""
    return list(PWM_SPECS)


def pwm_from_params(v: Mapping[str, Any]) -> PwmCalibration:
    """Build the calibration from the values of ``PWM_SPECS`` (ValueError naming a field)."""
    return PwmCalibration.from_mapping(
        {s.name.removeprefix('pwm.'): v[s.name] for s in PWM_SPECS})


def declare_pwm(node: Node) -> PwmCalibration:
    """Declare the PWM duty limits and calibration tables (all required); return them."""
    return SettingsBinding(node, pwm_specs(node), pwm_from_params, lambda _: None).settings


@dataclass(frozen=True)
class PwmLayout:
    """The azimuths and the PWM calibration of their drives: what every PWM node reads.

    The PWM mapper, the simulated Arduino, its driver and its emulator all declare the same
    read-only parameters (``azimuth_names``, ``azimuths.*``, ``pwm.*``) and agree on the
    channel order of ``pwm/duty_cycle``: ``<azimuth>/motor, <azimuth>/servo`` per azimuth.
    """

    azimuths: tuple[AzimuthSpec, ...]
    calibration: PwmCalibration

    @classmethod
    def from_params(cls, names: Sequence[str], v: Mapping[str, Any]) -> PwmLayout:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        return cls(AZIMUTHS.from_params(names, v), pwm_from_params(v))

    @property
    def channels(self) -> list[str]:
        """Channel names in the order of the duties: ``<azimuth>/motor, <azimuth>/servo``."""
        return [f'{a.name}/{k}' for a in self.azimuths for k in ('motor', 'servo')]


def pwm_layout_specs(node: Node, names: Sequence[str]) -> list[ParamSpec]:
    """Return the parameters of a ``PwmLayout`` with azimuths ``names`` (all read only)."""
    return AZIMUTHS.specs(node, names) + pwm_specs(node)


def declare_pwm_layout(node: Node) -> PwmLayout:
    """Declare ``azimuth_names``, each azimuth's parameters and the PWM tables; return them."""
    names = AZIMUTHS.names(node)
    return SettingsBinding(node, pwm_layout_specs(node, names),
                           lambda v: PwmLayout.from_params(names, v), lambda _: None).settings
