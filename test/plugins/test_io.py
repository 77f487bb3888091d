"""Node tests: io."""

from __future__ import annotations

import pytest
from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, add
from support.rov import io_probe, io_msg

from enbarr_core.framework.errors import ConfigurationError
from enbarr_plugins.io.sim_gpio import SimGpioNode
from enbarr_plugins.io.sim_stepper import SimStepperNode

# -- GPIO ------------------------------------------------------------------------------------


@pytest.fixture
def gpio(context, executor):
    node = add(executor, SimGpioNode(node_name='lights', context=context,
                                     parameter_overrides=[Parameter('pin', value=12)]))
    node.start()
    pub, states = io_probe(context, executor)
    return node, pub, states


def test_gpio_executor_name_and_initial_level(gpio):
    node, _, _ = gpio
    assert node.executor_name == 'gpio_12' and node.level is False
    assert node.settings.pin == 12


def test_gpio_sets_its_pin_and_reports_it(gpio):
    node, pub, states = gpio
    pub.publish(io_msg('gpio_12', True))
    assert node.level is True and states == [('gpio_12', True)] and node.handled == 1
    pub.publish(io_msg('gpio_12', False))
    assert node.level is False and states[-1] == ('gpio_12', False) and node.handled == 2


def test_gpio_ignores_other_executors(gpio):
    node, pub, states = gpio
    pub.publish(io_msg('gpio_12', True))
    pub.publish(io_msg('gpio_13', False))      # another executor: ignored
    assert node.level is True and len(states) == 1 and node.handled == 1
    assert node.refused == 0


def test_gpio_refuses_what_is_not_a_bool(gpio):
    node, pub, states = gpio
    pub.publish(io_msg('gpio_12', True))
    pub.publish(io_msg('gpio_12', 1))          # an int is not a level: refused
    assert node.refused == 1 and node.level is True and len(states) == 1
    pub.publish(io_msg('gpio_12', 'on'))
    assert node.refused == 2 and len(states) == 1


# -- stepper ---------------------------------------------------------------------------------

@pytest.fixture
def stepper(context, executor):
    node = add(executor, SimStepperNode(node_name='manipulator', context=context,
                                        parameter_overrides=[
                                            Parameter('executor', value='manipulator'),
                                            Parameter('max_rate', value=400.0),
                                            Parameter('max_position', value=500)]))
    node.start()
    pub, states = io_probe(context, executor)
    assert node.executor_name == 'manipulator'
    return node, pub, states


def moved_to(spin, executor, node, pub, states, steps: int, position: int) -> None:
    pub.publish(io_msg('manipulator', steps))
    assert node.target == position
    assert spin(executor, lambda: states and states[-1] == ('manipulator', position), TIMEOUT)


def test_stepper_moves_to_its_target_at_its_rate(executor, spin, stepper):
    node, pub, states = stepper
    moved_to(spin, executor, node, pub, states, 120, 120)
    assert node.handled == 1
    assert all(name == 'manipulator' for name, _ in states)
    positions = [v for _, v in states]
    assert positions == sorted(positions) and len(positions) > 1  # moved, not jumped
    assert node.position == 120.0


def test_stepper_moves_relative_to_its_target(executor, spin, stepper):
    node, pub, states = stepper
    moved_to(spin, executor, node, pub, states, 120, 120)
    n = len(states)
    moved_to(spin, executor, node, pub, states, -20, 100)
    assert len(states) > n


def test_stepper_refuses_a_bool(stepper):
    node, pub, _ = stepper
    pub.publish(io_msg('manipulator', True))   # a bool is not a step count
    assert node.refused == 1 and node.target == 0


def test_stepper_refuses_a_target_beyond_its_end_stop(stepper):
    node, pub, _ = stepper
    pub.publish(io_msg('manipulator', 120))
    pub.publish(io_msg('manipulator', 400))    # 520 > max_position 500
    assert node.refused == 1 and node.target == 120


def test_stepper_ignores_other_executors(stepper):
    node, pub, _ = stepper
    pub.publish(io_msg('gpio_12', 10))         # another executor
    assert node.refused == 0 and node.target == 0 and node.handled == 0


def test_stepper_reports_only_while_it_moves(executor, spin, stepper):
    node, pub, states = stepper
    moved_to(spin, executor, node, pub, states, 120, 120)
    # Nothing moves any more: io_state only while the position changes.
    n = len(states)
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert len(states) == n


def test_stepper_at_rest_costs_no_timer_and_moves_again_when_asked(executor, spin, stepper):
    node, pub, states = stepper
    moves = [0]
    move = node._move

    def counted():
        moves[0] += 1
        move()
    node._mover.callback = counted
    assert node._mover.is_canceled()                  # at rest from the start: no wake-ups
    moved_to(spin, executor, node, pub, states, 40, 40)
    assert spin(executor, node._mover.is_canceled, TIMEOUT)
    at_rest = moves[0]
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert moves[0] == at_rest                        # nothing woke it at rest
    moved_to(spin, executor, node, pub, states, -40, 0)  # and a new move resumes it


def test_stepper_move_asked_while_it_comes_to_rest_is_not_lost(stepper):
    node, _, _ = stepper
    node._mover.reset()                               # moving, and now at its target
    real_cancel = node._mover.cancel

    def cancel_then_request():
        real_cancel()
        node.target = 9         # a request from another thread lands between the two
    node._mover.cancel = cancel_then_request
    node._move()
    assert not node._mover.is_canceled()              # the re-check restarted it


def test_stepper_end_stops_must_be_ordered(context):
    with pytest.raises(ConfigurationError, match='min_position must not exceed max_position'):
        SimStepperNode(context=context, parameter_overrides=[
            Parameter('min_position', value=10), Parameter('max_position', value=0)])
