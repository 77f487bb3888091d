"""Operator modes of a DP vessel driven by a game controller (``sensor_msgs/Joy``).

The vessel starts in manual mode: the sticks command surge, sway and yaw force. One button
asks for automatic mode (hold the pose where the vessel is), another for guidance (follow the
configured path), and a third returns to manual. A request is refused, with a reason, when it
is unsafe: automatic or guidance need a fresh pose estimate, guidance needs a path. Losing the
joystick, or the pose estimate going stale while the vessel is automatic, falls back to
manual with zero force; so does the absence of guidance references outside manual (no
guidance node, or one that cannot make them).

The joystick-loss rule (``LOSS_RULES``) follows how the driver publishes:

- ``timeout``: a driver that publishes at a steady rate (ROS ``joy``, ``joy_linux``: 20 Hz
  autorepeat by default) is lost when no sample comes for ``joy_timeout``. A republished
  sample (same stamp, same content) counts as a sign of life (``on_repeat``).
- ``connection``: a driver that publishes only on change (ds4_driver) is silent while the
  stick rests or is held still, so silence is no loss there. The driver's connection state
  decides: a ``True`` heartbeat at least every ``joy_timeout`` keeps the joystick
  (``on_connection``); ``False`` loses it at once, a missing heartbeat after
  ``joy_timeout``. While connected, the last sample's sticks keep their force however long
  they rest; samples that arrive while not connected are not taken.

Which axis and button does what is the vessel profile's (``JoyMapping``, built from the
named layouts of ``enbarr_core.control.joy_layouts``): joystick drivers number their buttons
differently. The modes themselves are ``enbarr_interfaces.modes.Mode``, the vocabulary of
the ``mode`` topic. Joystick conventions are those of ``sensor_msgs/Joy``: sticks in -1..1,
up and left positive, which matches REP-103 FLU: stick up = surge ahead, stick left = sway
to port, right stick left = yaw counter-clockwise (``JoyMapping.signs`` flips an axis whose
driver counts the other way).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from enbarr_interfaces.modes import Mode

#: How joystick loss is judged (see the module docstring).
LOSS_RULES = ('timeout', 'connection')


@dataclass(frozen=True)
class JoyMapping:
    """Which ``Joy`` axis and button does what (indices of ``axes``/``buttons``)."""

    axis_surge: int            # stick up = +1: surge ahead
    axis_sway: int             # stick left = +1: sway to port
    axis_yaw: int              # stick left = +1: yaw counter-clockwise
    button_automatic: int      # to automatic: hold the pose
    button_guidance: int       # to guidance: follow the path
    button_manual: int         # back to manual
    deadzone: float = 0.05     # |axis| below this reads 0
    signs: tuple[float, float, float] = (1.0, 1.0, 1.0)  # +1 or -1 per (surge, sway, yaw)

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        for name in ('axis_surge', 'axis_sway', 'axis_yaw', 'button_automatic',
                     'button_guidance', 'button_manual'):
            if getattr(self, name) < 0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        buttons = (self.button_automatic, self.button_guidance, self.button_manual)
        if len(set(buttons)) != 3:
            raise ValueError(f'mode buttons must differ, got {buttons}')
        if not 0.0 <= self.deadzone < 1.0:
            raise ValueError(f'deadzone must be in [0, 1), got {self.deadzone}')
        if len(self.signs) != 3 or any(s not in (1.0, -1.0) for s in self.signs):
            raise ValueError(f'signs must be three of +1/-1, got {self.signs}')


@dataclass(frozen=True)
class Transition:
    """A mode change, or a refused request (``accepted`` False, ``reason`` says why)."""

    requested: Mode
    previous: Mode
    accepted: bool
    reason: str


class ModeManager:
    """Turns joystick samples and estimator health into the operator mode and manual force."""

    def __init__(self, mapping: JoyMapping, tau_max: Sequence[float],
                 joy_timeout: float = 0.5, loss_rule: str = 'timeout') -> None:
        mapping.validate()
        if loss_rule not in LOSS_RULES:
            raise ValueError(f'loss_rule must be one of {LOSS_RULES}, got {loss_rule!r}')
        self.mapping = mapping
        self.tau_max = np.asarray(tau_max, dtype=float)
        self.joy_timeout = joy_timeout
        self.loss_rule = loss_rule
        self.connected = False             # connection rule: the driver's state
        self._heartbeat: float | None = None  # connection rule: last True heartbeat [s]
        self.mode = Mode.MANUAL
        self.tau_manual: NDArray[np.float64] = np.zeros(3)
        self.rejected_samples = 0
        self.unconnected_samples = 0
        self._buttons: tuple[int, ...] = ()
        self._last_joy: float | None = None

    def on_joy(self, axes: Sequence[float], buttons: Sequence[int], now: float,
               estimate_fresh: bool, has_path: bool) -> list[Transition]:
        """Handle one ``Joy`` sample at time ``now`` [s]; return the transitions it asked for.

        Non-finite axes or missing indices reject the whole sample (counted), as if it never
        arrived. Under the connection rule a sample while not connected is not taken (counted
        in ``unconnected_samples``).
        """
        m = self.mapping
        if self.loss_rule == 'connection' and not self.connected:
            self.unconnected_samples += 1
            return []
        try:
            sticks = [axes[m.axis_surge], axes[m.axis_sway], axes[m.axis_yaw]]
            pressed_now = [buttons[i] for i in (m.button_automatic, m.button_guidance,
                                                m.button_manual)]
        except IndexError:
            self.rejected_samples += 1
            return []
        if not all(math.isfinite(a) and abs(a) <= 1.0 + 1e-6 for a in sticks):
            self.rejected_samples += 1
            return []
        self._last_joy = now
        sticks = [0.0 if abs(a) < m.deadzone else max(-1.0, min(1.0, a)) for a in sticks]
        self.tau_manual = self.tau_max * np.array(m.signs) * np.array(sticks)
        previous = dict(zip((m.button_automatic, m.button_guidance, m.button_manual),
                            self._buttons or (0, 0, 0)))
        self._buttons = tuple(pressed_now)
        rising = [button for button, now_down in zip(
            (m.button_automatic, m.button_guidance, m.button_manual), pressed_now)
            if now_down and not previous[button]]
        if m.button_manual in rising:  # manual wins over anything pressed with it (safety)
            return [self.request(Mode.MANUAL, estimate_fresh, has_path)]
        mode_of = {m.button_automatic: Mode.AUTOMATIC, m.button_guidance: Mode.GUIDANCE}
        return [self.request(mode_of[b], estimate_fresh, has_path) for b in rising]

    def request(self, mode: Mode, estimate_fresh: bool, has_path: bool) -> Transition:
        """Change to ``mode`` if that is safe; the transition says whether and why not."""
        previous = self.mode
        if mode is previous:
            return Transition(mode, previous, False, f'already {mode.value}')
        if mode is not Mode.MANUAL and not estimate_fresh:
            return Transition(mode, previous, False, 'no fresh pose estimate')
        if mode is Mode.GUIDANCE and not has_path:
            return Transition(mode, previous, False, 'no path configured')
        self.mode = mode
        return Transition(mode, previous, True, 'operator request')

    @property
    def heartbeat_at(self) -> float | None:
        """Time [s] of the last ``True`` connection heartbeat (connection rule), or None."""
        return self._heartbeat

    def on_repeat(self, now: float) -> None:
        """Note a republished sample (same stamp and content) at ``now`` [s]: a sign of life."""
        if self._last_joy is not None:
            self._last_joy = now

    def on_connection(self, connected: bool, now: float) -> Transition | None:
        """Take the driver's connection state (a heartbeat when True) at ``now`` [s].

        Only the connection rule listens. ``False`` loses the joystick at once (manual, zero
        force); the transition is returned when that changed anything.
        """
        if self.loss_rule != 'connection':
            return None
        if connected:
            self.connected, self._heartbeat = True, now
            return None
        was = self.connected
        self.connected, self._heartbeat = False, None
        return self._lose('joystick disconnected') if was else None

    def _lose(self, reason: str) -> Transition | None:
        """Manual with zero force; None when that is already the state."""
        if self.mode is Mode.MANUAL and not self.tau_manual.any():
            self._last_joy = None
            return None
        self.tau_manual = np.zeros(3)
        self._last_joy = None
        previous, self.mode = self.mode, Mode.MANUAL
        return Transition(Mode.MANUAL, previous, True, reason)

    def joystick_contested(self) -> Transition | None:
        """Do what a joystick loss does, at once (manual, zero force): a second joystick.

        None when that is already the state (no joystick held, manual, zero force).
        """
        if self._last_joy is None and self.mode is Mode.MANUAL and not self.tau_manual.any():
            return None
        self.tau_manual = np.zeros(3)
        self._last_joy = None
        previous, self.mode = self.mode, Mode.MANUAL
        return Transition(Mode.MANUAL, previous, True, 'joystick contested')

    def check(self, now: float, estimate_fresh: bool,
              reference_fresh: bool = True) -> Transition | None:
        """Supervise: fall back to manual with zero force when that is the safe thing.

        That is on joystick loss, and outside manual on a stale estimate or when no guidance
        reference arrives.
        """
        if self.loss_rule == 'connection':
            if self._heartbeat is not None and now - self._heartbeat > self.joy_timeout:
                self.connected, self._heartbeat = False, None
                t = self._lose('joystick heartbeat lost')
                if t is not None:
                    return t
        elif self._last_joy is not None and now - self._last_joy > self.joy_timeout:
            self.tau_manual = np.zeros(3)
            self._last_joy = None
            previous, self.mode = self.mode, Mode.MANUAL
            return Transition(Mode.MANUAL, previous, True, 'joystick lost')
        if self.mode is not Mode.MANUAL and not estimate_fresh:
            previous, self.mode = self.mode, Mode.MANUAL
            self.tau_manual = np.zeros(3)
            return Transition(Mode.MANUAL, previous, True, 'pose estimate stale')
        if self.mode is not Mode.MANUAL and not reference_fresh:
            previous, self.mode = self.mode, Mode.MANUAL
            self.tau_manual = np.zeros(3)
            return Transition(Mode.MANUAL, previous, True, 'no guidance reference')
        return None
