"""``enbarr check-device ds4``: the DualShock 4 gamepad node's identity and one state.

Kept apart from the driver (``joystick/ds4_evdev.py``) and the emulator
(``joystick/ds4_emulator.py``): it uses both (``--device emulated`` runs the emulator in this
process) and neither needs it.
"""

from __future__ import annotations

import os
import select

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins import emulation
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.joystick.ds4_emulator import Ds4Emulator
from enbarr_plugins.joystick.ds4_evdev import (
    check_identity, EventDecoder, LAYOUT, open_device, READ_EVENTS)
from enbarr_plugins.joystick.ds4_protocol import EVENT, GAMEPAD_ABS, GAMEPAD_KEYS


def check_device(target: CheckTarget) -> list[str]:
    """``enbarr check-device ds4``: open the gamepad, print its identity and one state."""
    device = target.device or 'auto'
    emulator = None
    if emulation.is_emulated(device):
        emulator = Ds4Emulator()
        h = emulator.open()
        check_identity(h)
    else:
        h = open_device(device)
    try:
        decoder = EventDecoder(h.keys, h.absinfo)
        decoder.reset(*h.state())
        if emulator is not None:  # the event path too: one frame through the pipe
            emulator.press('cross')
        ready, _, _ = select.select([h.fd], [], [], min(target.timeout, 0.2))
        if ready:
            data = os.read(h.fd, EVENT.size * READ_EVENTS)
            if data == b'':
                raise DeviceError(f'{h.path}: end of input (unplugged)')
            decoder.feed(data)
        axes, buttons = decoder.joy()
        pressed = [n for n, b in zip(LAYOUT.buttons, buttons) if b]
        return [f'device: {h.path}', f'name: {h.name}',
                f'buttons: {len(GAMEPAD_KEYS & h.keys)} gamepad keys '
                f'({", ".join(hex(k) for k in sorted(GAMEPAD_KEYS & h.keys))})',
                'axes: ' + ', '.join(f'{c}: {h.absinfo[c].minimum}..{h.absinfo[c].maximum} '
                                     f'flat {h.absinfo[c].flat}' for c in sorted(GAMEPAD_ABS)),
                'state (enbarr_ds4 layout): axes ' + ' '.join(f'{a:+.2f}' for a in axes)
                + f'; pressed: {", ".join(pressed) or "none"}']
    finally:
        h.close()
        if emulator is not None:
            emulator.unplug()
