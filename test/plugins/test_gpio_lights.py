"""Node and unit tests: GPIO lights through gpiozero's MockFactory; the lgpio backend on a
machine without a GPIO chip; ``enbarr check-device gpio``."""

from __future__ import annotations

from typing import Any

import pytest
from support.devices import MockFactories, pass_time
from support.nodes import TIMEOUT, add
from support.rov import io_msg, io_probe

from enbarr_core.commands.main import main
from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.io import pins
from enbarr_plugins.io.check import check_gpio
from enbarr_plugins.io.gpio_lights import GpioLightsNode
from support.rov import overrides

FAST_RETRY = {'reconnect.initial_delay': 0.05, 'reconnect.max_delay': 0.1}


def lights(context: Any, executor: Any, start: bool = True, **extra: Any) -> GpioLightsNode:
    node = add(executor, GpioLightsNode(context=context, parameter_overrides=overrides(
        {'pin': 12, 'pin_factory': 'mock', **FAST_RETRY, **extra})))
    if start:
        node.start()
    return node


def level(node: GpioLightsNode) -> bool:
    return node.factory.pin(12).state


@pytest.fixture
def rig(context, executor):
    node = lights(context, executor)
    pub, states = io_probe(context, executor)
    return node, pub, states


def test_a_constructed_node_claims_no_pin_until_started(context, executor, spin,
                                                        monkeypatch):
    factories = MockFactories(monkeypatch)
    node = lights(context, executor, start=False, initial=True)
    pub, states = io_probe(context, executor)
    pass_time(executor, spin, node)
    assert factories.made == [] and node.factory is None and not node.connected
    assert states == [] and node.faults == 0
    node.start()
    assert len(factories.made) == 1 and [p.info.name for p in factories.pins()] == ['GPIO12']
    assert level(node) is True                     # the initial level, set when opened


def test_sets_the_pin_and_reports_the_level(rig):
    node, pub, states = rig
    assert node.connected and node.executor_name == 'gpio_12' and level(node) is False
    pub.publish(io_msg('gpio_12', True))
    assert level(node) is True and states == [('gpio_12', True)]
    pub.publish(io_msg('gpio_12', False))
    assert level(node) is False and states[-1] == ('gpio_12', False) and node.handled == 2
    assert [s.state for s in node.factory.pin(12).states] == [False, True, False]


def test_acts_only_on_its_executor_and_refuses_other_types(rig):
    node, pub, states = rig
    pub.publish(io_msg('gpio_13', True))        # another executor: ignored
    pub.publish(io_msg('manipulator', True))
    assert level(node) is False and states == [] and node.refused == 0
    pub.publish(io_msg('gpio_12', 1))           # an int is not a level
    pub.publish(io_msg('gpio_12', 'on'))
    assert node.refused == 2 and level(node) is False and states == []


def test_active_low_and_initial_level(context, executor):
    node = lights(context, executor, initial=True, active_high=False)
    assert node.factory.pin(12).state is False   # on = low
    node.act(False)
    assert node.factory.pin(12).state is True


def test_safe_state_holds_the_lights(rig):
    node, pub, _ = rig
    pub.publish(io_msg('gpio_12', True))
    node.safe_state()
    assert level(node) is True


def test_a_failing_pin_is_a_fault_and_the_level_comes_back(executor, spin, rig):
    node, pub, states = rig

    def broken(value: bool) -> None:
        raise OSError(5, 'Input/output error')
    node.factory.pin(12)._set_state = broken     # the pin dies (this factory only)
    pub.publish(io_msg('gpio_12', True))
    assert not node.connected and 'GPIO12 (mock): writing the pin failed' in node.last_fault
    assert states == []                          # the failed level is not reported as set
    assert spin(executor, lambda: node.connected, TIMEOUT)   # a new factory: a good pin
    assert level(node) is True                   # the level last asked for


def test_lgpio_without_a_gpio_chip_is_a_clear_device_error(context, executor):
    with pytest.raises(DeviceError, match='pin_factory lgpio'):
        pins.make_factory('lgpio')
    node = add(executor, GpioLightsNode(context=context, parameter_overrides=overrides(
        {'pin': 12, 'pin_factory': 'lgpio'})))
    node.start()
    assert not node.connected and 'GPIO12 (lgpio)' not in node.last_fault  # named by err
    assert 'pin_factory lgpio' in node.last_fault


def test_bad_pin_factory_names_the_parameter(context):
    with pytest.raises(ConfigurationError, match='pin_factory: one of lgpio, mock'):
        GpioLightsNode(context=context, parameter_overrides=overrides(
            {'pin_factory': 'rpigpio'}))


@pytest.mark.unit
def test_check_device_reads_a_mock_pin_and_fails_without_a_chip(capsys):
    lines = check_gpio(CheckTarget(device='emulated', name='12'))
    assert lines[1] == 'GPIO12: input, level low'
    with pytest.raises(DeviceError, match='pin_factory lgpio'):
        check_gpio(CheckTarget(name='12'))
    with pytest.raises(DeviceError, match='--name'):
        check_gpio(CheckTarget(device='emulated', name='pin12'))
    assert main(['check-device', 'gpio', '--device', 'emulated', '--name', '12']) == 0
    assert 'GPIO12: input, level low' in capsys.readouterr().out
    assert main(['check-device', 'gpio', '--name', '12']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'lgpio' in err[0]


@pytest.mark.unit
def test_a_pin_that_cannot_be_claimed_closes_the_others_and_names_the_device(monkeypatch):
    factories = MockFactories(monkeypatch)
    with pytest.raises(DeviceError, match=r'^STEP5/DIR5 \(mock\): cannot use the pins as '
                                          'outputs'):
        pins.open_outputs('mock', [pins.Output(5), pins.Output(5)], 'STEP5/DIR5 (mock)')
    assert len(factories.made) == 1 and factories.made[0].pins == {}   # released, closed
    factory, (a, none) = pins.open_outputs('mock', [pins.Output(6, initial=True),
                                                    pins.Output(-1)], 'GPIO6 (mock)')
    assert a.value == 1 and none is None and factory.pin(6).state is True
