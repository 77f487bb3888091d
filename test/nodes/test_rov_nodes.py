"""Node tier: each node in a private rclpy context, driven through its topics and parameter
services as the rest of the graph (or ``ros2 param set``) would drive it.

Fast topics are fed and observed through the in-process ``LinkBus`` (synchronous calls), the
surface topics through ordinary ROS publishers. Nothing here waits a fixed time: every wait
spins until a condition holds, with a generous timeout.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

from geometry_msgs.msg import TwistStamped, WrenchStamped
import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import Imu, JointState, MagneticField
import yaml

from enbarr_core.allocation.fixed import allocation_matrix, Thruster
from enbarr_core.control.command_gate import Verdict
from enbarr_core.framework.kinematics import quat_to_euler
from enbarr_core.framework.errors import AllocationError, ConfigurationError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.estimation.attitude_filter_node import AttitudeFilterNode
from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_core.simulation.rov_simulator_node import RovSimulatorNode
from enbarr_core.allocation.thruster_converter_node import ThrusterConverterNode
from enbarr_core.control.velocity_control_node import VelocityControlNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.io.sim_gpio import SimGpioNode
from enbarr_plugins.io.sim_stepper import SimStepperNode
from enbarr_plugins.thrusters.sim import SimThrustersNode
from enbarr_plugins.imu.sim import SimImuNode

TIMEOUT = 10.0  # [s] every spin-until; never a bound on how fast anything must be
SIM_PROFILE = os.path.join(os.path.dirname(__file__), '..', '..', 'params', 'enbarr_sim.yaml')


# --- helpers ------------------------------------------------------------------------------


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f'{prefix}.{k}' if prefix else str(k), v, out)
    else:
        out[prefix] = value


def sim_parameters(node: str | None = None) -> dict[str, Any]:
    """The common parameters of ``params/enbarr_sim.yaml`` (plus those of ``node``), with
    nested keys flattened to ROS names (``thrusters.front_right.position``)."""
    with open(SIM_PROFILE, encoding='utf-8') as f:
        profile = yaml.safe_load(f)
    out: dict[str, Any] = {}
    _flatten('', profile['parameters'], out)
    if node is not None:
        _flatten('', profile['nodes'][node].get('parameters', {}), out)
    return out


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


def add(executor: Any, node: Any) -> Any:
    """Hand ``node`` to the executor (which destroys it at teardown) and return it."""
    executor.add_node(node)
    return node


def probe(context: Any, executor: Any, name: str = 'probe') -> EnbarrNode:
    """A helper node in the test's context, to publish and listen as other nodes would."""
    return add(executor, EnbarrNode(name, context=context))


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


def call(executor: Any, future: Any) -> Any:
    """Wait for a service future while the one executor serves both sides."""
    executor.spin_until_future_complete(future, timeout_sec=TIMEOUT)
    assert future.done(), 'no answer from the parameter service'
    return future.result()


# --- 1. command receiver ------------------------------------------------------------------


def test_command_receiver_gates_commands_failsafe_and_io(context, executor, spin):
    node = add(executor, CommandReceiverNode(
        node_name='command_receiver', context=context, parameter_overrides=[
            Parameter('timeout', value=0.2), Parameter('max_age', value=5.0),
            Parameter('max_linear', value=1.0)]))
    surface = probe(context, executor, 'surface')
    twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                         topics.SURFACE_TWIST.qos)
    io_pub = surface.create_publisher(ParameterMsg, topics.SURFACE_IO.name,
                                      topics.SURFACE_IO.qos)
    goals: list[np.ndarray] = []
    ios: list[ParameterMsg] = []
    surface.create_topic_subscription(
        topics.TRAJECTORY_REQUEST, lambda m: goals.append(convert.twist_to_nu(m.twist)))
    surface.create_topic_subscription(topics.IO_REQUEST, ios.append)
    LinkBus.of(context).connect()
    # The receiver's goal publisher is in this process: the probe is fed by direct calls.
    assert all(s.local for s in surface._links)
    assert spin(executor, lambda: twist_pub.get_subscription_count() > 0
                and io_pub.get_subscription_count() > 0, TIMEOUT)

    # Before any command: failsafe, a zero goal is republished.
    assert spin(executor, lambda: len(goals) >= 2, TIMEOUT)
    assert not np.any(goals[-1])

    # A fresh valid command is passed on as the goal.
    wanted = [0.3, -0.2, 0.1, 0.0, 0.05, -0.4]
    twist_pub.publish(twist(surface, wanted))
    assert spin(executor, lambda: any(np.allclose(g, wanted) for g in goals), TIMEOUT)
    assert node.gate.counts[Verdict.ACCEPTED] == 1

    # Refused commands: counted per verdict and never passed on.
    refused = [
        (Verdict.NON_FINITE, twist(surface, [math.nan, 0, 0, 0, 0, 0])),
        (Verdict.NON_FINITE, twist(surface, [0, 0, 0, 0, 0, math.inf])),
        (Verdict.OUT_OF_RANGE, twist(surface, [1.5, 0, 0, 0, 0, 0])),
        (Verdict.OUT_OF_RANGE, twist(surface, [0, 0, 0, 0, 0, -1.25])),
        (Verdict.STALE, twist(surface, [0.77, 0, 0, 0, 0, 0], offset_s=-30.0)),
        (Verdict.FUTURE, twist(surface, [0.66, 0, 0, 0, 0, 0], offset_s=+30.0)),
    ]
    expected = {v: 0 for v in Verdict}
    expected[Verdict.ACCEPTED] = 1
    for verdict, msg in refused:
        expected[verdict] += 1
        twist_pub.publish(msg)
        assert spin(executor, lambda v=verdict: node.gate.counts[v] == expected[v], TIMEOUT), \
            f'{verdict} not counted: {node.gate.counts}'
    assert node.gate.counts == expected
    for g in goals:
        assert np.all(np.isfinite(g))
        assert np.all(np.abs(g) <= 1.0)
        assert not np.isclose(g[0], 0.77) and not np.isclose(g[0], 0.66)

    # No accepted command for `timeout`: the goal falls to zero by itself.
    n = len(goals)
    assert spin(executor, lambda: len(goals) > n and not np.any(goals[-1]), TIMEOUT)
    assert node.gate.failsafe(stamp_ns(node))

    # IO: valid requests forwarded as they are, invalid ones refused and counted.
    io_pub.publish(io_msg('gpio_12', True))
    io_pub.publish(io_msg('manipulator', 400))
    io_pub.publish(io_msg('manipulator', 2.5))
    assert spin(executor, lambda: len(ios) == 3, TIMEOUT)
    assert [(m.name, convert.parameter_value_to_python(m.value)) for m in ios] == [
        ('gpio_12', True), ('manipulator', 400), ('manipulator', 2.5)]
    io_pub.publish(io_msg('manipulator', math.nan))
    assert spin(executor, lambda: node.io_rejected == 1, TIMEOUT)
    io_pub.publish(io_msg('', True))
    assert spin(executor, lambda: node.io_rejected == 2, TIMEOUT)
    io_pub.publish(io_msg('lights', ParameterValue(type=ParameterType.PARAMETER_NOT_SET)))
    assert spin(executor, lambda: node.io_rejected == 3, TIMEOUT)
    assert node.io_forwarded == 3

    # The failsafe (still active, goals keep coming) never emits io.
    n = len(goals)
    assert spin(executor, lambda: len(goals) >= n + 3, TIMEOUT)
    assert not np.any(goals[-1])
    assert len(ios) == 3


def test_command_receiver_failsafe_after_commands_stop(context, executor, spin):
    """A stream of commands, then silence: zero goal after `timeout`, and back on a new one."""
    node = add(executor, CommandReceiverNode(
        node_name='command_receiver', context=context, parameter_overrides=[
            Parameter('timeout', value=0.2), Parameter('max_age', value=5.0)]))
    surface = probe(context, executor, 'surface')
    twist_pub = surface.create_publisher(TwistStamped, topics.SURFACE_TWIST.name,
                                         topics.SURFACE_TWIST.qos)
    goals: list[np.ndarray] = []
    surface.create_topic_subscription(
        topics.TRAJECTORY_REQUEST, lambda m: goals.append(convert.twist_to_nu(m.twist)))
    # A plain ROS subscription (as `ros2 topic echo` would make) gets the link topic via DDS.
    echoed: list[TwistStamped] = []
    surface.create_subscription(TwistStamped, topics.TRAJECTORY_REQUEST.name, echoed.append,
                                topics.TRAJECTORY_REQUEST.qos)
    LinkBus.of(context).connect()
    assert spin(executor, lambda: twist_pub.get_subscription_count() > 0, TIMEOUT)
    assert spin(executor, lambda: len(echoed) >= 2, TIMEOUT)
    assert echoed[-1].header.frame_id == topics.BODY_FRAME
    wanted = [0.0, 0.0, -0.2, 0.0, 0.0, 0.1]
    for round_ in range(2):
        accepted = node.gate.counts[Verdict.ACCEPTED]
        n = len(goals)
        twist_pub.publish(twist(surface, wanted))
        assert spin(executor, lambda a=accepted: node.gate.counts[Verdict.ACCEPTED] > a,
                    TIMEOUT)
        assert any(np.allclose(g, wanted) for g in goals[n:])  # passed on at once
        n = len(goals)
        assert spin(executor, lambda n=n: len(goals) > n and not np.any(goals[-1]), TIMEOUT)
        assert node._failsafe


# --- 2. live tuning through the parameter services ---------------------------------------


def _imu(t_ns: int, rate_z: float) -> Imu:
    msg = Imu()
    convert.ns_to_stamp(t_ns, msg.header.stamp)
    msg.header.frame_id = topics.IMU_FRAME
    msg.orientation.w = 1.0
    msg.angular_velocity.z = rate_z
    return msg


def _param_client(executor: Any, spin: Any, context: Any, target: str) -> AsyncParameterClient:
    caller = probe(context, executor, 'ros2_param')
    client = AsyncParameterClient(caller, target)
    assert spin(executor, client.services_are_ready, TIMEOUT), 'parameter services not found'
    return client


def _get(executor: Any, spin: Any, client: AsyncParameterClient, name: str) -> Any:
    response = call(executor, client.get_parameters([name]))
    return convert.parameter_value_to_python(response.values[0])


def _set(executor: Any, spin: Any, client: AsyncParameterClient, name: str, value: Any) -> Any:
    response = call(executor, client.set_parameters([Parameter(name, value=value)]))
    assert len(response.results) == 1
    return response.results[0]


def test_velocity_control_live_tuning(context, executor, spin):
    node = add(executor, VelocityControlNode(
        node_name='control_loop', context=context, parameter_overrides=[
            Parameter('ki', value=[0.0] * 6), Parameter('goal_timeout', value=60.0)]))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    taus: list[np.ndarray] = []
    stamps: list[int] = []

    def on_tau(msg: WrenchStamped) -> None:
        taus.append(convert.wrench_to_tau(msg.wrench))
        stamps.append(convert.stamp_to_ns(msg.header.stamp))

    feeder.create_topic_subscription(topics.FORCE_COMMAND, on_tau)
    LinkBus.of(context).connect()
    client = _param_client(executor, spin, context, 'control_loop')

    goal = TwistStamped()
    goal.twist.linear.x = 0.2  # surge is not measured: feed-forward only
    goal_pub.publish(goal)
    t = [1_000_000_000]

    def feed(count: int) -> np.ndarray:
        for _ in range(count):
            t[0] += 10_000_000
            imu_pub.publish(_imu(t[0], rate_z=0.5))  # yaw rate error -0.5 rad/s
        assert stamps and stamps[-1] == t[0], 'no tau for the last IMU sample'
        return taus[-1]

    t[0] += 10_000_000
    imu_pub.publish(_imu(t[0], rate_z=0.5))  # the first sample only initializes
    assert not taus
    tau = feed(5)
    assert tau[0] > 0.0, 'the goal on trajectory_request did not reach the controller'
    assert tau[5] == pytest.approx(-4.0 * 0.5)  # kp_yaw 4, no ki: tau_N = kp e

    # Out of range: an array element (checked by Enbarr) and a scalar (by rclpy).
    result = _set(executor, spin, client, 'kp', [20.0, 20.0, 20.0, 4.0, 4.0, -1.0])
    assert not result.successful
    assert 'kp[5]' in result.reason and '-1.0' in result.reason
    result = _set(executor, spin, client, 'level_gain', 500.0)
    assert not result.successful and 'level_gain' in result.reason
    # Wrong length: refused by the settings build, naming the parameter.
    result = _set(executor, spin, client, 'kp', [1.0, 2.0, 3.0])
    assert not result.successful and 'kp' in result.reason
    # Read-only.
    result = _set(executor, spin, client, 'velocity_topic', 'dvl/odometry')
    assert not result.successful and result.reason
    # Wrong type.
    result = _set(executor, spin, client, 'level_gain', 'high')
    assert not result.successful and result.reason
    # Every refusal kept the old values, in the node and its controller.
    assert _get(executor, spin, client, 'kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 4.0]
    assert _get(executor, spin, client, 'level_gain') == 2.0
    assert _get(executor, spin, client, 'velocity_topic') == ''
    assert node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 4.0)
    assert node.controller.settings.level_gain == 2.0
    assert feed(1)[5] == pytest.approx(-2.0)

    # A valid change is applied and acts on the next control step.
    result = _set(executor, spin, client, 'kp', [20.0, 20.0, 20.0, 4.0, 4.0, 8.0])
    assert result.successful, result.reason
    assert node.controller.settings.kp == (20.0, 20.0, 20.0, 4.0, 4.0, 8.0)
    assert _get(executor, spin, client, 'kp') == [20.0, 20.0, 20.0, 4.0, 4.0, 8.0]
    assert feed(1)[5] == pytest.approx(-8.0 * 0.5)
    result = _set(executor, spin, client, 'level_gain', 5.0)
    assert result.successful, result.reason
    assert node.controller.settings.level_gain == 5.0


def test_attitude_filter_live_tuning(context, executor, spin):
    node = add(executor, AttitudeFilterNode(node_name='filtering', context=context))
    client = _param_client(executor, spin, context, 'filtering')
    before = node.filter.settings
    result = _set(executor, spin, client, 'accel_noise', 0.2)
    assert result.successful, result.reason
    assert node.filter.settings is not before
    assert node.filter.settings.accel_noise == 0.2
    assert node.filter.settings.gyro_noise == before.gyro_noise
    result = _set(executor, spin, client, 'accel_noise', -1.0)
    assert not result.successful and 'accel_noise' in result.reason
    assert node.filter.settings.accel_noise == 0.2
    assert _get(executor, spin, client, 'accel_noise') == 0.2


# --- 3. IO plugins ------------------------------------------------------------------------


def _io_probe(context: Any, executor: Any) -> tuple[Any, list[tuple[str, Any]]]:
    p = probe(context, executor, 'surface')
    pub = p.create_topic_publisher(topics.IO_REQUEST)
    states: list[tuple[str, Any]] = []
    p.create_topic_subscription(
        topics.IO_STATE,
        lambda m: states.append((m.name, convert.parameter_value_to_python(m.value))))
    LinkBus.of(context).connect()
    return pub, states


def test_sim_gpio_acts_only_on_its_pin_with_a_bool(context, executor):
    node = add(executor, SimGpioNode(node_name='lights', context=context,
                                     parameter_overrides=[Parameter('pin', value=12)]))
    pub, states = _io_probe(context, executor)
    assert node.executor_name == 'gpio_12' and node.level is False

    pub.publish(io_msg('gpio_12', True))
    assert node.level is True and states == [('gpio_12', True)] and node.handled == 1
    pub.publish(io_msg('gpio_13', False))      # another executor: ignored
    assert node.level is True and len(states) == 1 and node.handled == 1
    assert node.refused == 0
    pub.publish(io_msg('gpio_12', 1))          # an int is not a level: refused
    assert node.refused == 1 and node.level is True and len(states) == 1
    pub.publish(io_msg('gpio_12', 'on'))
    assert node.refused == 2 and len(states) == 1
    pub.publish(io_msg('gpio_12', False))
    assert node.level is False and states[-1] == ('gpio_12', False) and node.handled == 2


def test_sim_stepper_moves_to_target(context, executor, spin):
    node = add(executor, SimStepperNode(node_name='manipulator', context=context,
                                        parameter_overrides=[
                                            Parameter('executor', value='manipulator'),
                                            Parameter('max_rate', value=400.0),
                                            Parameter('max_position', value=500)]))
    pub, states = _io_probe(context, executor)
    assert node.executor_name == 'manipulator'

    pub.publish(io_msg('manipulator', 120))
    assert node.target == 120 and node.handled == 1
    assert spin(executor, lambda: states and states[-1] == ('manipulator', 120), TIMEOUT)
    assert all(name == 'manipulator' for name, _ in states)
    positions = [v for _, v in states]
    assert positions == sorted(positions) and len(positions) > 1  # moved, not jumped
    assert node.position == 120.0

    pub.publish(io_msg('manipulator', True))   # a bool is not a step count
    assert node.refused == 1 and node.target == 120
    pub.publish(io_msg('manipulator', 400))    # 520 > max_position 500
    assert node.refused == 2 and node.target == 120
    pub.publish(io_msg('gpio_12', 10))         # another executor
    assert node.refused == 2 and node.target == 120 and node.handled == 1

    n = len(states)
    pub.publish(io_msg('manipulator', -20))
    assert node.target == 100
    assert spin(executor, lambda: states[-1] == ('manipulator', 100), TIMEOUT)
    assert len(states) > n
    # Nothing moves any more: io_state only while the position changes.
    n = len(states)
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert len(states) == n


# --- 4. simulated thrusters ---------------------------------------------------------------


def test_sim_thrusters_output_watchdog_refusals_and_safe_state(context, executor, spin):
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=0.0, command_timeout=0.1)))
    names = sim_parameters()['thruster_names']
    assert node.names == names and node.neutral
    p = probe(context, executor, 'controller')
    cmd_pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
    outputs: list[JointState] = []
    thrusts: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_OUTPUT, outputs.append)
    p.create_topic_subscription(topics.SIM_THRUST, thrusts.append)
    LinkBus.of(context).connect()

    def command(efforts: list[float], names_: list[str] = names) -> None:
        msg = JointState(name=list(names_), effort=[float(e) for e in efforts])
        msg.header.stamp = p.get_clock().now().to_msg()
        cmd_pub.publish(msg)

    cmd = [0.5, -0.5, 1.0, -1.0, 0.0, 0.25, -0.25, 0.1]
    command(cmd)
    assert len(outputs) == 1 and len(thrusts) == 1
    assert outputs[-1].name == names and thrusts[-1].name == names
    assert outputs[-1].effort.tolist() == pytest.approx(cmd)
    expected = [c * (51.5 if c >= 0 else 40.2) for c in cmd]
    assert thrusts[-1].effort.tolist() == pytest.approx(expected)
    assert not node.neutral

    # Commands in another order (by name), partial commands: missing thrusters are zero.
    command([0.2, -0.3], ['vert_rear_left', 'front_right'])
    assert outputs[-1].effort.tolist() == pytest.approx([-0.3, 0, 0, 0, 0, 0, 0, 0.2])
    assert thrusts[-1].effort.tolist() == pytest.approx(
        [-0.3 * 40.2, 0, 0, 0, 0, 0, 0, 0.2 * 51.5])

    # Refused: NaN, Inf, an unknown name, names/efforts of different lengths.
    command(cmd)
    n, before = len(outputs), node.command.copy()
    command([math.nan] + cmd[1:])
    command([math.inf] + cmd[1:])
    command([0.1], ['bow_thruster'])
    bad = JointState(name=names, effort=[0.1, 0.2])
    cmd_pub.publish(bad)
    assert node.refused == 4
    assert len(outputs) == n and len(thrusts) == n
    assert node.command.tolist() == before.tolist()

    # |cmd| > 1: clipped to the limits and counted.
    command([1.5, -2.0, 0, 0, 0, 0, 0, 0])
    assert node.clipped == 1
    assert outputs[-1].effort.tolist() == pytest.approx([1.0, -1.0, 0, 0, 0, 0, 0, 0])
    assert thrusts[-1].effort.tolist() == pytest.approx([51.5, -40.2, 0, 0, 0, 0, 0, 0])

    # Commands stop: the watchdog goes neutral by itself, once.
    n = len(outputs)
    assert node.timeouts == 0
    assert spin(executor, lambda: node.timeouts == 1, TIMEOUT)
    assert len(outputs) == n + 1
    assert not np.any(outputs[-1].effort) and not np.any(thrusts[-1].effort)
    assert node.neutral
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert node.timeouts == 1 and len(outputs) == n + 1  # neutral is not repeated

    # safe_state(): all zeros at once.
    command(cmd)
    assert np.any(outputs[-1].effort)
    node.safe_state()
    assert outputs[-1].name == names
    assert not np.any(outputs[-1].effort) and not np.any(thrusts[-1].effort)
    assert node.neutral


def test_sim_thrusters_time_constant_ramps_thrust(context, executor):
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=5.0, command_timeout=10.0)))
    names = node.names
    msg = JointState(name=names, effort=[1.0] * len(names))
    LinkBus.of(context).connect()
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
    pub.publish(msg)        # from neutral: no lag on the first command
    assert node.thrust == pytest.approx([51.5] * len(names))
    pub.publish(JointState(name=names, effort=[-1.0] * len(names)))
    assert np.all(node.thrust > -40.2) and np.all(node.thrust < 51.5)  # lags


def test_sim_thrusters_needs_thruster_names(context):
    with pytest.raises(ConfigurationError, match='thruster_names'):
        SimThrustersNode(node_name='thruster_control', context=context)


# --- 5. thruster converter ----------------------------------------------------------------


def test_thruster_converter_refuses_layout_that_cannot_yaw(context):
    # Horizontal thrusters on lines through the centre: no moment about z from any of them.
    layout = {
        'surge_fwd': ([0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
        'surge_aft': ([-0.2, 0.0, 0.0], [1.0, 0.0, 0.0]),
        'sway_left': ([0.0, 0.2, 0.0], [0.0, 1.0, 0.0]),
        'sway_right': ([0.0, -0.2, 0.0], [0.0, -1.0, 0.0]),
        'v_fl': ([0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_fr': ([0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_rl': ([-0.12, 0.2, 0.0], [0.0, 0.0, 1.0]),
        'v_rr': ([-0.12, -0.2, 0.0], [0.0, 0.0, 1.0]),
    }
    values: dict[str, Any] = {'thruster_names': list(layout)}
    for n, (pos, d) in layout.items():
        values.update({f'thrusters.{n}.position': pos, f'thrusters.{n}.direction': d,
                       f'thrusters.{n}.max_forward': 40.0, f'thrusters.{n}.max_reverse': 30.0})
    with pytest.raises(AllocationError, match='yaw') as info:
        ThrusterConverterNode(node_name='thruster_converter', context=context,
                              parameter_overrides=overrides(values))
    message = str(info.value)
    assert 'thruster_converter' in message
    for dof in ('surge', 'sway', 'heave'):
        assert f'produce {dof}' not in message
    # Without yaw in controlled_dofs the same layout is accepted.
    node = ThrusterConverterNode(
        node_name='thruster_converter_5dof', context=context, parameter_overrides=overrides(
            {**values, 'controlled_dofs': ['surge', 'sway', 'heave', 'roll', 'pitch']}))
    node.destroy_node()


def test_thruster_converter_allocates_wrench(context, executor):
    node = add(executor, ThrusterConverterNode(
        node_name='thruster_converter', context=context, parameter_overrides=layout_overrides()))
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.FORCE_COMMAND)
    commands: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_COMMANDS, commands.append)
    LinkBus.of(context).connect()
    thrusters = sim_thrusters()
    names = [t.name for t in thrusters]
    B = allocation_matrix(thrusters)
    fwd = np.array([t.max_forward for t in thrusters])
    rev = np.array([t.max_reverse for t in thrusters])

    def send(tau: list[float], ns: int) -> JointState:
        w = WrenchStamped()
        convert.ns_to_stamp(ns, w.header.stamp)
        w.header.frame_id = topics.BODY_FRAME
        convert.set_wrench(w.wrench, tau)
        n = len(commands)
        pub.publish(w)
        assert len(commands) == n + 1
        return commands[-1]

    tau = np.array([10.0, -5.0, 8.0, 0.5, -0.3, 1.0])
    out = send(tau.tolist(), 1_234_567_890_123)
    assert list(out.name) == names
    assert convert.stamp_to_ns(out.header.stamp) == 1_234_567_890_123
    u = np.array(out.effort)
    assert np.all(np.abs(u) <= 1.0) and np.any(u)
    thrust = np.where(u >= 0.0, u * fwd, u * rev)
    assert B @ thrust == pytest.approx(tau, abs=1e-6)
    assert not node.result.saturated and node.saturated == 0

    # Far beyond the thrusters: every command within [-1, 1], one at the limit, direction kept.
    big = np.array([500.0, 0.0, 300.0, 0.0, 0.0, 20.0])
    u = np.array(send(big.tolist(), 1_234_567_890_124).effort)
    assert np.all(np.abs(u) <= 1.0 + 1e-12) and np.max(np.abs(u)) == pytest.approx(1.0)
    delivered = B @ np.where(u >= 0.0, u * fwd, u * rev)
    assert node.saturated == 1
    assert np.cross(delivered[:3], big[:3]) == pytest.approx(np.zeros(3), abs=1e-6)
    assert delivered[0] / big[0] == pytest.approx(delivered[5] / big[5])

    # A non-finite wrench is refused, nothing published.
    n = len(commands)
    w = WrenchStamped()
    w.wrench.force.x = math.nan
    pub.publish(w)
    assert node.rejected == 1 and len(commands) == n


# --- 6. attitude filter -------------------------------------------------------------------

G = 9.81


@pytest.mark.parametrize('mag_body, yaw', [
    ([0.0, 1.8e-5, -4.8e-5], 0.0),            # body x east: north (+y world) is body +y
    ([1.8e-5, 0.0, -4.8e-5], math.pi / 2),    # body x north
])
def test_attitude_filter_level_at_rest(context, executor, mag_body, yaw):
    node = add(executor, AttitudeFilterNode(node_name='filtering', context=context))
    p = probe(context, executor, 'imu')
    raw_pub = p.create_topic_publisher(topics.IMU_RAW)
    mag_pub = p.create_topic_publisher(topics.IMU_MAG)
    out: list[Imu] = []
    p.create_topic_subscription(topics.IMU, out.append)
    LinkBus.of(context).connect()

    t = 5_000_000_000

    def sample(t_ns: int, gyro: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        mag = MagneticField()
        convert.ns_to_stamp(t_ns, mag.header.stamp)
        convert.set_vector3(mag.magnetic_field, mag_body)
        mag_pub.publish(mag)
        raw = Imu()
        convert.ns_to_stamp(t_ns, raw.header.stamp)
        raw.header.frame_id = topics.IMU_FRAME
        raw.orientation_covariance[0] = -1.0
        convert.set_vector3(raw.angular_velocity, gyro)
        convert.set_vector3(raw.linear_acceleration, (0.0, 0.0, G))
        raw_pub.publish(raw)

    for _ in range(300):
        t += 2_500_000
        sample(t)
    assert len(out) == 299 and node.samples == 299 and node.rejected == 0
    last = out[-1]
    assert convert.stamp_to_ns(last.header.stamp) == t
    assert last.header.frame_id == topics.IMU_FRAME
    q = convert.quaternion_to_array(last.orientation)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    roll, pitch, yaw_est = quat_to_euler(q)
    assert abs(roll) < 1e-3 and abs(pitch) < 1e-3
    assert abs(math.remainder(yaw_est - yaw, 2 * math.pi)) < 0.02
    cov = np.array(last.orientation_covariance).reshape(3, 3)
    assert np.all(np.diag(cov) > 0.0) and np.all(np.isfinite(cov))
    assert np.array(last.angular_velocity_covariance)[[0, 4, 8]].min() > 0.0
    assert convert.vector3_to_array(last.angular_velocity) == pytest.approx(np.zeros(3),
                                                                            abs=1e-3)

    # A NaN gyro sample is dropped and counted; so is a stamp that does not advance.
    sample(t + 2_500_000, gyro=(math.nan, 0.0, 0.0))
    assert node.rejected == 1 and len(out) == 299
    sample(t)
    assert node.rejected == 2 and len(out) == 299
    sample(t + 2_500_000)  # and the filter goes on
    assert len(out) == 300 and node.rejected == 2
    # A gap longer than max_gap (0.5 s): that sample is dropped and counted, the filter
    # starts over from the next one.
    t += 2_500_000 + 1_000_000_000
    sample(t)
    assert node.rejected == 3 and len(out) == 300 and not node.filter.initialized
    sample(t + 2_500_000)
    assert len(out) == 301 and node.rejected == 3 and node.filter.initialized


# --- 7. simulator and simulated IMU -------------------------------------------------------


def test_simulator_truth_and_sim_imu_errors(context, executor):
    bias = [0.01, -0.02, 0.03]
    sim = add(executor, RovSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides(sim_parameters('simulator'))))
    imu = add(executor, SimImuNode(node_name='imu', context=context, parameter_overrides=[
        Parameter('gyro_bias', value=bias), Parameter('gyro_noise', value=0.002)]))
    p = probe(context, executor, 'listener')
    truth: dict[int, Imu] = {}
    raw: dict[int, Imu] = {}
    mags: dict[int, MagneticField] = {}
    p.create_topic_subscription(topics.SIM_IMU,
                               lambda m: truth.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(topics.IMU_RAW,
                               lambda m: raw.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    p.create_topic_subscription(topics.IMU_MAG,
                               lambda m: mags.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
    LinkBus.of(context).connect()
    assert not sim._loops[0].running and imu is not None  # never started: driven by hand

    deadline = time.monotonic() + TIMEOUT
    while sim.samples < 400 and time.monotonic() < deadline:
        sim.step()
        time.sleep(0.001)
    assert sim.samples >= 400
    assert len(truth) == len(raw) == len(mags) == sim.samples
    stamps = sorted(truth)
    assert stamps == sorted(raw) == sorted(mags)
    assert np.all(np.diff(stamps) > 0)

    f = np.array([convert.vector3_to_array(m.linear_acceleration) for m in truth.values()])
    assert f == pytest.approx(np.tile([0.0, 0.0, G], (len(f), 1)), abs=1e-2)
    for m in truth.values():
        roll, pitch, yaw = quat_to_euler(convert.quaternion_to_array(m.orientation))
        assert abs(roll) < 1e-3 and abs(pitch) < 1e-3 and abs(yaw) < 1e-3

    gyro_err = np.array([convert.vector3_to_array(raw[s].angular_velocity)
                         - convert.vector3_to_array(truth[s].angular_velocity) for s in stamps])
    accel_err = np.array([convert.vector3_to_array(raw[s].linear_acceleration)
                          - convert.vector3_to_array(truth[s].linear_acceleration)
                          for s in stamps])
    n = len(stamps)
    assert gyro_err.mean(axis=0) == pytest.approx(bias, abs=5 * 0.002 / math.sqrt(n))
    assert gyro_err.std(axis=0) == pytest.approx([0.002] * 3, rel=0.25)
    assert accel_err.mean(axis=0) == pytest.approx(np.zeros(3), abs=5 * 0.03 / math.sqrt(n))
    assert accel_err.std(axis=0) == pytest.approx([0.03] * 3, rel=0.25)
    assert raw[stamps[0]].orientation_covariance[0] == -1.0
    m = np.array([convert.vector3_to_array(mags[s].magnetic_field) for s in stamps])
    assert m.mean(axis=0) == pytest.approx([0.0, 1.8e-5, -4.8e-5], abs=2e-7)


def test_velocity_control_drops_out_of_order_imu(context, executor):
    """A late or repeated IMU stamp is dropped and counted; the loop state is kept (a reset
    would drop the reference model's velocity and jolt the commanded force)."""
    node = add(executor, VelocityControlNode(node_name='control_loop', context=context))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    taus: list[np.ndarray] = []
    feeder.create_topic_subscription(
        topics.FORCE_COMMAND, lambda m: taus.append(convert.wrench_to_tau(m.wrench)))
    LinkBus.of(context).connect()
    goal = TwistStamped()
    goal.twist.linear.x = 0.3
    t = 1_000_000_000
    convert.ns_to_stamp(t, goal.header.stamp)  # goal age is measured on the IMU time line
    goal_pub.publish(goal)
    for _ in range(50):
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    ref_before = node.reference.nu_ref.copy()
    assert ref_before[0] > 0.1 and len(taus) == 49
    imu_pub.publish(_imu(t - 5_000_000, rate_z=0.0))  # from the past
    imu_pub.publish(_imu(t, rate_z=0.0))              # repeated
    assert node.rejected == 2 and len(taus) == 49
    np.testing.assert_array_equal(node.reference.nu_ref, ref_before)
    imu_pub.publish(_imu(t + 10_000_000, rate_z=0.0))
    assert len(taus) == 50 and abs(taus[-1][0] - taus[-2][0]) < 0.5


def test_velocity_control_ignores_a_stale_goal(context, executor):
    """A goal stamped more than goal_timeout before the IMU sample counts as zero."""
    node = add(executor, VelocityControlNode(node_name='control_loop', context=context))
    feeder = probe(context, executor, 'feeder')
    imu_pub = feeder.create_topic_publisher(topics.IMU)
    goal_pub = feeder.create_topic_publisher(topics.TRAJECTORY_REQUEST)
    LinkBus.of(context).connect()
    goal = TwistStamped()
    goal.twist.linear.x = 0.3
    convert.ns_to_stamp(1_000_000_000, goal.header.stamp)
    goal_pub.publish(goal)
    t = 1_000_000_000
    for _ in range(90):  # 0.9 s: the goal is fresh, the reference reaches it
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    assert node.reference.nu_ref[0] > 0.25
    for _ in range(250):  # samples go on without a gap; from 2.0 s the goal is stale
        t += 10_000_000
        imu_pub.publish(_imu(t, rate_z=0.0))
    assert abs(node.reference.nu_ref[0]) < 1e-3
    assert node.rejected == 0  # no gap, no reset: the goal timed out
