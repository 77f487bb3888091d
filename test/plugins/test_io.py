"""Node tests: io."""

from __future__ import annotations

from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, add
from support.rov import _io_probe, io_msg

from enbarr_plugins.io.sim_gpio import SimGpioNode
from enbarr_plugins.io.sim_stepper import SimStepperNode


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
