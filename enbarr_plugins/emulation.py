"""Where a driver finds the emulator of its device when a profile runs with no hardware.

Every real driver names its device with one parameter (``bus`` for I2C, ``port`` for serial,
``host`` for the network, ``device`` for cameras and input devices). The value ``emulated``
(or ``emulated:NAME`` when a process runs more than one emulator of a kind) makes the driver
take the endpoint that an emulator node of this package registered in the same process: an
in-memory I2C bus behind the smbus2 interface, the path of a pseudo-terminal the emulator
serves, a loopback TCP port, an input-event pipe or a video file. From there on the driver
runs exactly its hardware code path: the same bytes, the same faults.

An emulator and the drivers that use it must run in one process (the same profile ``group``).
An emulator node registers its endpoint when it starts (constructing it opens nothing), and
bringup starts emulators before drivers. A driver that starts before its emulator finds
nothing, reports the device absent and retries with backoff like for a device that is not
plugged in yet.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
import threading
import time
from typing import Any

from enbarr_core.framework.errors import ConfigurationError, DeviceError

#: Parameter value naming the emulator instead of a device.
EMULATED = 'emulated'

#: Kinds of endpoint: what ``lookup`` returns for each.
KINDS = {
    'i2c': 'an in-memory I2C bus (transport.i2c.FakeI2cBus)',
    'serial': 'the path of a pseudo-terminal served by the emulator',
    'tcp': 'a (host, port) on loopback',
    'evdev': 'an input-event source (joystick emulator)',
    'camera': 'the path of a video file the emulator wrote',
}

_lock = threading.Lock()
_endpoints: dict[tuple[str, str], Any] = {}
_owners: dict[tuple[str, str], Any] = {}


def is_emulated(value: Any) -> bool:
    """Whether a device parameter's value names an emulator (``emulated`` or ``emulated:X``)."""
    return isinstance(value, str) and (value == EMULATED or value.startswith(EMULATED + ':'))


def emulator_name(value: str) -> str:
    """Return the emulator's name in ``emulated:NAME`` (``default`` for a bare ``emulated``)."""
    _, _, name = value.partition(':')
    return name or 'default'


def register(kind: str, name: str, endpoint: Any, owner: Any = None) -> None:
    """Offer ``endpoint`` as the emulated device ``kind``/``name`` of this process.

    ``owner`` (the emulator node) may register again under its name (a replugged device);
    another owner of the same kind and name is a ``ConfigurationError``: two emulators of
    one kind in a profile need different ``name`` parameters, else both drivers would open
    the same device.
    """
    if kind not in KINDS:
        raise ValueError(f'kind: one of {", ".join(KINDS)}, got {kind!r}')
    with _lock:
        held = _owners.get((kind, name))
        if owner is not None and held is not None and held is not owner:
            raise ConfigurationError(
                f'name: {_describe(held)} already emulates the {kind} device {name!r} in '
                f'this process; give {_describe(owner)} another name (and its driver '
                f'emulated:<name>)', parameter='name')
        _endpoints[(kind, name)] = endpoint
        if owner is not None:
            _owners[(kind, name)] = owner


def _describe(owner: Any) -> str:
    get_name = getattr(owner, 'get_name', None)
    return f'node {get_name()!r}' if callable(get_name) else repr(owner)


def unregister(kind: str, name: str, endpoint: Any = None) -> None:
    """Withdraw an endpoint (only ``endpoint`` itself when given: a newer one stays)."""
    with _lock:
        if endpoint is None or _endpoints.get((kind, name)) is endpoint:
            _endpoints.pop((kind, name), None)
            _owners.pop((kind, name), None)


def lookup(kind: str, value: str) -> Any:
    """Return the endpoint that ``value`` (``emulated`` or ``emulated:NAME``) names.

    ``DeviceError`` when no emulator of that kind and name runs in this process: the driver
    treats it like an absent device and retries.
    """
    name = emulator_name(value)
    with _lock:
        endpoint = _endpoints.get((kind, name))
    if endpoint is None:
        with _lock:
            known = sorted(n for k, n in _endpoints if k == kind)
        raise DeviceError(
            f'{value}: no {kind} emulator named {name!r} runs in this process (known: '
            f'{", ".join(known) or "none"}); put its emulator node in the same profile group')
    return endpoint


def get_or_create(kind: str, name: str, factory: Any) -> Any:
    """Return the endpoint ``kind``/``name``, made by ``factory()`` if there is none yet.

    For shared I2C buses: several emulated chips sit on one bus.
    """
    with _lock:
        endpoint = _endpoints.get((kind, name))
        if endpoint is None:
            endpoint = _endpoints[(kind, name)] = factory()
        return endpoint


# -- emulated I2C chips on a shared bus --------------------------------------------------------
# An emulator node plugs its chips into the named emulated bus when started and unplugs them
# when destroyed; a ``check-device --bus emulated`` puts chips on a private bus for the check's
# duration. One place for both, so that no emulator leaves a bus registered behind it.

def plug_i2c(name: str, chips: Mapping[int, Any]) -> Any:
    """Attach ``chips`` (address -> chip) to the emulated I2C bus ``name`` (made if missing).

    Returns the bus (a ``transport.i2c.FakeI2cBus``).
    """
    from enbarr_plugins.transport.i2c import FakeI2cBus
    bus = get_or_create('i2c', name, FakeI2cBus)
    for address, chip in chips.items():
        bus.attach(address, chip)
    return bus


def unplug_i2c(name: str, bus: Any, chips: Mapping[int, Any]) -> None:
    """Detach those of ``chips`` still on ``bus``; withdraw the bus ``name`` once it is empty."""
    for address, chip in chips.items():
        if bus.devices.get(address) is chip:
            bus.detach(address)
    if not bus.devices:
        unregister('i2c', name, bus)


@contextmanager
def checked_i2c_bus(value: str, attach: Callable[[Any], object]) -> Iterator[str]:
    """Yield the bus a device check opens, its own or a private emulated one.

    ``value`` itself; for an emulated one a private emulated bus (its ``emulated:NAME``) on
    which ``attach(bus)`` put the chips, withdrawn when the check ends.
    """
    if not is_emulated(value):
        yield value
        return
    from enbarr_plugins.transport.i2c import FakeI2cBus
    name = f'check-device-{time.monotonic_ns()}'
    bus = FakeI2cBus()
    attach(bus)
    register('i2c', name, bus)
    try:
        yield f'emulated:{name}'
    finally:
        unregister('i2c', name)
