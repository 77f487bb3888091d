"""DualShock 4 emulator: a DS4 gamepad input node that writes real ``struct input_event`` records.

uinput is not available in containers, so the emulator stands where the kernel stands (with its
own copy of the kernel's numbers, written from the kernel's sources, not the driver's): it
describes the gamepad node hid-playstation registers (name, key and axis capabilities, absinfo
0..255 flat 0 for sticks and triggers, -1..1 for the hat; ``drivers/hid/hid-playstation.c``,
``ps_gamepad_create``) and writes the events a kernel would (``struct input_event``, 24 bytes
on 64-bit, EV_KEY/EV_ABS then SYN_REPORT per frame; ``include/uapi/linux/input.h``) into a
pipe whose read end the driver reads exactly as it reads a real device's fd
(``ds4_evdev.EventDecoder``). ``state()`` answers like EVIOCGKEY/EVIOCGABS.

Faults for tests: ``unplug()`` (the pipe closes: end of input, like ENODEV on a real node)
and ``replug()``; ``absent`` (open refused); ``wrong_identity`` (it presents itself as the
DS4's motion-sensor node); ``garbage()`` (records with a bad type, code or value);
``split_frame()`` (a record split across two writes); ``syn_dropped()`` (the kernel's buffer
overran: SYN_DROPPED, events lost, the state must be re-read); ``stall()`` (nothing written;
a resting controller looks the same).

``Ds4EmulatorNode`` wraps it for profiles: registered when it starts as the ``evdev`` endpoint
``name`` (``emulated:NAME`` in the driver's ``device``), scripted like ``scripted_joy``
(``'7.0 press triangle'``, ``'0.0 sticks S W Y'`` with the profile's ``joy.surge``,
``joy.sway``, ``joy.yaw`` stick names, ``'72.0 stop'`` = unplugged), so it is the scripted
operator of an emulated vessel, and it reports on ``/diagnostics`` what it wrote.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import os
import struct
import threading
import time
from typing import Any

from enbarr_core.framework.driver import OK, WARN
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_plugins import emulation
from enbarr_core.control.joy_layouts import AXIS_CONTROLS
from enbarr_plugins.joystick.ds4_protocol import AbsInfo, InputHandle
from enbarr_plugins.joystick.scripted import parse_joy_script
from enbarr_plugins.operator.script import Step

# The device's side of the kernel ABI, typed here from the kernel's sources rather than taken
# from the driver's ds4_protocol: the emulator stands where the kernel stands, so a wrong
# number on the driver's side must show in the tests as a wrong button, not be copied here.
# include/uapi/linux/input.h: struct input_event, 24 bytes on 64-bit.
EVENT = struct.Struct('=qqHHi')
# include/uapi/linux/input-event-codes.h
EV_SYN, EV_KEY, EV_ABS = 0x00, 0x01, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3
ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ = 0x00, 0x01, 0x02, 0x03, 0x04, 0x05
ABS_HAT0X, ABS_HAT0Y = 0x10, 0x11
# drivers/hid/hid-playstation.c, ps_gamepad_buttons, with the codes of input-event-codes.h.
BUTTON_CODES = {
    'square': 0x134,    # BTN_WEST
    'triangle': 0x133,  # BTN_NORTH
    'circle': 0x131,    # BTN_EAST
    'cross': 0x130,     # BTN_SOUTH
    'l1': 0x136,        # BTN_TL
    'l2': 0x138,        # BTN_TL2
    'r1': 0x137,        # BTN_TR
    'r2': 0x139,        # BTN_TR2
    'share': 0x13a,     # BTN_SELECT
    'options': 0x13b,   # BTN_START
    'ps': 0x13c,        # BTN_MODE
    'l3': 0x13d,        # BTN_THUMBL
    'r3': 0x13e,        # BTN_THUMBR
}

#: hdev->name of a DS4 on USB (hid-playstation names the gamepad node after it).
NAME = 'Sony Interactive Entertainment Wireless Controller'
STICK_CODES = {'left_x': ABS_X, 'left_y': ABS_Y, 'right_x': ABS_RX, 'right_y': ABS_RY}
ABSINFO = {code: AbsInfo(128, 0, 255) for code in (ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ)}
ABSINFO.update({ABS_HAT0X: AbsInfo(0, -1, 1), ABS_HAT0Y: AbsInfo(0, -1, 1)})
ABSINFO[ABS_Z] = ABSINFO[ABS_RZ] = AbsInfo(0, 0, 255)


def stick_raw(value: float) -> int:
    """Raw 0..255 of a stick at ``value`` in the Joy convention (+1 = left/up)."""
    return max(0, min(255, round(127.5 - 127.5 * value)))


class Ds4Emulator:
    """The device: its state, its event stream and its faults (see the module docstring)."""

    def __init__(self) -> None:
        self.absent = False
        self.wrong_identity = False
        self.stalled = False
        self.pressed: set[int] = set()
        self.values = {code: a.value for code, a in ABSINFO.items()}
        self.events = 0
        self.bytes = 0
        self.opens = 0
        self.faults = 0
        self._lock = threading.Lock()
        self._w: int | None = None

    # -- what the driver sees ---------------------------------------------------------------
    def open(self) -> InputHandle:
        """Open the node: a pipe the driver reads (``DeviceError`` when unplugged)."""
        with self._lock:
            if self.absent:
                raise DeviceError('emulated DS4: not plugged in')
            self._close_writer()
            r, w = os.pipe()
            self._w = w
            self.opens += 1
        if self.wrong_identity:  # the motion-sensor node of the same controller
            accel = {c: AbsInfo(0, -4096, 4096, 16) for c in (ABS_X, ABS_Y, ABS_Z, ABS_RX,
                                                               ABS_RY, ABS_RZ)}
            return InputHandle('emulated', f'{NAME} Motion Sensors', frozenset(), accel, r,
                               self.state, lambda: os.close(r), accelerometer=True)
        return InputHandle('emulated', NAME, frozenset(BUTTON_CODES.values()), dict(ABSINFO),
                           r, self.state, lambda: _close(r))

    def state(self) -> tuple[frozenset[int], dict[int, int]]:
        """Pressed keys and axis values now (what EVIOCGKEY/EVIOCGABS return)."""
        with self._lock:
            return frozenset(self.pressed), dict(self.values)

    # -- the operator -----------------------------------------------------------------------
    def sticks(self, values: Mapping[str, float]) -> None:
        """Move sticks by name (``left_y``: +1 = up) in one frame."""
        frame = []
        for name, value in values.items():
            code, raw = STICK_CODES[name], stick_raw(value)
            if self.values[code] != raw:
                self.values[code] = raw
                frame.append((EV_ABS, code, raw))
        if frame:
            self._write(frame)

    def press(self, name: str, down: bool = True) -> None:
        """Press (or release) a button by name."""
        code = BUTTON_CODES[name]
        (self.pressed.add if down else self.pressed.discard)(code)
        self._write([(EV_KEY, code, int(down))])

    def release_all(self) -> None:
        """Release every pressed button."""
        frame = [(EV_KEY, code, 0) for code in sorted(self.pressed)]
        self.pressed.clear()
        if frame:
            self._write(frame)

    # -- faults -----------------------------------------------------------------------------
    def unplug(self) -> None:
        """Pull the cable: the pipe closes (the driver reads end of input)."""
        with self._lock:
            self.absent = True
            self.faults += 1
            self._close_writer()

    def replug(self) -> None:
        """Plug it back in: the next open succeeds (the state is kept, as on the pad)."""
        with self._lock:
            self.absent = False

    def garbage(self) -> None:
        """Write corrupted records: unknown type, a key and an axis it lacks, a bad value."""
        self.faults += 1
        self._write([(0x1f, 0, 7), (EV_KEY, 0x2ff, 1), (EV_ABS, 0x28, 5), (EV_ABS, ABS_X, 999),
                     (EV_KEY, BUTTON_CODES['cross'], 7)], raw=True)

    def split_frame(self, name: str) -> None:
        """Press ``name`` with its frame split mid-record across two writes."""
        self.faults += 1
        code = BUTTON_CODES[name]
        self.pressed.add(code)
        data = self._pack([(EV_KEY, code, 1), (EV_SYN, SYN_REPORT, 0)])
        self._send(data[:10])
        time.sleep(0.02)
        self._send(data[10:])

    def syn_dropped(self, name: str) -> None:
        """Overrun the kernel's queue while ``name`` was pressed: events lost, SYN_DROPPED."""
        self.faults += 1
        code = BUTTON_CODES[name]
        self.pressed.add(code)  # the press itself was lost: only the state has it
        self._send(self._pack([(EV_ABS, ABS_X, 0), (EV_SYN, SYN_DROPPED, 0),
                               (EV_ABS, ABS_Y, 0), (EV_SYN, SYN_REPORT, 0)]))

    def stall(self, stalled: bool = True) -> None:
        """Stop (or resume) writing anything."""
        self.stalled = stalled

    # -- bytes ------------------------------------------------------------------------------
    def _pack(self, events: Sequence[tuple[int, int, int]]) -> bytes:
        t = time.time()
        sec, usec = int(t), int((t % 1.0) * 1e6)
        return b''.join(EVENT.pack(sec, usec, *e) for e in events)

    def _write(self, events: Sequence[tuple[int, int, int]], raw: bool = False) -> None:
        self._send(self._pack([*events, (EV_SYN, SYN_REPORT, 0)]))

    def _send(self, data: bytes) -> None:
        with self._lock:
            if self._w is None or self.stalled:
                return
            try:
                os.write(self._w, data)
            except OSError:  # the driver closed its end
                self._close_writer()
                return
            self.events += len(data) // EVENT.size
            self.bytes += len(data)

    def _close_writer(self) -> None:
        if self._w is not None:
            _close(self._w)
            self._w = None

    def close(self) -> None:
        """Close the stream for good (the node is destroyed)."""
        with self._lock:
            self._close_writer()


def _close(fd: int) -> None:
    try:
        os.close(fd)
    except OSError:
        pass


SPECS = [
    ParamSpec('name', 'default', "Emulator name: the driver's device is 'emulated:NAME'",
              read_only=True),
    ParamSpec('script', [''], "Timed operator lines, as scripted_joy's ('stop': unplugged)",
              read_only=True, element=str),
    ParamSpec('hold', 0.1, 'How long a scripted press holds the button', 's', 0.02, 5.0,
              read_only=True),
    *(ParamSpec(f'joy.{dof}', default, f"Stick name of the {dof} stick (the profile's)",
                read_only=True) for dof, default in zip(AXIS_CONTROLS,
                                                        ('left_y', 'left_x', 'right_x'))),
]


@dataclass(frozen=True)
class Ds4EmulatorSettings:
    """Settings of ``Ds4EmulatorNode`` (see ``SPECS``)."""

    name: str
    script: tuple[Step, ...]
    hold: float                          # [s]
    sticks: tuple[tuple[str, float], ...]  # (stick name, sign) for surge, sway, yaw

    @classmethod
    def from_params(cls, v: dict[str, Any]) -> Ds4EmulatorSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        sticks = []
        for dof in AXIS_CONTROLS:
            spec = v[f'joy.{dof}']
            name = spec.lstrip('-+')
            if name not in STICK_CODES:
                raise ValueError(f'joy.{dof}: a stick of {", ".join(STICK_CODES)} (optionally '
                                 f"'-'), got {spec!r}")
            sticks.append((name, -1.0 if spec.startswith('-') else 1.0))
        try:
            script = parse_joy_script([x for x in v['script'] if x.strip()],
                                      {n: i for i, n in enumerate(BUTTON_CODES)})
        except ValueError as err:
            raise ValueError(f'script: {err}') from err
        return cls(v['name'], script, v['hold'], tuple(sticks))


class Ds4EmulatorNode(EnbarrNode):
    """See the module docstring."""

    device_emulator = True  # bringup builds it before the drivers (compose.build_nodes)

    def __init__(self, node_name: str = 'ds4_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: Ds4EmulatorSettings = self.bind_settings(
            SPECS, Ds4EmulatorSettings.from_params, lambda s: None).settings
        self.emulator = Ds4Emulator()
        self._names = list(BUTTON_CODES)
        self._next = 0
        self._start_ns: int | None = None
        self._release_ns: int | None = None
        self.create_timer(0.05, self._tick)  # the script's resolution (20 Hz)
        self.create_periodic(1.0, self._report)

    def start(self) -> None:
        """Offer the device (the ``evdev`` endpoint ``name``), start the script's clock now.

        Bringup starts the emulators before the drivers, so the driver finds the device when it
        opens it; constructing the node offers nothing.
        """
        emulation.register('evdev', self.settings.name, self.emulator, owner=self)
        super().start()
        self._start_ns = self.now_ns()

    def _tick(self) -> None:
        if self._start_ns is None:
            return
        now = self.now_ns()
        if self._release_ns is not None and now >= self._release_ns:
            self._release_ns = None
            self.emulator.release_all()
        script = self.settings.script
        elapsed = (now - self._start_ns) * 1e-9
        while self._next < len(script) and script[self._next].time <= elapsed:
            step = script[self._next]
            self._next += 1
            if step.verb == 'sticks':
                self.emulator.sticks({name: sign * value for (name, sign), value in zip(
                    self.settings.sticks, step.value)})
            elif step.verb == 'press':
                self.emulator.press(self._names[step.value])
                self._release_ns = now + int(self.settings.hold * 1e9)
            else:
                self.emulator.unplug()

    def _report(self) -> None:
        e = self.emulator
        self.publish_diagnostics(WARN if e.absent else OK, 'unplugged' if e.absent else 'ok', {
            'events': e.events, 'bytes': e.bytes, 'opens': e.opens, 'faults': e.faults,
            'pressed': len(e.pressed)})

    def destroy_node(self) -> None:
        """Withdraw the endpoint, close the stream, destroy the node."""
        emulation.unregister('evdev', self.settings.name, self.emulator)
        self.emulator.close()
        super().destroy_node()
