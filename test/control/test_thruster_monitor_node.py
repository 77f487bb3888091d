"""Node tests: the thruster monitor against the simulated thrusters, a rotor fouled live."""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy.parameter
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from support.nodes import add, probe, TIMEOUT
from support.rov import layout_overrides, sim_parameters

from enbarr_core.allocation.thruster_converter_node import ThrusterConverterNode
from enbarr_core.control.thruster_monitor_node import CLEAR_TOPIC, ThrusterMonitorNode
from enbarr_core.framework.health import DEGRADED, ERROR, OK
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.thrusters.sim import SimThrustersNode

pytestmark = pytest.mark.node

NAMES = sim_parameters()['thruster_names']


class Rig:
    """Simulated thrusters with their motor lag, the monitor, and a controller at 50 Hz."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.executor = executor
        self.thrusters = add(executor, SimThrustersNode(
            node_name='thruster_control', context=context,
            parameter_overrides=layout_overrides(time_constant=0.05, command_timeout=1.0)))
        self.monitor = add(executor, ThrusterMonitorNode(
            context=context, parameter_overrides=[
                rclpy.parameter.Parameter('hold_time', value=0.3)]))
        self.probe = p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.clear = p.create_publisher(String, CLEAR_TOPIC, 10)
        self.status: list[Any] = []
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name, self._on_diag,
                              topics.DIAGNOSTICS.qos)
        LinkBus.of(context).connect()
        self.thrusters.start()
        p.create_timer(0.02, self.command)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        self.status += [s for s in msg.status if s.hardware_id == 'thruster_monitor']

    def command(self) -> None:
        msg = JointState(name=list(NAMES), effort=[0.6] * len(NAMES))
        msg.header.stamp = self.probe.get_clock().now().to_msg()
        self.pub.publish(msg)

    def last(self) -> tuple[int, str, list[tuple[str, str]]]:
        s = self.status[-1]
        return s.level[0], s.message, [(kv.key, kv.value) for kv in s.values]


@pytest.fixture
def rig(context, executor) -> Rig:
    return Rig(context, executor)


def test_healthy_thrusters_stay_ok_then_a_blocked_one_is_failed_until_cleared(rig, spin):
    assert spin(rig.executor, lambda: rig.status and rig.last()[0] == OK, TIMEOUT)
    assert rig.monitor.health is not None and set(rig.monitor.health.names) == set(NAMES)
    blocked = NAMES[3]
    rig.thrusters.set_parameters([rclpy.parameter.Parameter('fouled',
                                                            value=[f'{blocked}:0.0'])])
    assert spin(rig.executor, lambda: rig.last()[0] == ERROR, TIMEOUT)
    level, message, values = rig.last()
    assert blocked in message
    # the convention the allocation listens for (allocation.failures): one key per thruster
    assert [v for k, v in values if k == 'failed_thruster'] == [blocked]
    assert 'blocked or tangled' in dict(values)[f'failed.{blocked}']
    # freed, it stays failed until the operator clears it
    rig.thrusters.set_parameters([rclpy.parameter.Parameter('fouled', value=[''])])
    n = len(rig.status)
    assert spin(rig.executor, lambda: len(rig.status) > n + 1, TIMEOUT)
    assert rig.last()[0] == ERROR
    rig.clear.publish(String(data=blocked))
    assert spin(rig.executor, lambda: rig.last()[0] == OK, TIMEOUT)


def test_a_tangled_rotor_is_failed_and_a_clean_one_beside_it_is_not(rig, spin):
    tangled = NAMES[0]
    rig.thrusters.set_parameters([rclpy.parameter.Parameter('fouled',
                                                            value=[f'{tangled}:0.3'])])
    assert spin(rig.executor, lambda: rig.status and rig.last()[0] == ERROR, TIMEOUT)
    assert [v for k, v in rig.last()[2] if k == 'failed_thruster'] == [tangled]


def test_no_feedback_is_reported_stale_not_judged(context, executor, spin):
    monitor = add(executor, ThrusterMonitorNode(context=context))
    level, message, _ = monitor.diagnostic_status()
    assert level == DEGRADED and 'stale' in message


def test_a_blocked_thruster_is_taken_out_of_the_allocation_and_given_back(context, executor,
                                                                          spin):
    """force -> converter -> thrusters (one fouled) -> feedback -> monitor -> /diagnostics ->
    converter: the blocked thruster is commanded zero, the others take over; cleared, it is
    commanded again."""
    thrusters = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context,
        parameter_overrides=layout_overrides(time_constant=0.05, command_timeout=1.0)))
    converter = add(executor, ThrusterConverterNode(context=context,
                                                    parameter_overrides=layout_overrides()))
    monitor = add(executor, ThrusterMonitorNode(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('hold_time', value=0.3)]))
    p = probe(context, executor, 'controller')
    force = p.create_topic_publisher(topics.FORCE_COMMAND)
    clear = p.create_publisher(String, CLEAR_TOPIC, 10)
    commands: list[JointState] = []
    p.create_topic_subscription(topics.THRUSTER_COMMANDS, commands.append)
    LinkBus.of(context).connect()
    thrusters.start()

    def push() -> None:   # surge and heave: every thruster works
        w = WrenchStamped()
        w.header.stamp = p.get_clock().now().to_msg()
        w.wrench.force.x, w.wrench.force.z = 20.0, 80.0   # 20 N a vertical: judged
        force.publish(w)
    p.create_timer(0.02, push)

    def effort(name: str) -> float:
        last = commands[-1]
        return float(last.effort[list(last.name).index(name)])

    blocked = NAMES[4]   # a vertical thruster
    assert spin(executor, lambda: commands and abs(effort(blocked)) > 0.1, TIMEOUT)
    thrusters.set_parameters([rclpy.parameter.Parameter('fouled', value=[f'{blocked}:0.0'])])
    assert spin(executor, lambda: blocked in converter.allocator.failed, TIMEOUT)
    assert spin(executor, lambda: effort(blocked) == 0.0, TIMEOUT)
    # without vert_front_right, heave with no roll or pitch moment is carried by the
    # diagonal pair alone: vert_front_left and vert_rear_right, 40 N each (vert_rear_left 0)
    assert effort(NAMES[5]) == pytest.approx(40.0 / 51.5, abs=0.02)
    assert effort(NAMES[6]) == pytest.approx(40.0 / 51.5, abs=0.02)
    assert monitor.health is not None and blocked in monitor.health.failed
    # freed and cleared by the operator: back in the allocation
    thrusters.set_parameters([rclpy.parameter.Parameter('fouled', value=[''])])
    clear.publish(String(data=blocked))
    assert spin(executor, lambda: blocked not in converter.allocator.failed, TIMEOUT)
    assert spin(executor, lambda: abs(effort(blocked)) > 0.1, TIMEOUT)
