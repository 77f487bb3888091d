"""Fixtures of the ROV node tests: the simulated profile's parameters and messages."""

from __future__ import annotations

import os
from typing import Any

import yaml
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterValue
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu

from enbarr_core.allocation.fixed import Thruster
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.nodes import probe

SIM_PROFILE = os.path.join(os.path.dirname(__file__), '..', '..', 'params', 'enbarr_sim.yaml')


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f'{prefix}.{k}' if prefix else str(k), v, out)
    else:
        out[prefix] = value


def sim_parameters(node: str | None = None) -> dict[str, Any]:
    """The common parameters of ``params/enbarr_sim.yaml`` (plus those of ``node``), with
    nested keys flattened to ROS names (``thrusters.front_right.position``).
    """
    with open(SIM_PROFILE, encoding='utf-8') as f:
        profile = yaml.safe_load(f)
    out: dict[str, Any] = {}
    _flatten('', profile['parameters'], out)
    if node is not None:
        _flatten('', profile['nodes'][node].get('parameters', {}), out)
    return out


def vehicle_parameters() -> dict[str, Any]:
    """What the velocity loop needs from ``params/enbarr_sim.yaml`` (it has no defaults): the
    vehicle model (``vehicle.*``) and its own tuning (the ``control_loop`` node's gains,
    limits and reference model)."""
    control = sim_parameters('control_loop')
    own = {k: v for k, v in control.items() if k not in sim_parameters()}
    return {**{k: v for k, v in control.items() if k.startswith('vehicle.')}, **own}


def overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


def layout_overrides(**extra: Any) -> list[Parameter]:
    """The sim thruster layout (and vehicle) as parameter overrides, plus ``extra``."""
    return overrides({**sim_parameters(), **extra})


def sim_thrusters() -> list[Thruster]:
    p = sim_parameters()
    return [Thruster(n, p[f'thrusters.{n}.position'], p[f'thrusters.{n}.direction'],
                     p[f'thrusters.{n}.max_forward'], p[f'thrusters.{n}.max_reverse'])
            for n in p['thruster_names']]


def stamp_ns(node: Any) -> int:
    return node.get_clock().now().nanoseconds


def twist(node: Any, nu: list[float], offset_s: float = 0.0) -> TwistStamped:
    msg = TwistStamped()
    convert.ns_to_stamp(stamp_ns(node) + int(offset_s * 1e9), msg.header.stamp)
    msg.header.frame_id = topics.BODY_FRAME
    convert.set_twist(msg.twist, nu)
    return msg


def io_msg(name: str, value: Any) -> ParameterMsg:
    if isinstance(value, ParameterValue):
        return ParameterMsg(name=name, value=value)
    return ParameterMsg(name=name, value=convert.python_to_parameter_value(value))


def imu_sample(t_ns: int, rate_z: float) -> Imu:
    """A level ``imu/data`` sample stamped ``t_ns`` turning at ``rate_z`` [rad/s]."""
    msg = Imu()
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    msg.header.frame_id = topics.IMU_FRAME
    msg.orientation.w = 1.0
    msg.angular_velocity.z = rate_z
    return msg


def io_probe(context: Any, executor: Any) -> tuple[Any, list[tuple[str, Any]]]:
    """A surface probe: an ``io_request`` publisher and the (executor, value) states seen."""
    p = probe(context, executor, 'surface')
    pub = p.create_topic_publisher(topics.IO_REQUEST)
    states: list[tuple[str, Any]] = []
    p.create_topic_subscription(
        topics.IO_STATE,
        lambda m: states.append((m.name, convert.parameter_value_to_python(m.value))))
    LinkBus.of(context).connect()
    return pub, states


G = 9.81  # [m/s^2] what the simulated IMU reads at rest
