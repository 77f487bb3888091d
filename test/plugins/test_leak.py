"""Unit and node tests: the leak detector's debounce and latch, and the ``leak_gpio`` driver
on gpiozero's MockFactory (the test drives the pin as a wet or dry SOS sensor would)."""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.parameter import Parameter
from std_msgs.msg import Bool
from support.devices import diagnostics_of, pass_time
from support.nodes import add, probe, TIMEOUT
from support.rov import overrides

from enbarr_core.framework.driver import ERROR, OK
from enbarr_interfaces import topics
from enbarr_plugins.io.leak import LeakGpioNode, LeakLatch

PIN = 27


# -- the latch (pure) ------------------------------------------------------------------------
@pytest.mark.unit
def test_a_wet_glitch_shorter_than_the_debounce_is_not_a_leak():
    latch = LeakLatch(debounce=0.5, dry_hold=10.0)
    assert latch.update(True, 0.0) is False
    assert latch.update(True, 0.4) is False
    assert latch.update(False, 0.45) is False     # the glitch ends before 0.5 s
    assert latch.update(True, 1.0) is False       # a new run starts from here
    assert latch.update(True, 1.49) is False
    assert latch.leaks == 0


@pytest.mark.unit
def test_wet_for_the_debounce_is_a_leak_that_stays_until_dry_for_the_hold():
    latch = LeakLatch(debounce=0.5, dry_hold=10.0)
    latch.update(True, 0.0)
    assert latch.update(True, 0.5) is True and latch.leaks == 1
    assert latch.update(False, 1.0) is True       # dry: still latched
    assert latch.update(False, 10.9) is True
    assert latch.update(True, 11.0) is True       # a drip restarts the dry hold
    assert latch.update(False, 12.0) is True
    assert latch.update(False, 21.9) is True
    assert latch.update(False, 22.0) is False     # dry for 10 s: cleared
    assert latch.leaks == 1


@pytest.mark.unit
def test_zero_debounce_declares_on_the_first_wet_reading():
    latch = LeakLatch(debounce=0.0, dry_hold=0.0)
    assert latch.update(True, 5.0) is True
    assert latch.update(False, 5.1) is False


# -- the driver ------------------------------------------------------------------------------
def leak_node(context: Any, executor: Any, **extra: Any) -> LeakGpioNode:
    node = add(executor, LeakGpioNode(context=context, parameter_overrides=overrides(
        {'pin': PIN, 'pin_factory': 'mock', 'debounce': 0.5, 'dry_hold': 5.0, **extra})))
    node.start()
    return node


def listen(context: Any, executor: Any) -> list[bool]:
    got: list[bool] = []
    p = probe(context, executor)
    p.create_subscription(Bool, topics.LEAK.name, lambda m: got.append(m.data),
                          topics.LEAK.qos)
    return got


@pytest.mark.node
def test_dry_wet_latched_cleared_on_the_topic(context, executor, spin):
    node = leak_node(context, executor)
    pin = node.factory.pin(PIN)
    got = listen(context, executor)
    node.poll(0.0)                                  # dry (pulled down)
    assert spin(executor, lambda: got == [False], TIMEOUT)
    pin.drive_high()                                # wet
    node.poll(1.0)
    node.poll(1.3)                                  # wet 0.3 s < debounce
    assert node.latch.leak is False and node.wet is True
    pin.drive_low()
    node.poll(1.4)                                  # the glitch is over
    pin.drive_high()
    node.poll(2.0)
    node.poll(2.5)                                  # wet 0.5 s: leak
    assert spin(executor, lambda: got == [False, True], TIMEOUT)
    pin.drive_low()
    node.poll(3.0)
    node.poll(7.9)                                  # dry 4.9 s < dry_hold: still a leak
    assert node.latch.leak is True and node.status() == (ERROR, f'LEAK at GPIO{PIN} (mock)')
    node.poll(8.0)                                  # dry 5 s: cleared
    assert spin(executor, lambda: got == [False, True, False], TIMEOUT)
    assert node.status()[0] == OK and node.latch.leaks == 1


@pytest.mark.node
def test_active_low_sensor_with_pull_up(context, executor, spin):
    node = leak_node(context, executor, active_high=False, pull='up', debounce=0.0)
    pin = node.factory.pin(PIN)
    got = listen(context, executor)
    node.poll(0.0)                                  # pulled up: dry
    assert node.wet is False
    pin.drive_low()
    node.poll(0.1)
    assert spin(executor, lambda: got[-1:] == [True], TIMEOUT)


@pytest.mark.node
def test_a_late_subscriber_learns_the_leak_and_diagnostics_name_the_pin(context, executor,
                                                                       spin):
    node = leak_node(context, executor, debounce=0.0)
    node.factory.pin(PIN).drive_high()
    node.poll(0.0)
    got = listen(context, executor)                 # joins after the leak was published
    assert spin(executor, lambda: got == [True], TIMEOUT)
    statuses = diagnostics_of(probe(context, executor, 'diag'), node.get_name())
    assert spin(executor, lambda: any(s.level == bytes([ERROR]) for s in statuses), TIMEOUT)
    status = next(s for s in statuses if s.level == bytes([ERROR]))
    assert f'GPIO{PIN}' in status.message and 'LEAK' in status.message


@pytest.mark.node
def test_a_failing_pin_is_a_fault_and_the_leak_stays_latched(context, executor, spin):
    node = leak_node(context, executor, debounce=0.0, **{'reconnect.initial_delay': 0.05,
                                                          'reconnect.max_delay': 0.1})
    pin = node.factory.pin(PIN)
    pin.drive_high()
    node.poll(0.0)
    assert node.latch.leak

    def broken() -> bool:
        raise OSError(5, 'Input/output error')
    pin._get_state = broken                      # the pin dies (this factory only)
    node.poll(0.1)
    assert not node.connected and node.faults == 1
    assert 'GPIO27 (mock): reading the pin failed' in node.last_fault
    level, message = node.status()
    assert level == ERROR and message.startswith(f'LEAK at GPIO{PIN} (mock); device fault')
    assert spin(executor, lambda: node.connected, TIMEOUT)   # a new factory: a good pin
    node.poll(0.2)                               # it reads dry, but not for dry_hold yet
    assert node.latch.leak and node.wet is False


@pytest.mark.node
def test_a_bad_pull_is_refused_naming_the_parameter(context):
    from enbarr_core.framework.errors import ConfigurationError
    with pytest.raises(ConfigurationError, match='pull'):
        LeakGpioNode(context=context, parameter_overrides=overrides(
            {'pin_factory': 'mock', 'pull': 'sideways'}))


# -- the simulated twin ----------------------------------------------------------------------
@pytest.mark.node
def test_the_twin_floods_at_leak_at_and_stays_flooded(context, executor, spin):
    import time

    from enbarr_core.framework.node import install_world, WorldOf
    from enbarr_plugins.io.sim_leak import SimLeakNode
    install_world(context, WorldOf.of(context).world, epoch_ns=time.time_ns())  # world time 0
    got = listen(context, executor)
    now = add(executor, SimLeakNode('now', context=context, parameter_overrides=overrides(
        {'leak_at': 0.0})))
    now.start()
    assert spin(executor, lambda: True in got, TIMEOUT)
    assert now.leak
    now.set_parameters([Parameter('leak_at', value=-1.0)])   # latched: it stays flooded
    pass_time(executor, spin, now, 0.3)
    assert now.leak and got.count(True) == 1


@pytest.mark.node
def test_the_twin_stays_dry_before_leak_at(context, executor, spin):
    import time

    from enbarr_core.framework.node import install_world, WorldOf
    from enbarr_plugins.io.sim_leak import SimLeakNode
    install_world(context, WorldOf.of(context).world, epoch_ns=time.time_ns())
    got = listen(context, executor)
    later = add(executor, SimLeakNode('later', context=context, parameter_overrides=overrides(
        {'leak_at': 1e6})))
    later.start()
    assert spin(executor, lambda: got == [False], TIMEOUT)
    pass_time(executor, spin, later, 0.3)
    assert got == [False] and not later.leak
