"""What a DualShock 4 gamepad node is to Linux evdev: the kernel's numbers and the open node.

The numbers are the kernel's ABI, written from its sources (``test_ds4_evdev.py`` types each
one again from the same sources and checks them):

- ``include/uapi/linux/input-event-codes.h``: event types ``EV_SYN`` 0x00, ``EV_KEY`` 0x01,
  ``EV_ABS`` 0x03, ``EV_MSC`` 0x04; ``SYN_REPORT`` 0, ``SYN_DROPPED`` 3; axes ``ABS_X`` 0x00,
  ``ABS_Y`` 0x01, ``ABS_Z`` 0x02, ``ABS_RX`` 0x03, ``ABS_RY`` 0x04, ``ABS_RZ`` 0x05,
  ``ABS_HAT0X`` 0x10, ``ABS_HAT0Y`` 0x11; buttons ``BTN_SOUTH`` 0x130, ``BTN_EAST`` 0x131,
  ``BTN_NORTH`` 0x133, ``BTN_WEST`` 0x134, ``BTN_TL`` 0x136, ``BTN_TR`` 0x137, ``BTN_TL2``
  0x138, ``BTN_TR2`` 0x139, ``BTN_SELECT`` 0x13a, ``BTN_START`` 0x13b, ``BTN_MODE`` 0x13c,
  ``BTN_THUMBL`` 0x13d, ``BTN_THUMBR`` 0x13e; ``INPUT_PROP_ACCELEROMETER`` 0x06.
- ``drivers/hid/hid-playstation.c``: ``ps_gamepad_buttons`` maps square to BTN_WEST,
  triangle BTN_NORTH, circle BTN_EAST, cross BTN_SOUTH, L1/R1 BTN_TL/BTN_TR, L2/R2
  BTN_TL2/BTN_TR2, share BTN_SELECT, options BTN_START, L3/R3 BTN_THUMBL/BTN_THUMBR, PS
  BTN_MODE; ``ps_gamepad_create`` gives ABS_X/Y (left stick), ABS_RX/RY (right stick), ABS_Z/RZ
  (L2/R2 triggers) 0..255 and the hat ABS_HAT0X/Y -1..1; the motion sensors and the touchpad
  are separate nodes.
- ``include/uapi/linux/input.h``: ``struct input_event`` is ``struct timeval`` (two longs on
  64-bit) then ``__u16 type, code; __s32 value``: 24 bytes.

The driver (``ds4_evdev``) and the check (``joystick/check.py``) read these; the emulator
(``ds4_emulator``) keeps its own copy of the kernel's numbers and shares only the typed
interface below (``AbsInfo``, ``InputHandle``), so a wrong number here shows up in the tests
as a wrong button instead of being copied into the device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import struct

#: ``struct input_event`` on 64-bit Linux: tv_sec, tv_usec (long), type, code (u16), value.
EVENT = struct.Struct('=qqHHi')
EV_SYN, EV_KEY, EV_ABS, EV_MSC = 0x00, 0x01, 0x03, 0x04
SYN_REPORT, SYN_DROPPED = 0, 3
ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ = 0x00, 0x01, 0x02, 0x03, 0x04, 0x05
ABS_HAT0X, ABS_HAT0Y = 0x10, 0x11
BTN_SOUTH, BTN_EAST, BTN_NORTH, BTN_WEST = 0x130, 0x131, 0x133, 0x134
BTN_TL, BTN_TR, BTN_TL2, BTN_TR2 = 0x136, 0x137, 0x138, 0x139
BTN_SELECT, BTN_START, BTN_MODE, BTN_THUMBL, BTN_THUMBR = 0x13a, 0x13b, 0x13c, 0x13d, 0x13e
INPUT_PROP_ACCELEROMETER = 0x06

#: enbarr_ds4 button name -> evdev key code, as hid-playstation maps the DS4's buttons.
BUTTON_CODES = {
    'square': BTN_WEST, 'triangle': BTN_NORTH, 'circle': BTN_EAST, 'cross': BTN_SOUTH,
    'l1': BTN_TL, 'l2': BTN_TL2, 'r1': BTN_TR, 'r2': BTN_TR2,
    'share': BTN_SELECT, 'options': BTN_START, 'ps': BTN_MODE,
    'l3': BTN_THUMBL, 'r3': BTN_THUMBR,
}
GAMEPAD_KEYS = frozenset(BUTTON_CODES.values())
GAMEPAD_ABS = frozenset((ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ, ABS_HAT0X, ABS_HAT0Y))
STICKS = (ABS_X, ABS_Y, ABS_RX, ABS_RY)  # left_x, left_y, right_x, right_y
TRIGGERS = (ABS_Z, ABS_RZ)               # l2, r2


@dataclass(frozen=True)
class AbsInfo:
    """Range of an absolute axis (``struct input_absinfo``)."""

    value: int
    minimum: int
    maximum: int
    flat: int = 0


@dataclass
class InputHandle:
    """An opened input node: its identity, the fd its events are read from, its state query.

    For a real device these come from python-evdev (``InputDevice``); the emulator builds one
    around a pipe.
    """

    path: str
    name: str
    keys: frozenset[int]
    absinfo: dict[int, AbsInfo]
    fd: int
    state: Callable[[], tuple[frozenset[int], dict[int, int]]]  # EVIOCGKEY, EVIOCGABS
    close: Callable[[], None]
    accelerometer: bool = False  # INPUT_PROP_ACCELEROMETER: a motion-sensor node
