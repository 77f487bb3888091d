"""Thrust feedback: a thruster that does not turn as commanded is found and latched failed.

Pure (no ROS). The Enbarr README's ``thruster_sensors``: each thruster reports its shaft speed
(``sensor_msgs/JointState`` velocity [rad/s], and its current in ``effort`` [A] where the ESC
measures it). A propeller's thrust goes with the square of its speed (T = K_T rho D^4 n|n|,
Fossen 2021, ch. 9), and the thruster plugins make thrust proportional to the command, so a
command c in -1..1 should turn the shaft at

    n_expected = sign(c) sqrt(|c|) n_full

with ``n_full`` the speed at full throttle. A blocked rotor (a rope round the shaft, a jammed
propeller) turns far slower than that, or not at all; a tangled one slower. A thruster is
failed when, for ``hold_time`` without a break, it is commanded at least ``min_command`` and
its measured speed is below ``ratio`` times the expected one, or turns the other way. The hold
spans the motor's spin-up (a real ESC ramps, the simulated thruster has a first-order lag),
so a command step alone never trips it.

A failure is latched: a thruster that turned again by itself (a weed that let go) is not
trusted back without the operator (:meth:`ThrusterHealth.clear`). What is done with a failed
thruster is the allocator's: it is removed and the rest re-allocated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math


@dataclass(frozen=True)
class HealthSettings:
    """Settings of :class:`ThrusterHealth`."""

    full_speed: float    # shaft speed at full throttle [rad/s]
    min_command: float   # below this |command| nothing is judged (the speed is too small)
    ratio: float         # failed below this fraction of the expected speed
    hold_time: float     # for this long without a break [s]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` naming the first bad field."""
        if not (math.isfinite(self.full_speed) and self.full_speed > 0.0):
            raise ValueError(f'full_speed: {self.full_speed} rad/s must be finite and > 0')
        if not 0.0 < self.min_command <= 1.0:
            raise ValueError(f'min_command: {self.min_command} must be in (0, 1]')
        if not 0.0 < self.ratio < 1.0:
            raise ValueError(f'ratio: {self.ratio} must be in (0, 1)')
        if not (math.isfinite(self.hold_time) and self.hold_time > 0.0):
            raise ValueError(f'hold_time: {self.hold_time} s must be finite and > 0')


def expected_speed(command: float, full_speed: float) -> float:
    """Shaft speed [rad/s] a thrust command ``command`` (-1..1) should give (module doc)."""
    return math.copysign(math.sqrt(abs(command)) * full_speed, command)


def short_of(command: float, speed: float, s: HealthSettings) -> bool:
    """Whether ``speed`` [rad/s] falls short of what ``command`` asks (module docstring)."""
    if abs(command) < s.min_command:
        return False
    want = expected_speed(command, s.full_speed)
    return speed * want <= 0.0 or abs(speed) < s.ratio * abs(want)


class ThrusterHealth:
    """Per-thruster judgement of commanded against measured speed (module docstring)."""

    def __init__(self, names: Sequence[str], settings: HealthSettings) -> None:
        settings.validate()
        self.settings = settings
        self.names = tuple(names)
        self._since: dict[str, int | None] = {n: None for n in self.names}
        self.failed: dict[str, str] = {}   # name -> why, latched
        self.command = {n: 0.0 for n in self.names}

    def commanded(self, name: str, value: float) -> None:
        """Take the command last given to thruster ``name`` (-1..1)."""
        if name in self.command:
            self.command[name] = float(value)

    def measured(self, name: str, speed: float, now_ns: int) -> str | None:
        """Judge thruster ``name`` at speed ``speed`` [rad/s] measured at ``now_ns``.

        Return why, when this measurement fails it (once; it stays in ``failed``), else None.
        An unknown name or a speed that is not finite is not judged (None).
        """
        if name not in self._since or name in self.failed or not math.isfinite(speed):
            return None
        s = self.settings
        command = self.command[name]
        if not short_of(command, speed, s):
            self._since[name] = None
            return None
        since = self._since[name]
        if since is None or now_ns < since:
            self._since[name] = now_ns
            return None
        if (now_ns - since) * 1e-9 < s.hold_time:
            return None
        want = expected_speed(command, s.full_speed)
        why = (f'commanded {command:+.2f} for {(now_ns - since) * 1e-9:.2f} s, turning '
               f'{speed:.0f} rad/s of the {want:.0f} expected: blocked or tangled')
        self.failed[name] = why
        return why

    def clear(self, name: str | None = None) -> None:
        """Trust thruster ``name`` again (every thruster when None): the operator's call."""
        for n in (self.names if name is None else (name,)):
            self.failed.pop(n, None)
            if n in self._since:
                self._since[n] = None
