"""DualShock 4 through Linux evdev: ``sensor_msgs/Joy`` in the ``enbarr_ds4`` layout.

The kernel's numbers (event types, axis and key codes, ``struct input_event``) and the
open-node interface are in ``ds4_protocol``, with their sources. Semantics: the gamepad node
of ``drivers/hid/hid-playstation.c`` has both sticks and both triggers 0..255 with flat 0 and
the d-pad as a hat -1..1 (hat value 0 = up = HAT0Y -1); the motion sensors ("... Motion
Sensors", INPUT_PROP_ACCELEROMETER) and the touchpad ("... Touchpad", its click BTN_LEFT) are
separate nodes. ``Documentation/input/event-codes.rst``: events up to SYN_REPORT form one
frame; after SYN_DROPPED ignore everything up to and including the next SYN_REPORT, then
query the state with EVIOCGKEY/EVIOCGABS. The python-evdev package opens the device, reads
its name, capabilities and absinfo, and queries the state (``active_keys``, ``absinfo``); the
events themselves are read from its fd and decoded here (``EventDecoder``), the same code
for the emulator's pipe (``ds4_emulator``), so emulated and real runs share the byte path.

Layout ``enbarr_ds4`` (= naoki-mizuno/ds4_driver's standard Joy, see ``layouts``): axes
[left_x, left_y, right_x, right_y, l2, r2], sticks normalised with the device's absinfo
(centre (min+max)/2, within ``flat`` of it 0) and negated so that up and left are +1
(REP-103 FLU for surge, sway and yaw), triggers 0 released .. 1 pressed; 18 buttons [square,
triangle, circle, cross, l1, l2, r1, r2, share, options, ps, trackpad (always 0: the touchpad
node), l3, r3, dpad_left, dpad_up, dpad_right, dpad_down]. Published on every change (each
SYN_REPORT that changed the state) and at a steady ``rate`` (the heartbeat), stamped on the
node clock at read time, with ``joy/connected`` (latched) True with each heartbeat and False
at once on a fault. Constructing the node opens and publishes nothing; ``start()`` opens the
device, says ``joy/connected`` False (nothing read yet), and the heartbeat says True from
then on; after ``stop()`` the node is silent.

Device: ``device`` = ``/dev/input/eventN``, ``auto`` (the first input node whose
capabilities are a DS4 gamepad's, re-found at every reconnect) or ``emulated[:NAME]``. A
node that is not a DS4 gamepad (a wrong path, the motion-sensor node) is refused at open
naming the path, its name and what its capabilities lack. Faults: read error ENODEV
(unplugged) or end of file (the emulator's unplug) -> ``joy/connected`` False, fault,
reconnect with backoff; records with an unknown type, code or an out-of-range value are
dropped and counted (``bad_events``); a record split across reads is reassembled; event
times that go backwards are counted (``out_of_order``) and applied in the kernel's order;
SYN_DROPPED -> resynchronise from the device state. A silent gamepad node is a resting
stick (evdev reports changes only): a link that stalls without the kernel noticing is not
detected here. Device I/O runs on the driver's reader thread (select with a timeout), never
on the executor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import errno
import os
import select
import threading
import time
from typing import Any

from sensor_msgs.msg import Joy
from std_msgs.msg import Bool

from enbarr_core.framework.driver import SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_core.control.joy_layouts import get_layout
from enbarr_plugins.joystick.ds4_protocol import (
    ABS_HAT0X, ABS_HAT0Y, AbsInfo, BUTTON_CODES, EV_ABS, EV_KEY, EV_MSC, EV_SYN, EVENT,
    GAMEPAD_ABS, GAMEPAD_KEYS, INPUT_PROP_ACCELEROMETER, InputHandle, STICKS, SYN_DROPPED,
    SYN_REPORT, TRIGGERS)

LAYOUT = get_layout('enbarr_ds4')
READ_EVENTS = 64  # events per read


def check_identity(h: InputHandle) -> None:
    """Raise ``DeviceError`` unless ``h`` is a DualShock 4 gamepad node."""
    missing_keys = sorted(GAMEPAD_KEYS - h.keys)
    missing_abs = sorted(GAMEPAD_ABS - set(h.absinfo))
    if h.accelerometer or missing_keys or missing_abs:
        what = ('a motion-sensor node (INPUT_PROP_ACCELEROMETER)' if h.accelerometer else
                f'lacks keys {[hex(k) for k in missing_keys]} and axes {missing_abs}')
        raise DeviceError(f'{h.path}: not a DualShock 4 gamepad: {h.name!r} is {what} (keys '
                          f'read: {[hex(k) for k in sorted(h.keys)][:16]}, axes read: '
                          f'{sorted(h.absinfo)})')
    for code in STICKS + TRIGGERS:
        a = h.absinfo[code]
        if a.maximum <= a.minimum:
            raise DeviceError(f'{h.path}: axis {code} has an empty range {a.minimum}..'
                              f'{a.maximum}')


def open_input(path: str) -> InputHandle:
    """Open a real input node with python-evdev; ``DeviceError`` naming the path."""
    import evdev  # only for real devices
    try:
        dev = evdev.InputDevice(path)
    except OSError as err:
        raise DeviceError(f'{path}: cannot open: {err.strerror or err}') from err
    try:
        caps = dev.capabilities(absinfo=True)
        absinfo = {code: AbsInfo(a.value, a.min, a.max, a.flat)
                   for code, a in caps.get(EV_ABS, [])}
        props = dev.input_props()
    except OSError as err:
        dev.close()
        raise DeviceError(f'{path}: cannot read its capabilities: {err}') from err

    def state() -> tuple[frozenset[int], dict[int, int]]:
        return frozenset(dev.active_keys()), {c: dev.absinfo(c).value for c in absinfo}

    return InputHandle(path, dev.name, frozenset(caps.get(EV_KEY, [])), absinfo, dev.fd,
                       state, dev.close, accelerometer=INPUT_PROP_ACCELEROMETER in props)


def find_gamepad() -> InputHandle:
    """Open the first DS4 gamepad node among ``/dev/input/event*`` (``auto``)."""
    import evdev
    seen = []
    for path in sorted(evdev.list_devices()):
        try:
            h = open_input(path)
        except DeviceError as err:
            seen.append(str(err))
            continue
        try:
            check_identity(h)
            return h
        except DeviceError:
            seen.append(f'{path} ({h.name})')
            h.close()
    raise DeviceError('auto: no DualShock 4 gamepad among the input devices (seen: '
                      f'{"; ".join(seen) or "none: is the controller paired or plugged in?"})')


@dataclass
class EventDecoder:
    """Decode ``struct input_event`` records into the gamepad state, frame by frame."""

    keys: frozenset[int]
    absinfo: dict[int, AbsInfo]
    pressed: set[int] = field(default_factory=set)
    values: dict[int, int] = field(default_factory=dict)
    events: int = 0
    frames: int = 0
    bad_events: int = 0
    dropped: int = 0        # SYN_DROPPED seen
    out_of_order: int = 0   # event times that went backwards
    resync_due: bool = False
    _buf: bytes = b''
    _frame: list[tuple[int, int, int]] = field(default_factory=list)
    _dropping: bool = False
    _last_time: float = 0.0

    def reset(self, pressed: frozenset[int], values: dict[int, int]) -> None:
        """Take the device's state (at open, after SYN_DROPPED)."""
        self.pressed = set(pressed) & self.keys
        self.values = {c: v for c, v in values.items() if c in self.absinfo}
        self._frame.clear()
        self.resync_due = False

    def feed(self, data: bytes) -> bool:
        """Decode bytes read; True when a completed frame changed the state."""
        buf = self._buf + data
        n = len(buf) // EVENT.size
        self._buf = buf[n * EVENT.size:]
        changed = False
        for sec, usec, etype, code, value in EVENT.iter_unpack(buf[:n * EVENT.size]):
            self.events += 1
            t = sec + usec * 1e-6
            if t < self._last_time:
                self.out_of_order += 1
            self._last_time = t
            if etype == EV_SYN:
                if code == SYN_DROPPED:
                    self.dropped += 1
                    self._dropping = True
                    self._frame.clear()
                elif code == SYN_REPORT:
                    if self._dropping:
                        self._dropping, self.resync_due = False, True
                    else:
                        changed |= self._apply()
                    self.frames += 1
                continue
            if self._dropping:
                continue
            if etype == EV_KEY and code in self.keys and value in (0, 1, 2):
                self._frame.append((etype, code, value))
            elif (etype == EV_ABS and code in self.absinfo
                  and self.absinfo[code].minimum <= value <= self.absinfo[code].maximum):
                self._frame.append((etype, code, value))
            elif etype == EV_MSC:
                continue
            else:
                self.bad_events += 1
        return changed

    @property
    def partial(self) -> int:
        """Bytes of an incomplete record held for the next read."""
        return len(self._buf)

    def _apply(self) -> bool:
        changed = False
        for etype, code, value in self._frame:
            if etype == EV_KEY:
                down = value != 0
                if down != (code in self.pressed):
                    changed = True
                    (self.pressed.add if down else self.pressed.discard)(code)
            elif self.values.get(code) != value:
                self.values[code] = value
                changed = True
        self._frame.clear()
        return changed

    def joy(self) -> tuple[list[float], list[int]]:
        """Return the state as ``Joy`` axes and buttons in the ``enbarr_ds4`` layout."""
        axes = []
        for code in STICKS:
            a = self.absinfo[code]
            centre, half = (a.minimum + a.maximum) / 2.0, (a.maximum - a.minimum) / 2.0
            d = self.values.get(code, centre) - centre
            x = 0.0 if abs(d) <= a.flat else max(-1.0, min(1.0, d / half))
            axes.append(-x if x else 0.0)  # up and left +1 (REP-103 FLU)
        for code in TRIGGERS:
            a = self.absinfo[code]
            v = self.values.get(code, a.minimum)
            axes.append((v - a.minimum) / (a.maximum - a.minimum))
        pressed = self.pressed
        buttons = [1 if BUTTON_CODES.get(name) in pressed else 0
                   for name in LAYOUT.buttons[:14]]
        hx, hy = self.values.get(ABS_HAT0X, 0), self.values.get(ABS_HAT0Y, 0)
        buttons += [int(hx < 0), int(hy < 0), int(hx > 0), int(hy > 0)]
        return axes, buttons


SPECS = [
    ParamSpec('device', 'auto', "'/dev/input/eventN', 'auto' (find the DS4 gamepad node) or "
              "'emulated[:NAME]'", read_only=True),
    ParamSpec('rate', 20.0, 'Heartbeat: Joy and joy/connected at least this often', 'Hz',
              1.0, 200.0, read_only=True),
]


@dataclass(frozen=True)
class Ds4EvdevSettings:
    """Settings of ``Ds4EvdevNode`` (see ``SPECS``)."""

    device: str
    rate: float  # [Hz]

    @classmethod
    def from_params(cls, v: dict[str, Any]) -> Ds4EvdevSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        device = v['device'].strip()
        if not (device == 'auto' or emulation.is_emulated(device) or device.startswith('/')):
            raise ValueError(f"device: '/dev/input/eventN', 'auto' or 'emulated[:NAME]', got "
                             f'{device!r}')
        return cls(device, v['rate'])


def open_device(device: str) -> InputHandle:
    """Open and identify the device a ``device`` value names (the driver's own path)."""
    if emulation.is_emulated(device):
        h = emulation.lookup('evdev', device).open()
        h.path = device
    elif device == 'auto':
        return find_gamepad()
    else:
        h = open_input(device)
    try:
        check_identity(h)
    except DeviceError:
        h.close()
        raise
    return h


class Ds4EvdevNode(SensorDriver):
    """See the module docstring."""

    def __init__(self, node_name: str = 'joystick', **kwargs: Any) -> None:
        self._handle: InputHandle | None = None
        self._reader: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.decoder: EventDecoder | None = None
        self.resyncs = 0
        self.truncated = 0
        super().__init__(node_name, **kwargs)
        self.settings: Ds4EvdevSettings = self.bind_settings(
            SPECS, Ds4EvdevSettings.from_params, lambda s: None).settings
        self.device = self.settings.device
        self._pub = self.create_topic_publisher(topics.JOY)
        self._connected_pub = self.create_topic_publisher(topics.JOY_CONNECTED)

    # -- device ---------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open and identify the DS4 gamepad node, take its state, start the reader."""
        h = open_device(self.settings.device)
        self.device = (f'auto ({h.path})' if self.settings.device == 'auto' else h.path)
        decoder = EventDecoder(h.keys, h.absinfo)
        try:
            decoder.reset(*h.state())
        except OSError as err:
            h.close()
            raise DeviceError(f'{h.path}: cannot read its state: {err}') from err
        if self.decoder is not None:  # counters go on across reconnects
            for name in ('events', 'frames', 'bad_events', 'dropped', 'out_of_order'):
                setattr(decoder, name, getattr(self.decoder, name))
        self._handle, self.decoder = h, decoder
        self.get_logger().info(f'{h.path}: {h.name!r}, a DualShock 4 gamepad')
        self._stop.clear()
        self._reader = threading.Thread(target=self._read_loop, args=(h, decoder),
                                        name=f'{self.get_name()}-evdev', daemon=True)
        self._reader.start()

    def close_device(self) -> None:
        """Stop the reader and close the device."""
        self._stop.set()
        reader = self._reader
        if reader is not None and reader is not threading.current_thread():
            reader.join(timeout=2.0)
        self._reader = None
        h, self._handle = self._handle, None
        if h is not None:
            h.close()

    def safe_state(self) -> None:
        """Say the joystick is gone: ``joy/connected`` False (the controller's loss rule).

        Also the first word of ``start()`` (``DeviceNode.start`` calls it between opening the
        device and starting the node): the heartbeat says True once the node has started.
        """
        self._connected_pub.publish(Bool(data=False))

    # -- reader thread -------------------------------------------------------------------------
    def _read_loop(self, h: InputHandle, decoder: EventDecoder) -> None:
        period = 1.0 / self.settings.rate
        next_beat = time.monotonic()
        while not self._stop.is_set():
            wait = max(0.0, next_beat - time.monotonic())
            try:
                ready, _, _ = select.select([h.fd], [], [], min(wait, period))
                data = os.read(h.fd, EVENT.size * READ_EVENTS) if ready else None
            except OSError as err:
                if self._stop.is_set():
                    return
                if err.errno in (errno.EAGAIN, errno.EINTR):  # python-evdev's fd is O_NONBLOCK
                    continue
                what = ('unplugged (ENODEV)' if err.errno == errno.ENODEV
                        else f'read failed: {err.strerror or err}')
                self._lost(h, decoder, what)
                return
            if data == b'':
                self._lost(h, decoder, 'end of input (unplugged)')
                return
            changed = False
            if data:
                with self._lock:
                    changed = decoder.feed(data)
                    if decoder.resync_due:
                        self._resync(h, decoder)
                        changed = True
            now = time.monotonic()
            beat = now >= next_beat
            if beat:
                next_beat = max(next_beat + period, now)
                if self.started:  # a source: silent before start (which says False first)
                    self._connected_pub.publish(Bool(data=True))
            if changed or beat:
                self._publish(decoder)

    def _resync(self, h: InputHandle, decoder: EventDecoder) -> None:
        self.resyncs += 1
        decoder.reset(*h.state())
        self.get_logger().warn(f'{h.path}: events dropped by the kernel (SYN_DROPPED): state '
                               're-read from the device', throttle_duration_sec=1.0)

    def _lost(self, h: InputHandle, decoder: EventDecoder, what: str) -> None:
        if decoder.partial:
            self.truncated += 1
        self._connected_pub.publish(Bool(data=False))
        self.device_fault(DeviceError(f'{h.path} ({h.name}): {what}'))

    def _publish(self, decoder: EventDecoder) -> None:
        if not self.started:  # a source: silent before start and after stop
            return
        with self._lock:
            axes, buttons = decoder.joy()
        msg = Joy()
        convert.ns_to_stamp(self.now_ns(), msg.header.stamp)
        msg.header.frame_id = topics.JOY.frame
        msg.axes = axes
        msg.buttons = buttons
        self._pub.publish(msg)
        self.sample_received()

    def status_values(self) -> dict[str, Any]:
        """Counters for ``/diagnostics``."""
        d = self.decoder
        h = self._handle
        return {**super().status_values(), 'name': h.name if h else '',
                'events': d.events if d else 0, 'frames': d.frames if d else 0,
                'bad_events': d.bad_events if d else 0, 'dropped': d.dropped if d else 0,
                'resyncs': self.resyncs, 'out_of_order': d.out_of_order if d else 0,
                'truncated': self.truncated}

    def destroy_node(self) -> None:
        """Say the joystick is gone (if it was ever looked for), stop the reader, destroy."""
        if self.connected or self.faults:  # a node only built (a check) has nothing to say
            try:
                self._connected_pub.publish(Bool(data=False))
            except Exception:  # noqa: BLE001 - destruction goes on
                pass
        super().destroy_node()
        self._stop.set()
