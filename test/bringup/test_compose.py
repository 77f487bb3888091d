"""Composition's pieces that a profile run relies on: the exit order, the build order and the
list of declared parameters that profile errors quote.
"""

from __future__ import annotations

from enbarr_core.bringup.compose import declared_parameters, shutdown_nodes
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
    """A driver opens its device at start, in build order: its emulator must be started by
    then."""
    from enbarr_core.bringup import compose
    from enbarr_core.bringup.profile import NodeSpec
    built: list[str] = []
    kinds = {'drv': Plain, 'emu': FakeEmulator}
    monkeypatch.setattr(compose.registry, 'resolve', lambda plugin: kinds[plugin])
    monkeypatch.setattr(compose, '_construct',
                        lambda profile, spec, context: built.append(spec.name) or spec.name)
    monkeypatch.setattr(compose, '_check_parameters', lambda *a: None)

    class Prof:
        nodes = [NodeSpec(name='imu', plugin='drv'), NodeSpec(name='imu_emulator', plugin='emu'),
                 NodeSpec(name='pwm', plugin='drv'), NodeSpec(name='pwm_emulator', plugin='emu')]
    assert compose.build_nodes(Prof(), None) == [
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
