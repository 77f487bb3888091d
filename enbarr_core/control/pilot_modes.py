"""The ROV's pilot modes and what each needs. Pure (no ROS).

ArduSub's modes, as its pilots know them:

- ``manual``: the sticks are forces. Each axis of the velocity goal, as a fraction of its
  ``full_stick`` value, times the velocity loop's ``tau_max`` goes to the allocation; no
  feedback, no leveling.
- ``stabilize``: roll and pitch held level, the yaw stick a yaw rate with the heading held
  when it is centred (``control.pilot_hold.HeadingHold``); surge, sway and heave as in
  ``velocity``.
- ``depth_hold``: ``stabilize``, and the heave stick a climb rate with the depth held when it
  is centred (``control.pilot_hold.DepthHold``) from the depth sensor fused with the
  accelerometer (``estimation.depth_estimator``).
- ``velocity``: the body-velocity loop alone (the goal is a velocity), Enbarr's own.

A mode that needs a sensor is refused, with the reason, when that sensor is missing or stale:
``depth_hold`` without a depth measurement newer than ``depth_timeout``. In ``depth_hold``, a
depth that goes stale falls back to ``stabilize`` (the heading is still held; the heave stick
is a climb rate again) and says why. Mode changes are bumpless: a hold starts from where the
vehicle is.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

MANUAL, STABILIZE, DEPTH_HOLD, VELOCITY = 'manual', 'stabilize', 'depth_hold', 'velocity'
MODES: tuple[str, ...] = (MANUAL, STABILIZE, DEPTH_HOLD, VELOCITY)
#: The executor name of a mode request on ``io_request`` (its string_value is the mode).
EXECUTOR = 'pilot_mode'


@dataclass(frozen=True)
class Transition:
    """The outcome of a request or of a check: the mode now, and why it changed or not."""

    mode: str
    changed: bool
    reason: str   # '' for a plain accepted change


class PilotModes:
    """The current mode and its rules (module docstring)."""

    def __init__(self, initial: str, depth_timeout: float) -> None:
        if initial not in MODES:
            raise ValueError(f'initial: {initial!r} is not one of {", ".join(MODES)}')
        if not (math.isfinite(depth_timeout) and depth_timeout > 0.0):
            raise ValueError(f'depth_timeout: {depth_timeout} s must be finite and > 0')
        self.mode = initial
        self.depth_timeout = depth_timeout
        self.refused = 0
        self.fallbacks = 0

    def depth_problem(self, depth_age: float | None) -> str | None:
        """Why depth hold cannot run with a depth ``depth_age`` [s] old (None: never), or None."""
        if depth_age is None:
            return 'no depth sensor heard'
        if depth_age > self.depth_timeout:
            return f'depth {depth_age:.1f} s old (limit {self.depth_timeout:g} s)'
        return None

    def request(self, mode: str, depth_age: float | None,
                manual_problem: str | None = None) -> Transition:
        """Ask for ``mode``; refused (with the reason) when unknown or its sensor is missing.

        ``manual_problem``: why manual cannot map the sticks to forces (None: it can).
        """
        if mode not in MODES:
            self.refused += 1
            return Transition(self.mode, False,
                              f'{mode!r} refused: not a mode ({", ".join(MODES)})')
        if mode == MANUAL and manual_problem is not None:
            self.refused += 1
            return Transition(self.mode, False, f'manual refused: {manual_problem}')
        if mode == DEPTH_HOLD:
            problem = self.depth_problem(depth_age)
            if problem is not None:
                self.refused += 1
                return Transition(self.mode, False, f'depth_hold refused: {problem}')
        changed = mode != self.mode
        self.mode = mode
        return Transition(mode, changed, '')

    def check(self, depth_age: float | None) -> Transition:
        """Apply the fallbacks: a stale depth in depth hold goes to stabilize, with why."""
        if self.mode == DEPTH_HOLD:
            problem = self.depth_problem(depth_age)
            if problem is not None:
                self.mode = STABILIZE
                self.fallbacks += 1
                return Transition(STABILIZE, True, f'depth_hold -> stabilize: {problem}')
        return Transition(self.mode, False, '')


def manual_problem(tau_max: tuple[float, ...]) -> str | None:
    """Why the sticks cannot be mapped to forces with ``tau_max``, or None."""
    if all(math.isfinite(t) for t in tau_max):
        return None
    return 'the velocity loop has no finite tau_max on every axis to scale the sticks by'


def manual_force(goal: tuple[float, ...], full_stick: tuple[float, ...],
                 tau_max: tuple[float, ...]) -> tuple[float, ...]:
    """Return the manual force: each goal axis over its full-stick value, clipped, x tau_max.

    ``tau_max`` must be finite (:func:`manual_problem`).
    """
    return tuple(max(-1.0, min(1.0, g / f)) * t for g, f, t in zip(goal, full_stick, tau_max))
