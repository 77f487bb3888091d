"""Raspberry Pi GPIO through gpiozero, shared by the lights and the stepper drivers.

``pin_factory`` is a parameter of both: ``lgpio`` (the default: gpiozero's ``LGPIOFactory``
on the lgpio library, which drives ``/dev/gpiochipN`` and works on the Pi 4 and the Pi 5) or
``mock`` (gpiozero's ``MockFactory``: pins in memory that record every level they take, what
the tests and ``enbarr check-device gpio --device emulated`` use; ``emulated`` means the same).
References: gpiozero 2.0 documentation, "API - Pins" (``gpiozero.pins.lgpio.LGPIOFactory``,
``gpiozero.pins.mock.MockFactory``).
"""

from __future__ import annotations

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
