"""The orchestrator's pieces that a profile run relies on: the exit order and the list of
declared parameters that profile errors quote.
"""

from __future__ import annotations

from enbarr_core.bringup.orchestrator import declared_parameters, shutdown_nodes
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.recording.recorder import Recorder
from support.nodes import add


class Plain:
    """Stands in for a node that is neither an EnbarrNode nor a recorder."""

    def __init__(self, name: str, destroyed: list[str]) -> None:
        self.name, self.destroyed = name, destroyed

    def get_name(self) -> str:
        return self.name

    def destroy_node(self) -> None:
        self.destroyed.append(self.name)


class FakeRecorder(Plain, Recorder):
    def close(self) -> None:
        pass


def test_recorders_are_destroyed_after_every_other_node() -> None:
    destroyed: list[str] = []
    nodes = [FakeRecorder('recorder', destroyed), Plain('imu', destroyed),
             Plain('thrusters', destroyed)]
    shutdown_nodes(nodes)
    assert destroyed == ['imu', 'thrusters', 'recorder']


class FakeEmulator(Plain):
    device_emulator = True


def test_emulators_go_after_the_drivers_and_before_the_recorders() -> None:
    destroyed: list[str] = []
    nodes = [FakeEmulator('imu_emulator', destroyed), FakeRecorder('recorder', destroyed),
             Plain('imu', destroyed), Plain('thrusters', destroyed)]
    shutdown_nodes(nodes)
    assert destroyed == ['imu', 'thrusters', 'imu_emulator', 'recorder']


def test_emulators_are_built_before_the_drivers(monkeypatch) -> None:
    """A driver opens its device when built: its emulator must be registered by then."""
    from enbarr_core.bringup import orchestrator
    from enbarr_core.bringup.profile import NodeSpec
    built: list[str] = []
    kinds = {'drv': Plain, 'emu': FakeEmulator}
    monkeypatch.setattr(orchestrator.registry, 'resolve', lambda plugin: kinds[plugin])
    monkeypatch.setattr(orchestrator, '_construct',
                        lambda profile, spec, context: built.append(spec.name) or spec.name)
    monkeypatch.setattr(orchestrator, '_check_parameters', lambda *a: None)

    class Prof:
        nodes = [NodeSpec(name='imu', plugin='drv'), NodeSpec(name='imu_emulator', plugin='emu'),
                 NodeSpec(name='pwm', plugin='drv'), NodeSpec(name='pwm_emulator', plugin='emu')]
    assert orchestrator.build_nodes(Prof(), None) == [
        'imu_emulator', 'pwm_emulator', 'imu', 'pwm']


def test_a_node_with_a_writer_is_not_taken_for_a_recorder() -> None:
    destroyed: list[str] = []
    lookalike = Plain('lookalike', destroyed)
    lookalike.writer = object()  # what the old duck-typed check looked for
    shutdown_nodes([lookalike, Plain('imu', destroyed)])
    assert destroyed == ['lookalike', 'imu']


def test_declared_parameters_lists_what_the_node_declared(context, executor) -> None:
    node = add(executor, EnbarrNode('n', context=context))
    node.declare_parameter('gain', 1.0)
    node.declare_parameter('limits.upper', 2.0)
    names = declared_parameters(node)
    assert {'gain', 'limits.upper', 'use_sim_time'} <= set(names)


# -- VesselGuard: how two runs that missed each other at start agree (issue 8) -----------------
import json  # noqa: E402
import logging  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import pytest  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from enbarr_core.bringup.orchestrator import DuplicateVesselError, VesselGuard  # noqa: E402


@pytest.fixture
def guard(context, executor) -> VesselGuard:
    nodes = [add(executor, EnbarrNode(n, context=context)) for n in ('imu', 'control_loop')]
    g = VesselGuard(SimpleNamespace(nodes=nodes))
    g.check_start(wait=0.0)  # claims; nothing else runs in this private domain
    return g


def claim(g: VesselGuard, dt_ns: int, nodes=('/imu',), pid: int = 1, host: str = 'other'):
    return String(data=json.dumps({'nodes': list(nodes), 'host': host, 'pid': pid,
                                   'started_ns': g.started_ns + dt_ns}))


def test_an_earlier_claim_on_our_names_stops_this_run(guard: VesselGuard) -> None:
    with pytest.raises(DuplicateVesselError) as info:
        guard._on_claim(claim(guard, -1))
    assert info.value.started and 'started first' in str(info.value)
    assert '/imu' in str(info.value)


def test_a_later_claim_is_warned_about_once(guard: VesselGuard, caplog) -> None:
    with caplog.at_level(logging.WARNING, 'enbarr.bringup'):
        guard._on_claim(claim(guard, +1))
        guard._on_claim(claim(guard, +1))
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and 'must stop' in warned[0], warned


def test_equal_start_times_are_ordered_by_host_then_pid(guard: VesselGuard) -> None:
    guard._on_claim(claim(guard, 0, host=guard.host, pid=guard.pid + 1))  # later: no stop
    with pytest.raises(DuplicateVesselError):
        guard._on_claim(claim(guard, 0, host=guard.host, pid=guard.pid - 1))


@pytest.mark.parametrize('msg', [
    'not json', '{}', json.dumps({'nodes': 5, 'host': 'h', 'pid': 1, 'started_ns': 0}),
    'x' * 100_000])
def test_garbage_on_the_claim_topic_is_ignored(guard: VesselGuard, msg: str) -> None:
    guard._on_claim(String(data=msg))


def test_claims_on_other_names_or_our_own_are_ignored(guard: VesselGuard) -> None:
    guard._on_claim(claim(guard, -1, nodes=('/thruster_control',)))  # a sibling group
    guard._on_claim(claim(guard, -1, host=guard.host, pid=guard.pid))  # our own claim


def test_the_claim_is_published_latched(guard: VesselGuard, context, executor, spin) -> None:
    got: list[str] = []
    from enbarr_core.bringup.orchestrator import CLAIM_QOS, CLAIM_TOPIC
    late = add(executor, EnbarrNode('late', context=context))
    late.create_subscription(String, CLAIM_TOPIC, lambda m: got.append(m.data), CLAIM_QOS)
    assert spin(executor, lambda: bool(got))
    assert json.loads(got[0])['nodes'] == ['/control_loop', '/imu']
