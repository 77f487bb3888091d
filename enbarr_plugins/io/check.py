"""``enbarr check-device gpio``: read one Raspberry Pi GPIO pin without a vessel.

The pin is only read, through the same gpiozero backends as the drivers (``io/pins.py``):
lgpio, or gpiozero's ``MockFactory`` for ``--device emulated``.
"""

from __future__ import annotations

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.io.pins import close_quietly, gpio_errors, make_factory


def check_gpio(target: CheckTarget) -> list[str]:
    """Read one pin (``--name``, default 12) through gpiozero; ``emulated``: MockFactory.

    The pin is only read (claimed as an input while reading, as gpiozero does).
    """
    name = target.name or '12'
    if not name.isdigit():
        raise DeviceError(f'--name: a BCM pin number (0..27), got {name!r}')
    pin_number = int(name)
    given = target.device or target.bus or target.port
    factory_name = 'mock' if given and emulation.is_emulated(given) else 'lgpio'
    factory = make_factory(factory_name)
    pin = None
    try:
        try:
            pin = factory.pin(pin_number)
            level = pin.state
            function = pin.function
            board = factory.board_info
        except gpio_errors() as err:
            raise DeviceError(f'GPIO{pin_number} ({factory_name}): cannot read: {err}') from err
        return [f'GPIO ({factory_name}): {board.model} rev {board.revision}',
                f'GPIO{pin_number}: {function}, level {"high" if level else "low"}']
    finally:
        close_quietly(pin, factory)
