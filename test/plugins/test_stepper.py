"""Node tests: the step/dir stepper through gpiozero's MockFactory: pulse counts, direction,
enable, addressing, refusals, the safe state and a failing pin."""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.parameter import Parameter
from support.devices import MockFactories, pass_time
from support.nodes import TIMEOUT, add
from support.rov import io_msg, io_probe, overrides

from enbarr_core.framework.errors import ConfigurationError
from enbarr_plugins.io.stepper import StepperNode

STEP, DIR, ENABLE = 18, 23, 24


def rising_edges(pin: Any) -> int:
    states = [s.state for s in pin.states]
    return sum(1 for a, b in zip(states, states[1:]) if b and not a)


def stepper(context: Any, executor: Any) -> StepperNode:
    return add(executor, StepperNode(context=context, parameter_overrides=overrides({
        'executor': 'manipulator', 'pin_factory': 'mock', 'max_rate': 2000.0,
        'min_position': -100, 'max_position': 500, 'reconnect.initial_delay': 0.05,
        'reconnect.max_delay': 0.1})))


@pytest.fixture
def rig(context, executor):
    node = stepper(context, executor)
    node.start()
    pub, states = io_probe(context, executor)
    return node, pub, states


def pin(node: StepperNode, number: int) -> Any:
    return node.factory.pin(number)


def test_a_constructed_node_claims_no_pin_until_started(context, executor, spin,
                                                        monkeypatch):
    factories = MockFactories(monkeypatch)
    node = stepper(context, executor)
    pub, states = io_probe(context, executor)
    pass_time(executor, spin, node)
    assert factories.made == [] and node.factory is None and not node.connected
    pub.publish(io_msg('manipulator', 10))       # refused: nothing to step with yet
    assert node.refused == 1 and states == [] and node.faults == 0
    node.start()
    assert sorted(p.info.name for p in factories.pins()) == ['GPIO18', 'GPIO23', 'GPIO24']
    assert pin(node, ENABLE).state is True and rising_edges(pin(node, STEP)) == 0


def test_steps_counts_pulses_with_direction_and_enable(executor, spin, rig):
    node, pub, states = rig
    assert node.connected and pin(node, ENABLE).state is True   # active low: disabled
    pub.publish(io_msg('manipulator', 40))
    assert spin(executor, lambda: node.position == 40, TIMEOUT)
    assert rising_edges(pin(node, STEP)) == 40 and pin(node, DIR).state is True
    assert pin(node, ENABLE).state is False                     # enabled (low) while holding
    assert spin(executor, lambda: states and states[-1] == ('manipulator', 40), TIMEOUT)
    pub.publish(io_msg('manipulator', -50))
    assert spin(executor, lambda: node.position == -10, TIMEOUT)
    assert rising_edges(pin(node, STEP)) == 90 and pin(node, DIR).state is False
    assert node.steps == 90


def test_requests_do_not_block_the_caller(rig):
    node, pub, _ = rig
    node.set_parameters([Parameter('max_rate', value=50.0)])
    pub.publish(io_msg('manipulator', 400))    # 8 s of steps at 50 steps/s
    assert node.target == 400 and node.position < 400   # returned before the move ended
    node.safe_state()


def test_acts_only_on_its_executor_and_refuses_bad_requests(executor, spin, rig):
    node, pub, states = rig
    pub.publish(io_msg('gpio_12', 10))          # another executor
    pub.publish(io_msg('manipulator', True))    # a bool is not steps
    pub.publish(io_msg('manipulator', 2.5))
    pub.publish(io_msg('manipulator', 501))     # beyond the end stop
    assert node.refused == 3 and node.target == 0 and node.handled == 0
    assert rising_edges(pin(node, STEP)) == 0


def test_safe_state_stops_and_disables(executor, spin, rig):
    node, pub, _ = rig
    node.set_parameters([Parameter('max_rate', value=100.0)])
    pub.publish(io_msg('manipulator', 400))
    assert spin(executor, lambda: node.position >= 5, TIMEOUT)
    node.safe_state()
    assert spin(executor, lambda: node.target == node.position, TIMEOUT)
    stopped = node.position
    edges = rising_edges(pin(node, STEP))
    assert stopped < 400 and pin(node, ENABLE).state is True   # disabled
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert node.position == stopped and rising_edges(pin(node, STEP)) == edges
    pub.publish(io_msg('manipulator', 3))       # a new request moves again
    assert spin(executor, lambda: node.position == stopped + 3, TIMEOUT)


def test_a_failing_pin_is_a_fault_then_it_resumes(executor, spin, rig):
    node, pub, _ = rig

    def broken(value: bool) -> None:
        raise OSError(5, 'Input/output error')
    pin(node, STEP)._set_state = broken
    pub.publish(io_msg('manipulator', 10))
    assert spin(executor, lambda: not node.connected, TIMEOUT)
    assert 'STEP18/DIR23/EN24 (mock): writing a pin failed at position 0' in node.last_fault
    assert spin(executor, lambda: node.connected, TIMEOUT)    # a new factory, good pins
    assert node.target == node.position == 0                  # the cut move is not resumed
    pub.publish(io_msg('manipulator', 10))
    assert spin(executor, lambda: node.position == 10, TIMEOUT)


def test_lgpio_without_a_gpio_chip_is_a_clear_device_error(context, executor):
    node = add(executor, StepperNode(context=context, parameter_overrides=overrides({})))
    node.start()
    assert not node.connected and 'pin_factory lgpio' in node.last_fault


def test_pins_must_differ(context):
    with pytest.raises(ConfigurationError, match='must differ'):
        StepperNode(context=context, parameter_overrides=overrides(
            {'pin_factory': 'mock', 'dir_pin': 18}))


def test_safe_state_in_the_middle_of_a_step_does_not_step_back(executor, spin, rig):
    node, pub, _ = rig
    step = pin(node, STEP)
    original = step._set_state
    calls = [0]

    def set_state(value: bool) -> None:      # safe_state lands while step 5 is being made
        if value:
            calls[0] += 1
            if calls[0] == 5:
                node.safe_state()
        original(value)
    step._set_state = set_state
    pub.publish(io_msg('manipulator', 100))
    assert spin(executor, lambda: calls[0] >= 5 and node.target == node.position, TIMEOUT)
    assert spin(executor, lambda: node.position == 5, TIMEOUT)
    assert rising_edges(step) == 5
    assert all(s.state for s in pin(node, DIR).states[1:])   # never reversed
