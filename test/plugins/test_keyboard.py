"""Keyboard teleoperation: the key rules (pure) and the node reading a real pseudo-terminal."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.node import Node
from rclpy.parameter import Parameter

from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_plugins.operator.keyboard import KeyboardTeleopNode, KeyState, apply_key


def test_keys_step_and_saturate():
    s = KeyState()
    for _ in range(20):
        s, io = apply_key(s, 'w', 0.05, 0.1, 0.5, 0.5)
        assert io is None
    assert s.nu[0] == 0.5  # saturated at max_linear
    s, _ = apply_key(s, 'e', 0.05, 0.1, 0.5, 0.5)
    s, _ = apply_key(s, 'f', 0.05, 0.1, 0.5, 0.5)
    assert s.nu == (0.5, 0.0, -0.05, 0.0, 0.0, -0.1)
    s, _ = apply_key(s, 'x', 0.05, 0.1, 0.5, 0.5)  # unknown: nothing
    assert s.nu == (0.5, 0.0, -0.05, 0.0, 0.0, -0.1)
    s, _ = apply_key(s, ' ', 0.05, 0.1, 0.5, 0.5)
    assert s.nu == (0.0,) * 6
    s, io = apply_key(s, 'l', 0.05, 0.1, 0.5, 0.5)
    assert s.lights and io == ('lights', True)
    s, io = apply_key(s, 'l', 0.05, 0.1, 0.5, 0.5)
    assert not s.lights and io == ('lights', False)
    assert apply_key(s, 'n', 0.05, 0.1, 0.5, 0.5)[1] == ('manipulator', -1)


def test_node_reads_a_terminal(context, executor, spin):
    master, slave = os.openpty()
    try:
        node = KeyboardTeleopNode(node_name='keyboard', context=context, parameter_overrides=[
            Parameter('device', value=os.ttyname(slave))])
        executor.add_node(node)
        probe = Node('probe', context=context)
        executor.add_node(probe)
        twists: list[list[float]] = []
        ios: list[tuple[str, object]] = []
        probe.create_subscription(TwistStamped, topics.SURFACE_TWIST.name,
                                  lambda m: twists.append(list(convert.twist_to_nu(m.twist))),
                                  topics.SURFACE_TWIST.qos)
        probe.create_subscription(ParameterMsg, topics.SURFACE_IO.name, lambda m: ios.append(
            (m.name, convert.parameter_value_to_python(m.value))), topics.SURFACE_IO.qos)
        node.start()
        os.write(master, b'ww')
        assert spin(executor, lambda: twists and twists[-1][0] == pytest.approx(0.1), 10.0)
        os.write(master, b'lm')
        assert spin(executor, lambda: ('gpio_12', True) in ios and ('manipulator', 50) in ios,
                    10.0)
        os.write(master, b' ')
        assert spin(executor, lambda: twists[-1] == [0.0] * 6, 10.0)
        os.close(master)  # the terminal goes away: the node stops sending
        master = -1
        assert spin(executor, lambda: node._stop.is_set(), 10.0)
    finally:
        if master >= 0:
            os.close(master)
        os.close(slave)


def test_not_a_terminal_is_a_clear_error(context):
    with pytest.raises(ConfigurationError, match='/dev/null is not a terminal'):
        KeyboardTeleopNode(node_name='keyboard', context=context, parameter_overrides=[
            Parameter('device', value='/dev/null')])


@pytest.mark.e2e  # the command line, in a process
def test_teleop_profile_without_a_terminal_is_refused():
    proc = subprocess.run([sys.executable, '-m', 'enbarr_core.bringup.cli', 'bringup', '--profile',
                           'enbarr_teleop', '--check'], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert 'nodes.keyboard' in proc.stderr and 'is not a terminal' in proc.stderr
