"""What the station page and the vessel say to each other, and when the page counts as gone.

Free of ROS and of the web server, so that the rules are tested with an injected clock.

The page sends, at its fixed rate (``input_rate``), one input message::

    {"type": "input", "seq": 17, "t": 123456.7,
     "axes": {"surge": 0.5, "sway": 0.0, "heave": 0.0, "yaw": -0.2},
     "buttons": ["triangle"], "lights": false}

``seq`` counts up from 1 on every page load, ``t`` is the page's own clock [ms] (only ever
compared with itself: the page and the vessel do not share a clock). Axes are the operator's
wish in -1..1 in REP-103 senses (surge ahead, sway to port, heave up, yaw counter-clockwise);
``buttons`` names the DualShock 4 buttons held (the page maps the browser's Gamepad API and the
keyboard onto them). The vessel turns that into its own command (``joy_axes_buttons``,
``twist_of``) and answers in every telemetry message with the last ``seq`` and ``t`` it took,
so the page can tell when its own input no longer gets through.

Besides the input, a page may send ``{"type": "surface_stop", "stop": true}`` (any page),
``{"type": "manipulator", "direction": 1}`` (or -1: the driving page only; the station moves
the manipulator ``manipulator_step`` steps that way) and ``{"type": "record", "action":
"start"}`` (or ``"stop"``: any page; the recorder's ``recorder/control``).

The camera has a WebSocket of its own (``/camera``), so that its frames never queue in front of
the telemetry and the acknowledgements. The station sends the latest JPEG at ``camera_rate``
as one binary message (``frame_message``: the image's stamp, then the JPEG), and each
detections message as text ``{"type": "detections", "stamp": [sec, nanosec], "boxes":
[[class_id, score, x_min, y_min, x_max, y_max], ...]}`` in the image's pixels. The stamp is
the image's header stamp (the detector copies it), so the page draws on an image only the
boxes found in that image. Binary frames, not a multipart MJPEG stream: an ``<img>`` showing
MJPEG gives the page no stamp for the frame it shows, so boxes could not be matched to it.

The failsafe rule (``DriveLease``): one page drives at a time. While its inputs keep coming,
each accepted one is published; when they stop for longer than ``input_timeout`` (a frozen tab,
a lost network) or its WebSocket closes, the lease ends: the station publishes one neutral
command and then nothing, so the vessel's own command-loss failsafe (the command receiver's
timeout, the DP controller's joystick-loss rule) takes over. It never keeps sending a held
command on the page's behalf. A gamepad held still is not silence: the page sends every tick
whether or not anything changed.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import struct
from typing import Any

#: The page's axis names, in the order ``DriveInput.axes`` keeps them.
AXES = ('surge', 'sway', 'heave', 'yaw')
#: The DualShock 4 buttons a page may report held (ds4_driver's names, as the layouts use).
BUTTONS = frozenset(('square', 'triangle', 'circle', 'cross', 'l1', 'l2', 'r1', 'r2', 'share',
                     'options', 'ps', 'l3', 'r3', 'dpad_left', 'dpad_up', 'dpad_right',
                     'dpad_down'))


class InputError(ValueError):
    """An input message that does not follow the protocol (the reason says how)."""


@dataclass(frozen=True)
class DriveInput:
    """One accepted input message of the page."""

    seq: int                                   # counts up per page load
    page_time: float                           # the page's clock [ms]
    axes: tuple[float, float, float, float]    # surge, sway, heave, yaw in -1..1
    buttons: frozenset[str]                    # DualShock 4 buttons held
    lights: bool                               # the page's lights switch


NEUTRAL_AXES = (0.0, 0.0, 0.0, 0.0)


def parse_input(msg: dict[str, Any]) -> DriveInput:
    """Check one decoded input message; ``InputError`` says what is wrong with it."""
    seq = msg.get('seq')
    if not isinstance(seq, int) or isinstance(seq, bool) or seq < 1:
        raise InputError(f'seq must be a positive integer, got {seq!r}')
    t = msg.get('t')
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        raise InputError(f't must be a finite number (the page clock, ms), got {t!r}')
    raw = msg.get('axes', {})
    if not isinstance(raw, dict) or set(raw) - set(AXES):
        raise InputError(f'axes must be an object with keys among {", ".join(AXES)}, '
                         f'got {raw!r}')
    axes = []
    for name in AXES:
        v = raw.get(name, 0.0)
        if (not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v)
                or abs(v) > 1.0):
            raise InputError(f'axes.{name} must be a number in -1..1, got {v!r}')
        axes.append(float(v))
    buttons = msg.get('buttons', [])
    if not isinstance(buttons, list) or not all(isinstance(b, str) for b in buttons):
        raise InputError(f'buttons must be a list of button names, got {buttons!r}')
    unknown = sorted(set(buttons) - BUTTONS)
    if unknown:
        raise InputError(f'unknown buttons {unknown}; known: {", ".join(sorted(BUTTONS))}')
    lights = msg.get('lights', False)
    if not isinstance(lights, bool):
        raise InputError(f'lights must be true or false, got {lights!r}')
    return DriveInput(seq, float(t), (axes[0], axes[1], axes[2], axes[3]),
                      frozenset(buttons), lights)


class Verdict:
    """What ``DriveLease.offer`` decided about one input."""

    TAKEN = 'taken'             # publish it
    NOT_HOLDER = 'not_holder'   # another page drives
    OLD = 'old'                 # seq or page time not after the last one taken


class DriveLease:
    """Which page drives and whether its inputs still come (see the module docstring).

    Times are seconds of one monotonic clock, passed in by the caller. A page is known by an
    opaque key (its connection). ``check`` and ``close`` return True exactly when the lease
    just ended, which is when the station publishes its one neutral command.
    """

    def __init__(self, timeout: float) -> None:
        if not (math.isfinite(timeout) and timeout > 0.0):
            raise ValueError(f'input_timeout must be finite and > 0, got {timeout}')
        self.timeout = timeout
        self.holder: object | None = None
        self.last: DriveInput | None = None
        self._last_at: float | None = None
        self.ended = 0          # leases that ended (close or timeout)
        self.timeouts = 0       # of which by silence
        self.refused = 0        # inputs refused (another page, out of order)

    def offer(self, key: object, inp: DriveInput, now: float) -> str:
        """Take ``inp`` from page ``key`` at ``now`` [s] if it may drive; return the verdict.

        A page takes the lease when nobody holds it. Within a lease, an input must be newer
        than the last in both ``seq`` and page time (a replayed or reordered one is refused).
        """
        if self.holder is None:
            self.holder, self.last = key, None
        elif self.holder is not key:
            self.refused += 1
            return Verdict.NOT_HOLDER
        if self.last is not None and (inp.seq <= self.last.seq
                                      or inp.page_time < self.last.page_time):
            self.refused += 1
            return Verdict.OLD
        self.last, self._last_at = inp, now
        return Verdict.TAKEN

    def live(self, now: float) -> bool:
        """Whether a page holds the lease and its last input is no older than the timeout."""
        return (self.holder is not None and self._last_at is not None
                and now - self._last_at <= self.timeout)

    def age(self, now: float) -> float | None:
        """Seconds since the holder's last input (None: nobody drives)."""
        return None if self._last_at is None or self.holder is None else now - self._last_at

    def check(self, now: float) -> bool:
        """End the lease when its inputs stopped; True when it just ended (send neutral)."""
        if self.holder is None or self.live(now):
            return False
        self.timeouts += 1
        return self._end()

    def close(self, key: object) -> bool:
        """Page ``key`` went away; True when it held the lease (send neutral)."""
        if self.holder is not key:
            return False
        return self._end()

    def _end(self) -> bool:
        self.holder, self.last, self._last_at = None, None, None
        self.ended += 1
        return True


def joy_axes_buttons(inp: DriveInput | None, rest: tuple[float, ...],
                     axes: tuple[tuple[int, float], ...], n_buttons: int,
                     button_index: dict[str, int]) -> tuple[list[float], list[int]]:
    """Return the ``sensor_msgs/Joy`` axes and buttons of ``inp`` in a joystick layout.

    ``rest`` is every axis at rest (the layout's; its length is the axis count), ``axes`` the
    (index, sign) of surge, sway and yaw (``JoyLayout.axis``), ``button_index`` the index of
    each button name of the layout. ``None``: the neutral sample (sticks at rest, nothing
    pressed). A button the layout does not have is left out.
    """
    out = list(rest)
    buttons = [0] * n_buttons
    if inp is None:
        return out, buttons
    surge, sway, _, yaw = inp.axes
    for (i, sign), value in zip(axes, (surge, sway, yaw)):
        out[i] = sign * value
    for name in inp.buttons:
        if name in button_index:
            buttons[button_index[name]] = 1
    return out, buttons


def twist_of(inp: DriveInput | None, max_linear: float,
             max_angular: float) -> tuple[float, float, float, float, float, float]:
    """Return the velocity goal [u, v, w, p, q, r] (m/s, rad/s, FLU) of ``inp``; zero for None."""
    if inp is None:
        return (0.0,) * 6
    surge, sway, heave, yaw = inp.axes
    return (surge * max_linear, sway * max_linear, heave * max_linear, 0.0, 0.0,
            yaw * max_angular)


#: Binary camera frame header: the image stamp's sec and nanosec, unsigned 32-bit big-endian.
FRAME_HEADER = struct.Struct('>II')


@dataclass(frozen=True)
class CameraFrame:
    """One compressed camera image, as the page gets it."""

    sec: int
    nanosec: int
    jpeg: bytes


@dataclass(frozen=True)
class Boxes:
    """The detections of one image: ``(class_id, score, x_min, y_min, x_max, y_max)`` rows."""

    sec: int
    nanosec: int
    rows: tuple[tuple[float, ...], ...]


def frame_message(frame: CameraFrame) -> bytes:
    """Return the binary WebSocket message of ``frame``: ``FRAME_HEADER``, then the JPEG."""
    return FRAME_HEADER.pack(frame.sec, frame.nanosec) + frame.jpeg


def boxes_message(boxes: Boxes) -> dict[str, Any]:
    """Return the text WebSocket message of ``boxes`` (JSON-ready)."""
    return {'type': 'detections', 'stamp': [boxes.sec, boxes.nanosec],
            'boxes': [list(r) for r in boxes.rows]}
