"""The ROV pilot's gamepad: a ``Joy`` sample to surface commands. Pure (no ROS).

Named controls of a layout (``control.joy_layouts``) drive the vehicle the way an ArduSub
pilot knows it (the picture is ``docs/rov_gamepad.png``):

- sticks are velocity goals in base_link (FLU): each stick, past its dead band, gives a
  fraction of that axis' full-stick speed, rescaled so that the goal grows from zero at the
  band's edge (no step) to the full speed at the stop;
- buttons are io requests, sent once on the press edge (a held button sends nothing more):
  a pilot mode (``control.pilot_modes``, executor ``pilot_mode``), the lights (a toggle),
  the manipulator (+/- steps), the camera tilt (an absolute angle, in steps, clamped).

A pad that is lost sends nothing: the mapper says ``None`` instead of a twist, so that the
vehicle's command receiver times out and its failsafe holds zero. It is lost when the driver
says it is disconnected (``joy/connected`` False), when its ``Joy`` is older than
``joy_timeout`` (a driver with a steady rate), or, for a driver that publishes only on change,
when its connection heartbeat is older than ``joy_timeout`` (held sticks are then still the
pad's, see ``control.modes``). Axes are never republished from a sample that went stale.
After a loss the first sample arms the buttons without firing them: a button held through
a reconnect is not a press.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Any

from enbarr_core.control.joy_layouts import get_layout, JoyLayout
from enbarr_core.control.pilot_modes import EXECUTOR as PILOT_EXECUTOR, MODES

#: Velocity-goal axes a stick can drive, index into nu = [u, v, w, p, q, r].
STICK_DOFS = {'surge': 0, 'sway': 1, 'heave': 2, 'yaw': 5}
#: Button controls: one press edge each (module docstring).
BUTTON_CONTROLS = ('manual', 'stabilize', 'depth_hold', 'velocity', 'lights',
                   'manipulator_open', 'manipulator_close', 'tilt_up', 'tilt_down',
                   'tilt_centre')


@dataclass(frozen=True)
class GamepadSettings:
    """What the pad's controls do; validated by ``validate``."""

    layout: str = 'enbarr_ds4'
    # Stick of each axis (a layout axis name, ``-name`` for the other way; '' = unused).
    sticks: tuple[tuple[str, str], ...] = (('surge', 'right_y'), ('sway', 'right_x'),
                                           ('heave', 'left_y'), ('yaw', 'left_x'))
    # Velocity at full stick [m/s for surge, sway, heave; rad/s for yaw].
    full_stick: tuple[tuple[str, float], ...] = (('surge', 0.5), ('sway', 0.5),
                                                 ('heave', 0.5), ('yaw', 1.0))
    deadzone: float = 0.1                 # fraction of the stick's travel
    # Button of each control (a layout button name; '' = unused).
    buttons: tuple[tuple[str, str], ...] = (
        ('manual', 'square'), ('stabilize', 'triangle'), ('depth_hold', 'cross'),
        ('velocity', 'circle'), ('lights', 'options'), ('manipulator_open', 'r1'),
        ('manipulator_close', 'l1'), ('tilt_up', 'dpad_up'), ('tilt_down', 'dpad_down'),
        ('tilt_centre', 'r3'))
    lights_executor: str = 'gpio_12'          # gpio_lights on pin 12 (enbarr_rov.yaml)
    manipulator_executor: str = 'manipulator'
    manipulator_step: int = 50            # [steps] per press
    tilt_executor: str = 'camera_tilt'
    tilt_step: float = 10.0               # [deg] per press
    tilt_min: float = -45.0               # [deg], down
    tilt_max: float = 45.0                # [deg], up
    joy_timeout: float = 0.5              # [s]

    def validate(self) -> JoyLayout:
        """Return the layout; ValueError naming the setting at fault."""
        try:
            layout = get_layout(self.layout)
        except ValueError as err:
            raise ValueError(f'layout: {err}') from err
        for control, spec in self.sticks:
            if control not in STICK_DOFS:
                raise ValueError(f'sticks: {control!r} is not one of {", ".join(STICK_DOFS)}')
            if spec:
                try:
                    layout.axis(spec)
                except ValueError as err:
                    raise ValueError(f'sticks.{control}: {err}') from err
        for control, speed in self.full_stick:
            if control not in STICK_DOFS:
                raise ValueError(f'full_stick: {control!r} is not one of '
                                 f'{", ".join(STICK_DOFS)}')
            if not (math.isfinite(speed) and speed >= 0.0):
                raise ValueError(f'full_stick.{control}: {speed} must be finite and >= 0')
        speeds = dict(self.full_stick)
        for control, spec in self.sticks:
            if spec and control not in speeds:
                raise ValueError(f'full_stick.{control}: needed for sticks.{control}')
        for control, name in self.buttons:
            if control not in BUTTON_CONTROLS:
                raise ValueError(f'buttons: {control!r} is not one of '
                                 f'{", ".join(BUTTON_CONTROLS)}')
            if name:
                try:
                    layout.button(name)
                except ValueError as err:
                    raise ValueError(f'buttons.{control}: {err}') from err
        used = [name for _, name in self.buttons if name]
        twice = sorted({name for name in used if used.count(name) > 1})
        if twice:
            raise ValueError(f'buttons: {twice[0]!r} is given to two controls')
        if not 0.0 <= self.deadzone < 1.0:
            raise ValueError(f'deadzone: {self.deadzone} must be in [0, 1)')
        if not self.tilt_min <= 0.0 <= self.tilt_max:
            raise ValueError(f'tilt_min, tilt_max: [{self.tilt_min}, {self.tilt_max}] deg '
                             'must hold 0 (the centre)')
        if not (math.isfinite(self.joy_timeout) and self.joy_timeout > 0.0):
            raise ValueError(f'joy_timeout: {self.joy_timeout} s must be finite and > 0')
        return layout


def dead_band(x: float, band: float) -> float:
    """Stick value ``x`` (-1..1) past a dead band of half-width ``band``, rescaled to -1..1.

    Zero inside the band; outside, (|x| - band) / (1 - band) with x's sign, so the output is
    continuous at the band's edge and reaches 1 at the stop. NaN reads as centred.
    """
    if not math.isfinite(x):
        return 0.0
    x = max(-1.0, min(1.0, x))
    magnitude = abs(x) - band
    if magnitude <= 0.0:
        return 0.0
    return math.copysign(magnitude / (1.0 - band), x)


@dataclass(frozen=True)
class IoRequest:
    """One io request for ``surface_command/io``: the executor's name and the value."""

    executor: str
    value: Any   # bool, int or float or str: the executor's type


class GamepadMapper:
    """The pad's state: the last sample, the button edges, the tilt goal, lost or not."""

    def __init__(self, settings: GamepadSettings) -> None:
        layout = settings.validate()
        self.settings = settings
        self.on_change = layout.publishes_on_change
        full = dict(settings.full_stick)
        # (dof, axis index, sign, full-stick speed) of each stick in use
        self._axes = [(STICK_DOFS[c], *layout.axis(spec), full[c])
                      for c, spec in settings.sticks if spec]
        self._buttons = [(c, layout.button(name)) for c, name in settings.buttons if name]
        self._nu: tuple[float, ...] = (0.0,) * 6
        self._last_joy: float | None = None       # arrival of the last sample [s]
        self._heartbeat: float | None = None      # last True of joy/connected [s]
        self._disconnected = False                # the driver said False
        self._pressed: dict[str, bool] | None = None   # None: the next sample arms
        self.lights = False
        self.tilt = 0.0                           # [deg]

    def on_connection(self, connected: bool, now: float) -> None:
        """Take the driver's connection state at ``now`` [s] (True is a heartbeat)."""
        if connected:
            self._heartbeat = now
            self._disconnected = False
        else:
            self._disconnected = True
            self._pressed = None

    def on_joy(self, axes: Sequence[float], buttons: Sequence[int],
               now: float) -> list[IoRequest]:
        """Take a ``Joy`` sample that arrived at ``now`` [s]; return the io requests it fires.

        A sample while disconnected is dropped (the driver's last word wins). The first
        sample after a loss arms the buttons and fires nothing.
        """
        if self._disconnected:
            return []
        if (self._last_joy is not None and not self.on_change
                and now - self._last_joy > self.settings.joy_timeout):
            self._pressed = None   # back from a stale gap: arm again
        self._last_joy = now
        nu = [0.0] * 6
        for dof, index, sign, full in self._axes:
            value = axes[index] if index < len(axes) else 0.0
            nu[dof] = sign * dead_band(value, self.settings.deadzone) * full
        self._nu = tuple(nu)
        pressed = {c: (index < len(buttons) and bool(buttons[index]))
                   for c, index in self._buttons}
        before, self._pressed = self._pressed, pressed
        if before is None:
            return []
        return [r for c in BUTTON_CONTROLS
                if pressed.get(c) and not before[c]
                for r in [self._press(c)] if r is not None]

    def _press(self, control: str) -> IoRequest | None:
        s = self.settings
        if control in MODES:
            return IoRequest(PILOT_EXECUTOR, control)
        if control == 'lights':
            self.lights = not self.lights
            return IoRequest(s.lights_executor, self.lights)
        if control == 'manipulator_open':
            return IoRequest(s.manipulator_executor, s.manipulator_step)
        if control == 'manipulator_close':
            return IoRequest(s.manipulator_executor, -s.manipulator_step)
        if control == 'tilt_centre':
            self.tilt = 0.0
        else:
            step = s.tilt_step if control == 'tilt_up' else -s.tilt_step
            self.tilt = max(s.tilt_min, min(s.tilt_max, self.tilt + step))
        return IoRequest(s.tilt_executor, self.tilt)

    def lost(self, now: float) -> str | None:
        """Return why the pad is lost at ``now`` [s], or None while it commands."""
        if self._disconnected:
            return 'the pad is disconnected'
        timeout = self.settings.joy_timeout
        if self.on_change:
            if self._heartbeat is None:
                return 'no connection heartbeat heard'
            if now - self._heartbeat > timeout:
                return f'no connection heartbeat for {now - self._heartbeat:.2f} s'
        if self._last_joy is None:
            return 'no joy sample heard'
        if not self.on_change and now - self._last_joy > timeout:
            return f'no joy sample for {now - self._last_joy:.2f} s'
        return None

    def twist(self, now: float) -> tuple[float, ...] | None:
        """Return the velocity goal [u, v, w, p, q, r] to send at ``now`` [s]; None: silence."""
        if self.lost(now) is not None:
            self._pressed = None
            return None
        return self._nu


def settings_from_params(v: Mapping[str, Any]) -> GamepadSettings:
    """Build ``GamepadSettings`` from a node's flat parameter values (``sticks.surge`` ...)."""
    return GamepadSettings(
        layout=v['layout'],
        sticks=tuple((c, v[f'sticks.{c}']) for c in STICK_DOFS),
        full_stick=tuple((c, float(v[f'full_stick.{c}'])) for c in STICK_DOFS),
        deadzone=v['deadzone'],
        buttons=tuple((c, v[f'buttons.{c}']) for c in BUTTON_CONTROLS),
        lights_executor=v['lights_executor'], manipulator_executor=v['manipulator_executor'],
        manipulator_step=v['manipulator_step'], tilt_executor=v['tilt_executor'],
        tilt_step=v['tilt_step'], tilt_min=v['tilt_min'], tilt_max=v['tilt_max'],
        joy_timeout=v['joy_timeout'])
