"""Node tests: the thruster monitor against the simulated thrusters, a rotor fouled live."""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy.parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from support.nodes import add, probe, TIMEOUT
from support.rov import layout_overrides, sim_parameters

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

    def last(self) -> tuple[int, str, dict[str, str]]:
        s = self.status[-1]
        return s.level[0], s.message, {kv.key: kv.value for kv in s.values}


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
    assert blocked in message and values['failed_thrusters'] == blocked
    assert 'blocked or tangled' in values[f'failed.{blocked}']
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
    assert rig.last()[2]['failed_thrusters'] == tangled


def test_no_feedback_is_reported_stale_not_judged(context, executor, spin):
    monitor = add(executor, ThrusterMonitorNode(context=context))
    level, message, _ = monitor.diagnostic_status()
    assert level == DEGRADED and 'stale' in message
