"""``enbarr check-device pca9685``: read one PCA9685 without a vessel, and without changing it.

Lives apart from the driver: it is the one place that needs both the driver's chip class and
the emulator (``--bus emulated``).
"""

from __future__ import annotations

import math

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.thrusters.pca9685 import open_device, Pca9685
from enbarr_plugins.thrusters.pca9685_emulator import start_check_emulator
from enbarr_plugins.thrusters.pca9685_protocol import (
    AI, DEFAULT_ADDRESS, MODE2_RESERVED, PRESCALE_MIN, SLEEP)


def check_pca9685(target: CheckTarget) -> list[str]:
    """Open the PCA9685 named by ``target``, print MODE1, PRE_SCALE, frequency, channel 0.

    Reads only: the chip is not reconfigured (a running vessel's thrusters keep their pulses).
    ``emulated`` starts an emulator in this process. ``DeviceError`` when absent or wrong.
    """
    bus = target.bus or '1'
    address = target.address if target.address is not None else DEFAULT_ADDRESS
    emulator = None
    if emulation.is_emulated(bus):
        emulator = start_check_emulator(bus, address)
    try:
        try:
            device, owned = open_device(bus, address)
        except ValueError as err:
            raise DeviceError(str(err)) from err
        chip = Pca9685(device)
        try:
            state = chip.read_state(0)
        finally:
            if owned:
                chip.close()
        if state['mode2'] & MODE2_RESERVED or state['prescale'] < PRESCALE_MIN:
            # MODE2 bits 7..5 are reserved (read 0); PRE_SCALE is never below 3.
            raise DeviceError(f'{chip.name}: not a PCA9685: MODE2 0x{state["mode2"]:02x}, '
                              f'PRE_SCALE 0x{state["prescale"]:02x}')
        pulse = state['pulse']
        pulse_text = ('full off' if pulse == 0.0 else 'full on' if math.isinf(pulse)
                      else f'{pulse:.0f} us')
        return [f'PCA9685 at {chip.name}',
                f'MODE1 0x{state["mode1"]:02x} ({"asleep" if state["mode1"] & SLEEP else "awake"}'
                f'{", auto-increment" if state["mode1"] & AI else ""})',
                f'PRE_SCALE {state["prescale"]} -> {state["frequency"]:.1f} Hz (25 MHz '
                'oscillator)',
                f'channel 0: {pulse_text}']
    finally:
        if emulator is not None:
            emulator()
