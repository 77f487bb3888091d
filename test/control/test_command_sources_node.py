"""Node tests: named command sources in the command receiver (a station beside an autonomy).

The receiver runs on ROS time driven by ``/clock`` from the test, so every timeout is judged
in the time the test publishes, whatever the machine's load. The station drives at priority
10 with a 0.3 s timeout, a scripted autonomy at priority 1 with 0.5 s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool, String
from support.nodes import add, probe, TIMEOUT
from support.rov import stamp_ns

from enbarr_core.control.command_gate import Verdict
from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus

MS = 1_000_000
T0 = 1_000 * 1_000 * MS
STATION_TOPIC = 'surface_command/twist'
AUTONOMY_TOPIC = 'autonomy/twist'
STATION_TIMEOUT_NS = 300 * MS
SOURCES = [
    Parameter('sources.names', value=['station', 'autonomy']),
    Parameter('sources.topics', value=[STATION_TOPIC, AUTONOMY_TOPIC]),
    Parameter('sources.priorities', value=[10, 1]),
    Parameter('sources.timeouts', value=[0.3, 0.5]),
]
STATION = [0.2, 0.0, 0.0, 0.0, 0.0, 0.1]
AUTONOMY = [0.0, 0.3, 0.0, 0.0, 0.0, -0.2]


class Rig:
    """The receiver with two named sources, a station and an autonomy, on a test clock."""

    def __init__(self, context: Any, executor: Any, spin: Any) -> None:
        self.executor, self.spin = executor, spin
        self.node = add(executor, CommandReceiverNode(
            node_name='command_receiver', context=context, parameter_overrides=[
                Parameter('use_sim_time', value=True), *SOURCES]))
        self.station = probe(context, executor, 'station')
        self.autonomy = probe(context, executor, 'autonomy')
        self.clock_pub = self.station.create_publisher(Clock, '/clock', 10)
        self.pubs = {
            'station': self.station.create_publisher(TwistStamped, STATION_TOPIC,
                                                     topics.SURFACE_TWIST.qos),
            'autonomy': self.autonomy.create_publisher(TwistStamped, AUTONOMY_TOPIC,
                                                       topics.SURFACE_TWIST.qos)}
        self.stop_pub = self.station.create_publisher(Bool, topics.SURFACE_STOP.name,
                                                      topics.SURFACE_STOP.qos)
        self.goals: list[np.ndarray] = []
        self.station.create_topic_subscription(
            topics.TRAJECTORY_REQUEST, lambda m: self.goals.append(convert.twist_to_nu(m.twist)))
        self.active: list[str] = []
        self.station.create_subscription(String, topics.SURFACE_ACTIVE_SOURCE.name,
                                         lambda m: self.active.append(m.data),
                                         topics.SURFACE_ACTIVE_SOURCE.qos)
        LinkBus.of(context).connect()
        assert self.until(lambda: all(p.get_subscription_count() > 0 for p in
                                      (*self.pubs.values(), self.stop_pub, self.clock_pub)))
        self.ns = 0

    def until(self, condition: Any) -> bool:
        return self.spin(self.executor, condition, TIMEOUT)

    def set_time(self, ns: int) -> None:
        """Publish ``ns`` on /clock and wait until the receiver's clock reads it."""
        self.ns = ns
        msg = Clock()
        convert.ns_to_stamp(ns, msg.clock)
        self.clock_pub.publish(msg)
        assert self.until(lambda: stamp_ns(self.node) == ns), f'/clock = {ns} never read'

    def send(self, source: str, nu: list[float], verdict: Verdict = Verdict.ACCEPTED,
             pub: Any = None) -> None:
        """Publish ``nu`` from ``source`` stamped now; wait until its gate judged it so."""
        gate = self.node.gates[source]
        before = gate.counts[verdict]
        msg = TwistStamped()
        convert.ns_to_stamp(self.ns, msg.header.stamp)
        msg.header.frame_id = topics.BODY_FRAME
        convert.set_twist(msg.twist, nu)
        (pub or self.pubs[source]).publish(msg)
        assert self.until(lambda: gate.counts[verdict] == before + 1), \
            f'{source}: no {verdict.value} ({gate.counts})'

    def stop(self, on: bool) -> None:
        self.stop_pub.publish(Bool(data=on))
        assert self.until(lambda: self.node.arbiter.stopped is on)

    def driving(self) -> str:
        """What drives now, as the receiver publishes it (waits for the latest label)."""
        assert self.until(lambda: self.active and self.active[-1] == self.node._active)
        return self.active[-1]


@pytest.fixture
def rig(context, executor, spin) -> Rig:
    r = Rig(context, executor, spin)
    r.set_time(T0)
    return r


def test_nothing_drives_before_any_command(rig):
    assert rig.driving() == 'none'


def test_autonomy_drives_alone(rig):
    rig.send('autonomy', AUTONOMY)
    assert rig.driving() == 'autonomy'
    assert np.allclose(rig.goals[-1], AUTONOMY)


def test_the_station_takes_over_and_autonomy_returns_after_its_timeout(rig):
    rig.send('autonomy', AUTONOMY)
    rig.set_time(T0 + 100 * MS)
    rig.send('station', STATION)
    assert rig.driving() == 'station'
    assert np.allclose(rig.goals[-1], STATION)
    t_station = rig.ns
    # The station falls silent; autonomy keeps sending every 50 ms and is not executed
    # until the station's timeout has passed (inclusive, as the gate holds a goal).
    t = t_station
    while t + 50 * MS <= t_station + STATION_TIMEOUT_NS:
        t += 50 * MS
        rig.set_time(t)
        rig.send('autonomy', AUTONOMY)
        assert rig.driving() == 'station', t - t_station
        assert np.allclose(rig.goals[-1], STATION)
    rig.set_time(t_station + STATION_TIMEOUT_NS + 50 * MS)
    rig.send('autonomy', AUTONOMY)
    assert rig.driving() == 'autonomy'
    assert np.allclose(rig.goals[-1], AUTONOMY)
    # The station comes back: it drives again at once.
    rig.send('station', STATION)
    assert rig.driving() == 'station'
    assert np.allclose(rig.goals[-1], STATION)


def test_all_silent_falls_to_the_zero_failsafe(rig):
    rig.send('autonomy', AUTONOMY)
    rig.set_time(T0 + 600 * MS)  # past autonomy's 0.5 s
    rig.node._publish_goal()
    assert rig.driving() == 'none'
    assert not np.any(rig.goals[-1]) and rig.node._failsafe


def test_the_station_stop_wins_while_autonomy_publishes(rig):
    rig.send('autonomy', AUTONOMY)
    assert rig.driving() == 'autonomy'
    rig.stop(True)
    assert rig.driving() == 'stop'
    assert not np.any(rig.goals[-1])
    for k in range(1, 4):
        rig.set_time(T0 + k * 50 * MS)
        rig.send('autonomy', AUTONOMY)
        rig.send('station', STATION)  # not even the station drives through its own stop
        assert not np.any(rig.goals[-1]) and rig.driving() == 'stop'
    rig.stop(False)
    rig.set_time(T0 + 160 * MS)
    rig.send('autonomy', AUTONOMY)
    rig.node._publish_goal()
    assert rig.driving() == 'station'  # sent 10 ms ago, live again
    assert np.allclose(rig.goals[-1], STATION)


def test_a_second_autonomy_publisher_is_refused_while_the_station_drives(rig, context,
                                                                          executor):
    rig.send('station', STATION)
    intruder = probe(context, executor, 'intruder')
    other = intruder.create_publisher(TwistStamped, AUTONOMY_TOPIC, topics.SURFACE_TWIST.qos)
    assert rig.until(lambda: rig.node.source_guards['autonomy']._sub.get_publisher_count() == 2)
    rig.set_time(T0 + 50 * MS)
    rig.send('autonomy', AUTONOMY, Verdict.CONTESTED)
    rig.send('autonomy', [-0.5, 0, 0, 0, 0, 0], Verdict.CONTESTED, pub=other)
    rig.send('station', STATION)
    assert rig.driving() == 'station'
    assert np.allclose(rig.goals[-1], STATION)
    assert rig.node.gates['autonomy'].counts[Verdict.ACCEPTED] == 0
    # Station silent past its timeout: the contested autonomy does not take over.
    rig.set_time(T0 + 50 * MS + STATION_TIMEOUT_NS + MS)
    rig.send('autonomy', AUTONOMY, Verdict.CONTESTED)
    assert rig.driving() == 'none'
    assert not np.any(rig.goals[-1])
    reports: list[tuple[Any, ...]] = []
    rig.node.publish_diagnostics = lambda *a: reports.append(a)
    rig.node._report()
    level, message, values = reports[-1]
    assert level == 2 and '/intruder' in message and '/autonomy' in message, message
    assert values['active_source'] == 'none' and values['contested'] == 3


def test_the_active_source_is_in_diagnostics(rig):
    rig.send('autonomy', AUTONOMY)
    reports: list[tuple[Any, ...]] = []
    rig.node.publish_diagnostics = lambda *a: reports.append(a)
    rig.node._report()
    assert reports[-1][2]['active_source'] == 'autonomy'


def test_without_sources_there_is_no_active_source_topic(context, executor):
    node = add(executor, CommandReceiverNode(node_name='command_receiver', context=context))
    assert node.arbiter is None and node.twist_guard is not None
    assert node.count_subscribers(topics.SURFACE_STOP.name) == 0
    assert node.count_publishers(topics.SURFACE_ACTIVE_SOURCE.name) == 0


@pytest.mark.parametrize('override, field', [
    (Parameter('sources.priorities', value=[3, 3]), 'sources.priorities[1]'),
    (Parameter('sources.timeouts', value=[0.3]), 'sources.timeouts'),
    (Parameter('sources.topics', value=[STATION_TOPIC, STATION_TOPIC]), 'sources.topics[1]'),
])
def test_a_bad_source_configuration_is_refused_naming_the_field(context, override, field):
    overrides = [p for p in SOURCES if p.name != override.name] + [override]
    with pytest.raises(ConfigurationError, match=field.replace('[', r'\[')):
        CommandReceiverNode(node_name='command_receiver', context=context,
                            parameter_overrides=overrides)


def test_a_second_publisher_on_the_driving_source_stops_it_at_once(rig, context, executor):
    rig.send('autonomy', AUTONOMY)
    assert rig.driving() == 'autonomy'
    intruder = probe(context, executor, 'intruder')
    intruder.create_publisher(TwistStamped, AUTONOMY_TOPIC, topics.SURFACE_TWIST.qos)
    assert rig.until(lambda: rig.node.source_guards['autonomy']._sub.get_publisher_count() == 2)
    rig.set_time(T0 + 50 * MS)  # well within autonomy's 0.5 s
    rig.send('autonomy', AUTONOMY, Verdict.CONTESTED)
    assert rig.driving() == 'none'
    assert not np.any(rig.goals[-1])


def test_the_profile_example_of_the_docs_configures_the_sources(context, executor, tmp_path):
    """The YAML of docs/profiles.md (Command sources), included beside the simulated ROV,
    reaches the node as its dotted parameters."""
    from pathlib import Path

    from enbarr_core.bringup.profile import load_profile
    docs = (Path(__file__).parents[2] / 'docs' / 'profiles.md').read_text(encoding='utf-8')
    example = docs.split('### Command sources', 1)[1].split('```yaml\n', 1)[1].split('```')[0]
    path = tmp_path / 'rov_autonomy.yaml'
    path.write_text('include: [enbarr_sim]\n' + example, encoding='utf-8')
    values = load_profile(str(path)).node('command_receiver').parameters
    node = add(executor, CommandReceiverNode(
        node_name='command_receiver', context=context,
        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]))
    assert node.arbiter is not None
    assert [(s.name, s.topic, s.priority, s.timeout) for s in node.arbiter.settings.sources] \
        == [('station', 'surface_command/twist', 10, 0.5), ('autonomy', 'autonomy/twist', 1, 1.0)]


def test_with_two_stop_publishers_a_stop_is_taken_and_a_release_is_not(rig, context,
                                                                        executor):
    rig.send('autonomy', AUTONOMY)
    intruder = probe(context, executor, 'intruder')
    intruder.create_publisher(Bool, topics.SURFACE_STOP.name, topics.SURFACE_STOP.qos)
    assert rig.until(lambda: rig.node.stop_guard._sub.get_publisher_count() == 2)
    rig.stop(True)
    assert rig.driving() == 'stop'
    refused = rig.node.stop_guard.contested_count
    rig.stop_pub.publish(Bool(data=False))
    assert rig.until(lambda: rig.node.stop_guard.contested_count == refused + 1)
    assert rig.node.arbiter.stopped and rig.driving() == 'stop'
