"""Raspberry Pi GPIO through gpiozero, shared by the lights and the stepper drivers.

``pin_factory`` is a parameter of both: ``lgpio`` (the default: gpiozero's ``LGPIOFactory``
on the lgpio library, which drives ``/dev/gpiochipN`` and works on the Pi 4 and the Pi 5) or
``mock`` (gpiozero's ``MockFactory``: pins in memory that record every level they take, what
the tests and ``enbarr check-device gpio --device emulated`` use; ``emulated`` means the same).
References: gpiozero 2.0 documentation, "API - Pins" (``gpiozero.pins.lgpio.LGPIOFactory``,
``gpiozero.pins.mock.MockFactory``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec

#: Values of the ``pin_factory`` parameter.
FACTORIES = ('lgpio', 'mock', 'emulated')

PIN_FACTORY_SPEC = ParamSpec(
    'pin_factory', 'lgpio', "GPIO backend: 'lgpio' (Raspberry Pi 4/5) or 'mock'/'emulated' "
    "(gpiozero's MockFactory, no hardware)", read_only=True)


def check_factory_name(name: str) -> str:
    """Return ``name`` if it is a known pin factory; ValueError naming the parameter."""
    if name not in FACTORIES:
        raise ValueError(f'pin_factory: one of {", ".join(FACTORIES)}, got {name!r}')
    return name


def gpio_errors() -> tuple[type[BaseException], ...]:
    """Exceptions a gpiozero call can raise when the GPIO chip or a pin fails."""
    from gpiozero import GPIOZeroError
    errors: list[type[BaseException]] = [GPIOZeroError, OSError, RuntimeError]
    try:
        import lgpio
        errors.append(lgpio.error)
    except ImportError:  # no lgpio: only the mock factory works
        pass
    return tuple(errors)


def make_factory(name: str) -> Any:
    """Open the pin factory ``name``; ``DeviceError`` when the GPIO chip cannot be opened."""
    check_factory_name(name)
    if name in ('mock', 'emulated'):
        from gpiozero.pins.mock import MockFactory
        return MockFactory()
    try:
        from gpiozero.pins.lgpio import LGPIOFactory
        return LGPIOFactory()
    except ImportError as err:
        raise DeviceError(f'GPIO (pin_factory lgpio): the lgpio library is not installed '
                          f'({err}); install python3-lgpio or use pin_factory mock') from err
    except gpio_errors() as err:
        raise DeviceError(f'GPIO (pin_factory lgpio): cannot open the GPIO chip: {err} (not '
                          'a Raspberry Pi, or /dev/gpiochip* not accessible: add the user '
                          "to the 'gpio' group)") from err


def close_quietly(*things: Any) -> None:
    """Close gpiozero devices and factories, ignoring their errors (a dying chip)."""
    for thing in things:
        if thing is None:
            continue
        try:
            thing.close()
        except Exception:  # noqa: BLE001 - closing goes on whatever the device says
            pass


@dataclass(frozen=True)
class Output:
    """One GPIO output a driver claims."""

    pin: int                  # BCM number; -1: not wired (nothing is claimed)
    active_high: bool = True  # False: the load is on while the pin is low
    initial: bool = False     # the level (on/off) it starts at


def open_outputs(factory_name: str, outputs: Sequence[Output],
                 device: str) -> tuple[Any, list[Any]]:
    """Open the pin factory and ``outputs`` as gpiozero ``DigitalOutputDevice``s.

    Returns the factory and one device per output (None where the pin is -1). A pin that
    cannot be claimed closes what was opened and raises ``DeviceError`` naming ``device``; a
    factory that cannot be opened raises ``make_factory``'s.
    """
    from gpiozero import DigitalOutputDevice
    factory = make_factory(factory_name)
    opened: list[Any] = []
    try:
        for out in outputs:
            opened.append(None if out.pin < 0 else DigitalOutputDevice(
                out.pin, active_high=out.active_high, initial_value=out.initial,
                pin_factory=factory))
    except gpio_errors() as err:
        close_quietly(*opened, factory)
        raise DeviceError(f'{device}: cannot use the pins as outputs: {err}') from err
    return factory, opened
