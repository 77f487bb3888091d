"""Node tests: scripted surface commands."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, add, probe

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.operator.scripted_commands import ScriptedCommandsNode


@pytest.fixture
def played(context, executor, spin):
    node = add(executor, ScriptedCommandsNode(context=context, parameter_overrides=[
        Parameter('script', value=['0.0 twist 0.1 0 0 0 0 0', '0.0 io gpio_12 true',
                                   '0.3 stop']),
        Parameter('rate', value=50.0)]))
    p = probe(context, executor, 'receiver')
    twists: list[np.ndarray] = []
    ios: list[tuple[str, object]] = []
    p.create_topic_subscription(topics.SURFACE_TWIST,
                                lambda m: twists.append(convert.twist_to_nu(m.twist)))
    p.create_topic_subscription(
        topics.SURFACE_IO,
        lambda m: ios.append((m.name, convert.parameter_value_to_python(m.value))))
    LinkBus.of(context).connect()
    assert spin(executor, lambda: all(n.count_subscribers(t.name) for n, t in (
        (node, topics.SURFACE_TWIST), (node, topics.SURFACE_IO))), TIMEOUT)
    node.start()
    assert spin(executor, lambda: node.finished, TIMEOUT)
    return node, twists, ios


def test_nothing_is_sent_before_start(context, executor, spin):
    node = add(executor, ScriptedCommandsNode(context=context, parameter_overrides=[
        Parameter('script', value=['0.0 twist 0.1 0 0 0 0 0'])]))
    ticks = [0]
    node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 3, TIMEOUT)
    assert not node.finished and node._next == 0


def test_twist_steps_are_sent_until_stop(executor, spin, played):
    node, twists, _ = played
    assert spin(executor, lambda: len(twists) >= 2, TIMEOUT)
    assert all(np.allclose(t, [0.1, 0, 0, 0, 0, 0]) for t in twists)


def test_io_steps_are_sent_once(executor, spin, played):
    _, _, ios = played
    assert spin(executor, lambda: len(ios) >= 1, TIMEOUT)
    assert ios == [('gpio_12', True)]


def test_a_bad_line_is_a_configuration_error_naming_it(context):
    with pytest.raises(ConfigurationError, match=r"script\[1\] '2.0 twist 1 2': twist takes 6"):
        ScriptedCommandsNode(context=context, parameter_overrides=[
            Parameter('script', value=['0.0 stop', '2.0 twist 1 2'])])
