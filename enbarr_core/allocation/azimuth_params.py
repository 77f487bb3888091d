"""Azimuth layout and PWM calibration parameters, shared by the allocation, the PWM mapper,
the simulated Arduino and the simulator (like ``thrusters.py`` for fixed thrusters)::

    azimuth_names: [az1, az2, az3]
    azimuths:
      az1: {position: [0.0, 0.1375], max_forward: 1.5, max_reverse: 1.0,
            angle_min: -1.9897, angle_max: 1.9897, time_constant: 0.1, max_angle_rate: 3.0}
    pwm:
      thrust_duty_percent: [4.3, ...]   thrust_newton: [-1.0, ...]
      angle_duty_percent: [4.3, ...]    angle_rad: [-1.9897, ...]

Positions are (x, y) in ``base_link`` [m]; angles [rad] are the direction of positive thrust,
counter-clockwise from surge; the CS Saucer manual's servo travel is +/-114 deg (1.9897 rad).
"""

from __future__ import annotations

import math

from rclpy.node import Node

from enbarr_core.allocation.azimuth import PwmCalibration
from enbarr_core.models.vessel3dof import AzimuthSpec
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.params import ParamSpec, SettingsBinding

SERVO_LIMIT = math.radians(114.0)


def declare_azimuths(node: Node) -> tuple[AzimuthSpec, ...]:
    """Declare ``azimuth_names`` and each azimuth's parameters; return the layout."""
    names = list(SettingsBinding(node, [ParamSpec(
        'azimuth_names', [''], 'Azimuth names, in the order of every per-azimuth array',
        read_only=True, element=str)], lambda v: v['azimuth_names'], lambda _: None).settings)
    if names == [''] or not names:
        raise ConfigurationError(f'node {node.get_name()!r}: parameter azimuth_names is not '
                                 'set; the profile must list the azimuths',
                                 parameter='azimuth_names')
    specs: list[ParamSpec] = []
    for n in names:
        p = f'azimuths.{n}.'
        specs += [
            ParamSpec(p + 'position', [0.0, 0.0], f'(x, y) of azimuth {n} in base_link', 'm',
                      -100.0, 100.0, read_only=True),
            ParamSpec(p + 'max_forward', 1.0, f'Largest forward thrust of {n}', 'N', 1e-6, 1e5,
                      read_only=True),
            ParamSpec(p + 'max_reverse', 1.0, f'Largest reverse thrust magnitude of {n}', 'N',
                      1e-6, 1e5, read_only=True),
            ParamSpec(p + 'angle_min', -SERVO_LIMIT, f'Servo travel limit of {n}', 'rad',
                      -math.pi, math.pi, read_only=True),
            ParamSpec(p + 'angle_max', SERVO_LIMIT, f'Servo travel limit of {n}', 'rad',
                      -math.pi, math.pi, read_only=True),
            ParamSpec(p + 'time_constant', 0.1, f'First-order thrust response of {n}', 's',
                      0.0, 10.0, read_only=True),
            ParamSpec(p + 'max_angle_rate', 3.0, f'Servo slew rate of {n}', 'rad/s', 1e-3,
                      1e3, read_only=True),
        ]

    def build(v: dict) -> tuple[AzimuthSpec, ...]:
        out = []
        for n in names:
            p = f'azimuths.{n}.'
            try:
                out.append(AzimuthSpec(
                    n, tuple(v[p + 'position']), v[p + 'max_forward'], v[p + 'max_reverse'],
                    v[p + 'angle_min'], v[p + 'angle_max'], v[p + 'time_constant'],
                    v[p + 'max_angle_rate']))
            except ConfigurationError as err:
                raise ValueError(str(err)) from err
        return tuple(out)

    return SettingsBinding(node, specs, build, lambda _: None).settings


PWM_SPECS = [
    ParamSpec('pwm.thrust_duty_percent', [4.3, 6.7, 7.0, 9.4],
              'Thrust calibration: duty cycles, increasing', '%', 4.3, 9.4, read_only=True),
    ParamSpec('pwm.thrust_newton', [-1.0, 0.0, 0.0, 1.5],
              'Thrust calibration: thrust at each duty (0 N entries = dead band)', 'N', -1e4,
              1e4, read_only=True),
    ParamSpec('pwm.angle_duty_percent', [4.3, 6.85, 9.4],
              'Servo calibration: duty cycles, increasing', '%', 4.3, 9.4, read_only=True),
    ParamSpec('pwm.angle_rad', [-SERVO_LIMIT, 0.0, SERVO_LIMIT],
              'Servo calibration: angle at each duty', 'rad', -math.pi, math.pi,
              read_only=True),
]


def declare_pwm(node: Node) -> PwmCalibration:
    """Declare the PWM calibration tables (CS Saucer manual: duty 4.3 .. 9.4 %)."""
    def build(v: dict) -> PwmCalibration:
        return PwmCalibration(
            tuple(v['pwm.thrust_duty_percent']), tuple(v['pwm.thrust_newton']),
            tuple(v['pwm.angle_duty_percent']), tuple(v['pwm.angle_rad']))
    return SettingsBinding(node, PWM_SPECS, build, lambda _: None).settings
