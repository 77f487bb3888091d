"""The per-process registry through which a driver's ``emulated`` device value finds its
emulator, and the ``check-device`` table (every kind names a function that exists)."""

from __future__ import annotations

import pytest

from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_plugins import check, emulation


@pytest.fixture(autouse=True)
def _clean() -> None:
    yield
    for kind, name in list(emulation._endpoints):
        if name.startswith('test_'):
            emulation.unregister(kind, name)


def test_is_emulated() -> None:
    assert emulation.is_emulated('emulated')
    assert emulation.is_emulated('emulated:bow')
    assert not emulation.is_emulated('/dev/ttyUSB0')
    assert not emulation.is_emulated('emulatedx')
    assert not emulation.is_emulated(1)
    assert emulation.emulator_name('emulated') == 'default'
    assert emulation.emulator_name('emulated:bow') == 'bow'


def test_lookup_finds_what_was_registered() -> None:
    emulation.register('serial', 'test_lidar', '/dev/pts/7')
    assert emulation.lookup('serial', 'emulated:test_lidar') == '/dev/pts/7'


def test_missing_emulator_is_a_device_error_naming_it() -> None:
    emulation.register('serial', 'test_arduino', '/dev/pts/3')
    with pytest.raises(DeviceError, match=r"emulated:test_lidar: no serial emulator named "
                       r"'test_lidar'.*known: .*test_arduino.*same profile group"):
        emulation.lookup('serial', 'emulated:test_lidar')


def test_unregister_leaves_a_newer_endpoint() -> None:
    old, new = object(), object()
    emulation.register('tcp', 'test_qtm', old)
    emulation.register('tcp', 'test_qtm', new)  # a replugged emulator
    emulation.unregister('tcp', 'test_qtm', old)
    assert emulation.lookup('tcp', 'emulated:test_qtm') is new
    emulation.unregister('tcp', 'test_qtm')
    with pytest.raises(DeviceError):
        emulation.lookup('tcp', 'emulated:test_qtm')


def test_unknown_kind_refused() -> None:
    with pytest.raises(ValueError, match='kind: one of'):
        emulation.register('usb', 'test_x', object())


def test_get_or_create_shares_one_endpoint() -> None:
    made = []
    first = emulation.get_or_create('i2c', 'test_bus', lambda: made.append(1) or object())
    again = emulation.get_or_create('i2c', 'test_bus', lambda: made.append(1) or object())
    assert first is again and made == [1]


@pytest.mark.parametrize('kind', sorted(check.CHECKS))
def test_every_check_kind_has_its_function(kind: str) -> None:
    assert callable(check.checker(kind))


def test_two_emulators_cannot_share_a_kind_and_name() -> None:
    """Two serial emulators both named 'default' would hand both drivers one pty."""
    class Node:
        def __init__(self, name: str) -> None:
            self.name = name

        def get_name(self) -> str:
            return self.name

    arduino, lidar = Node('arduino_emulator'), Node('lidar_emulator')
    emulation.register('serial', 'test_default', '/dev/pts/1', owner=arduino)
    emulation.register('serial', 'test_default', '/dev/pts/2', owner=arduino)  # replugged
    with pytest.raises(ConfigurationError, match="node 'arduino_emulator' already emulates "
                       "the serial device 'test_default'.*give node 'lidar_emulator' another "
                       'name') as err:
        emulation.register('serial', 'test_default', '/dev/pts/3', owner=lidar)
    assert err.value.parameter == 'name'
    assert emulation.lookup('serial', 'emulated:test_default') == '/dev/pts/2'
    emulation.unregister('serial', 'test_default', '/dev/pts/2')      # unplugged: free again
    emulation.register('serial', 'test_default', '/dev/pts/3', owner=lidar)


class FakeEmulator:
    """An endpoint emulator that notes what was done to it."""

    built: list[FakeEmulator] = []

    def __init__(self) -> None:
        self.calls: list[str] = []
        FakeEmulator.built.append(self)

    def start(self) -> str:
        self.calls.append('start')
        return '/dev/pts/42'

    def stop(self) -> None:
        self.calls.append('stop')


def test_a_check_opens_the_device_itself_unless_emulated() -> None:
    FakeEmulator.built.clear()
    with check.device_endpoint('/dev/ttyUSB0', '/dev/ttyUSB0', FakeEmulator) as path:
        assert path == '/dev/ttyUSB0'
    assert FakeEmulator.built == []  # no emulator built for a real device


@pytest.mark.parametrize('value', ['emulated', 'emulated:bow'])
def test_an_emulated_check_starts_the_emulator_and_stops_it_even_on_failure(value: str) -> None:
    FakeEmulator.built.clear()
    with check.device_endpoint(value, value, FakeEmulator) as path:
        [emulator] = FakeEmulator.built
        assert path == '/dev/pts/42' and emulator.calls == ['start']
    assert emulator.calls == ['start', 'stop']
    with pytest.raises(DeviceError, match='no answer'):
        with check.device_endpoint(value, value, FakeEmulator):
            raise DeviceError('/dev/pts/42: no answer')
    assert FakeEmulator.built[-1].calls == ['start', 'stop']
