"""Node tests: the allocation nodes take failed thrusters from their parameter and from
``/diagnostics``, re-solve, and report what is out and what is lost.

Expected thrusts come from the ROV's or the Saucer's layout written out here (``B`` of the
profile's positions and directions) and from hand-derived answers, never from the allocator.
"""

from __future__ import annotations

import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from support.nodes import add, param_client, probe, set_param, TIMEOUT
from support.rov import layout_overrides, sim_thrusters
from support.saucer import NAMES, overrides, POSITIONS, tau_of

from enbarr_core.allocation.azimuth_allocation_node import AzimuthAllocationNode
from enbarr_core.allocation.fixed import allocation_matrix
from enbarr_core.allocation.thruster_converter_node import ThrusterConverterNode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

ROV = sim_thrusters()
ROV_NAMES = [t.name for t in ROV]
B = allocation_matrix(ROV)
FWD = np.array([t.max_forward for t in ROV])
REV = np.array([t.max_reverse for t in ROV])
ERROR = b'\x02'  # diagnostic_msgs/DiagnosticStatus.ERROR
OK = b'\x00'


def wrench(tau: list[float], ns: int, three: bool = False) -> WrenchStamped:
    w = WrenchStamped()
    convert.ns_to_stamp(ns, w.header.stamp)
    w.header.frame_id = topics.BODY_FRAME
    (convert.set_wrench_tau3 if three else convert.set_wrench)(w.wrench, tau)
    return w


def detector_status(level: bytes, *entries: str, source: str = 'thrust_monitor') -> Any:
    """What a fault detector publishes: ERROR, one ``failed_thruster`` value per thruster."""
    values = [KeyValue(key='rpm_error', value='0.9')]
    values += [KeyValue(key='failed_thruster', value=e) for e in entries]
    return DiagnosticArray(status=[DiagnosticStatus(level=level, name=source,
                                                    message='no thrust', values=values)])


class Logged:
    """Counts the warnings a node logs (the change must be logged once, not per status)."""

    def __init__(self, node: Any) -> None:
        self.warnings: list[str] = []
        self.infos: list[str] = []
        real = node.get_logger()
        owner = self

        class Logger:
            def warn(self, msg: str, **kw: Any) -> None:
                owner.warnings.append(msg)

            def info(self, msg: str, **kw: Any) -> None:
                owner.infos.append(msg)

            def __getattr__(self, name: str) -> Any:
                return getattr(real, name)

        node.get_logger = lambda: Logger()


class RovRig:
    def __init__(self, context: Any, executor: Any, spin: Any, **extra: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, ThrusterConverterNode(
            node_name='thruster_converter', context=context,
            parameter_overrides=layout_overrides(**extra)))
        self.log = Logged(self.node)
        p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.FORCE_COMMAND)
        self.commands: list[JointState] = []
        p.create_topic_subscription(topics.THRUSTER_COMMANDS, self.commands.append)
        self.diag = p.create_publisher(DiagnosticArray, topics.DIAGNOSTICS.name,
                                       topics.DIAGNOSTICS.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.diag.get_subscription_count() > 0, TIMEOUT)
        self.ns = 1_000_000_000

    def send(self, tau: list[float]) -> np.ndarray:
        """Publish tau; return the thrust [N] of each thruster from the published command."""
        self.ns += 10_000_000
        n = len(self.commands)
        self.pub.publish(wrench(tau, self.ns))
        assert len(self.commands) == n + 1
        u = np.array(self.commands[-1].effort)
        return np.where(u >= 0.0, u * FWD, u * REV)

    def report(self) -> tuple[int, str, dict[str, Any]]:
        reports: list[Any] = []
        self.node.publish_diagnostics = lambda *a: reports.append(a)
        self.node._report()
        return reports[-1]


TAU = [3.0, -2.0, 1.5, 0.2, -0.1, 0.4]


def test_operator_marks_a_thruster_dead_live_and_the_rest_deliver_exactly(context, executor,
                                                                          spin):
    rig = RovRig(context, executor, spin)
    assert rig.report()[0] == 0
    client = param_client(executor, spin, context, 'thruster_converter')  # as ros2 param set
    result = set_param(executor, spin, client, 'failed_thrusters', ['front_right'])
    assert result.successful, result.reason
    thrust = rig.send(TAU)
    assert thrust[0] == 0.0
    np.testing.assert_allclose(B @ thrust, TAU, atol=1e-9)
    # Surge alone, by hand: front_left 0, the rear pair X / (2 cos 45) each.
    thrust = rig.send([5.0, 0, 0, 0, 0, 0])
    h = 5.0 / (2 * math.sqrt(0.5))
    np.testing.assert_allclose(thrust[:4], [0.0, 0.0, h, h], atol=1e-9)
    level, message, values = rig.report()
    assert level == 1 and 'thrusters out: front_right:dead; lost: none' in message, message
    assert values['thrusters_out'] == 'front_right:dead' and values['lost_dofs'] == ''
    assert len(rig.log.warnings) == 1 and 'front_right' in rig.log.warnings[0]
    # Two front ones out: sway and yaw cannot be produced alone any more.
    result = set_param(executor, spin, client, 'failed_thrusters',
                       ['front_right', 'front_left:dead'])
    assert result.successful, result.reason
    level, message, values = rig.report()
    assert level == 1 and values['lost_dofs'] == 'sway,yaw', values
    delivered = B @ rig.send(TAU)
    np.testing.assert_allclose(delivered[[0, 2, 3, 4]], np.array(TAU)[[0, 2, 3, 4]], atol=1e-9)
    np.testing.assert_allclose(delivered[[1, 5]], 0.0, atol=1e-9)
    # Back to none: the nominal allocation.
    assert set_param(executor, spin, client, 'failed_thrusters', ['']).successful
    assert rig.report()[0] == 0 and rig.node.allocator.failed == {}
    assert np.all(rig.send(TAU) != 0.0)
    assert len(rig.log.infos) == 1 and 'back' in rig.log.infos[0]


@pytest.mark.parametrize('bad, reason', [
    ('front_middle', "'front_middle': unknown thruster 'front_middle'"),
    ('front_right:stuck:20', "'front_right:stuck:20': expected front_right, front_right:dead"),
])
def test_a_bad_entry_is_refused_naming_it(context, executor, spin, bad, reason):
    rig = RovRig(context, executor, spin)
    result = rig.node.set_parameters([Parameter('failed_thrusters', value=['rear_left', bad])])[0]
    assert not result.successful and result.reason.startswith('failed_thrusters: ')
    assert reason in result.reason, result.reason
    assert rig.node.allocator.failed == {}  # nothing half applied
    with pytest.raises(ConfigurationError, match=reason) as info:
        ThrusterConverterNode(node_name='converter_bad', context=context,
                              parameter_overrides=layout_overrides(failed_thrusters=[bad]))
    assert info.value.parameter == 'failed_thrusters'


def test_a_detector_on_diagnostics_takes_a_thruster_out_and_gives_it_back(context, executor,
                                                                          spin):
    rig = RovRig(context, executor, spin)
    for _ in range(3):  # a detector repeats its status every period: one change, one log
        rig.diag.publish(detector_status(ERROR, 'vert_front_right'))
    assert spin(executor, lambda: 'vert_front_right' in rig.node.allocator.failed, TIMEOUT)
    # Heave alone, by hand: the diagonal pair left (front left, rear right) carries it.
    thrust = rig.send([0, 0, 4.0, 0, 0, 0])
    np.testing.assert_allclose(thrust[4:], [0.0, 2.0, 2.0, 0.0], atol=1e-9)
    level, message, values = rig.report()
    assert level == 1 and values['thrusters_out'] == 'vert_front_right:dead', message
    # A warning, an unknown name or another node's report does nothing.
    rig.diag.publish(detector_status(b'\x01', 'front_left', source='other'))
    rig.diag.publish(detector_status(ERROR, 'thruster_9', source='other'))
    rig.diag.publish(detector_status(ERROR, 'rear_left', source='last'))
    assert spin(executor, lambda: 'rear_left' in rig.node.allocator.failed, TIMEOUT)
    assert list(rig.node.allocator.failed) == ['rear_left', 'vert_front_right']
    assert sum('thruster_9' in w for w in rig.log.warnings) == 1
    # The detector's OK clears what it reported; the other source's failure stays.
    rig.diag.publish(detector_status(OK))
    assert spin(executor, lambda: 'vert_front_right' not in rig.node.allocator.failed,
                TIMEOUT)
    assert list(rig.node.allocator.failed) == ['rear_left']
    changes = [w for w in rig.log.warnings if w.startswith('thrusters out')]
    # Three changes, each logged once: vert_front_right out, rear_left too, vert_front_right back.
    assert len(changes) == 3, changes


# -- the Saucer's azimuth allocation --------------------------------------------------------

class SaucerRig:
    def __init__(self, context: Any, executor: Any, spin: Any, **extra: Any) -> None:
        self.node = add(executor, AzimuthAllocationNode(
            node_name='allocation', context=context, parameter_overrides=overrides(extra)))
        p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.FORCE_COMMAND)
        self.commands: list[JointState] = []
        p.create_topic_subscription(topics.AZIMUTH_COMMANDS, self.commands.append)
        self.diag = p.create_publisher(DiagnosticArray, topics.DIAGNOSTICS.name,
                                       topics.DIAGNOSTICS.qos)
        LinkBus.of(context).connect()
        assert spin(executor, lambda: self.diag.get_subscription_count() > 0, TIMEOUT)
        self.ns = 1_000_000_000

    def send(self, tau: list[float]) -> tuple[np.ndarray, np.ndarray]:
        self.ns += 20_000_000
        n = len(self.commands)
        self.pub.publish(wrench(tau, self.ns, three=True))
        assert len(self.commands) == n + 1
        return np.array(self.commands[-1].effort), np.array(self.commands[-1].position)


def test_azimuth_stuck_from_the_parameter_and_dead_from_diagnostics(context, executor, spin):
    rig = SaucerRig(context, executor, spin, failed_thrusters=['az_port_aft:stuck:-60'])
    tau = [0.5, -0.3, 0.05]
    thrust, angle = rig.send(tau)
    assert angle[NAMES.index('az_port_aft')] == pytest.approx(math.radians(-60.0), abs=1e-12)
    np.testing.assert_allclose(tau_of(POSITIONS, thrust, angle), tau, atol=1e-9)
    level, message, values = rig.node.diagnostic_status()
    assert level == 1 and values['thrusters_out'] == 'az_port_aft:stuck:-60', message
    # A detector says the bow one is dead as well: stuck aft + stbd aft still give X, Y, N.
    rig.diag.publish(detector_status(ERROR, 'az_bow:dead'))
    assert spin(executor, lambda: 'az_bow' in rig.node.allocator.failed, TIMEOUT)
    thrust, angle = rig.send(tau)
    assert thrust[NAMES.index('az_bow')] == 0.0
    np.testing.assert_allclose(tau_of(POSITIONS, thrust, angle), tau, atol=1e-9)
    # The operator takes the stuck one out entirely: one azimuth left, lost DOFs reported.
    assert rig.node.set_parameters([Parameter('failed_thrusters',
                                              value=['az_port_aft'])])[0].successful
    level, message, values = rig.node.diagnostic_status()
    assert level == 2 and values['lost_dofs'] == 'surge,sway,yaw', message
    thrust, _ = rig.send(tau)
    assert np.all(thrust == 0.0)
    bad = rig.node.set_parameters([Parameter('failed_thrusters',
                                             value=['az_bow:stuck:north'])])[0]
    assert not bad.successful and "'az_bow:stuck:north'" in bad.reason, bad.reason
