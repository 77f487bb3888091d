"""The ROV's failsafes, as ArduSub's: a trigger, a threshold and an action each. Pure (no ROS).

Each failsafe watches one condition and, when it holds, asks for an action from a fixed set
that ArduSub's pilots know, ordered from the least to the most severe:

- ``disabled``: the failsafe is off (never trips).
- ``warn``: report only (the log, ``failsafe/active``, ``/diagnostics``).
- ``stabilize``: leave depth hold for stabilize (heading held, the heave stick a climb rate).
- ``manual``: the sticks as forces, no feedback: needs no sensor at all, so it is the fallback
  of last resort before stopping.
- ``surface``: climb at a set rate with the heading held (depth hold, or stabilize without a
  depth, with a positive heave goal), whatever the pilot asks.
- ``neutral``: thrusters neutral (ArduSub's disarm).

When several failsafes are active the most severe action wins. Which failsafe watches what on
Enbarr (the node, ``control.failsafe_node``, measures the ages and levels):

``pilot_input`` (ArduSub FS_PILOT_INPUT): no pilot input, i.e. no finite velocity command on
    ``surface_command/twist``, for ``timeout`` s. Clears when one arrives.
``surface_link`` (FS_GCS_ENABLE): nothing at all from the topside (``surface_command/twist``,
    ``/io`` or ``/stop``) for ``timeout`` s. Clears when the link returns.
``leak`` (FS_LEAK_ENABLE): the ``leak`` topic reads true. Latches: it stays active, with its
    action, until the operator clears it (``io_request`` to executor ``failsafe``, value
    ``clear``) while the sensor reads dry.
``battery_low`` / ``battery_critical`` (FS_BATT_ENABLE; ArduSub 4's BATT_FS_LOW_ACT and
    BATT_FS_CRT_ACT): the battery voltage below ``voltage`` for ``time`` s (so that the sag of
    a thrust burst does not trip it). Both latch until the operator clears them with the
    voltage back above the threshold: a pack that recovers at rest sags again under load.
``depth`` (ArduSub's depth-sensor check in depth hold): in depth hold, the depth older than
    ``timeout``. Clears when the depth is fresh again.
``attitude`` (FS_EKF_ACTION): the attitude filter reports an error, or its IMU samples stop
    (its ``samples`` count stands still) or its report stops, for ``timeout`` s. Clears when
    it recovers.
``pressure`` / ``temperature`` (FS_PRESS_ENABLE / FS_TEMP_ENABLE): the pressure or temperature
    inside the hull above ``limit``. Clears when it falls below again.

A failsafe that never heard its input (no leak sensor, no battery monitor) does not trip:
nothing says the vehicle is unsafe; the node reports the input missing instead. The clocks
(``now``, ages) are seconds on one time line, given by the caller.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math

DISABLED, WARN, STABILIZE, MANUAL, SURFACE, NEUTRAL = (
    'disabled', 'warn', 'stabilize', 'manual', 'surface', 'neutral')
#: Every action, from the least to the most severe (the most severe active one wins).
ACTIONS: tuple[str, ...] = (DISABLED, WARN, STABILIZE, MANUAL, SURFACE, NEUTRAL)
SEVERITY: dict[str, int] = {a: i for i, a in enumerate(ACTIONS)}
#: The action published when no failsafe is active.
NONE = 'none'


@dataclass(frozen=True)
class Kind:
    """What a failsafe is: its threshold's meaning and the actions it may take."""

    name: str
    threshold: str            # the parameter's name: timeout, voltage, limit (or '' for none)
    units: str
    actions: tuple[str, ...]  # the allowed actions
    latches: bool             # stays active until the operator clears it
    ardusub: str              # the ArduSub parameter it mirrors


KINDS: dict[str, Kind] = {k.name: k for k in (
    Kind('pilot_input', 'timeout', 's', (DISABLED, WARN, NEUTRAL), False, 'FS_PILOT_INPUT'),
    Kind('surface_link', 'timeout', 's', (DISABLED, WARN, NEUTRAL, SURFACE), False,
         'FS_GCS_ENABLE'),
    Kind('leak', '', '', (DISABLED, WARN, SURFACE), True, 'FS_LEAK_ENABLE'),
    Kind('battery_low', 'voltage', 'V', (DISABLED, WARN, SURFACE), True, 'FS_BATT_ENABLE'),
    Kind('battery_critical', 'voltage', 'V', (DISABLED, WARN, SURFACE, NEUTRAL), True,
         'FS_BATT_ENABLE'),
    Kind('depth', 'timeout', 's', (DISABLED, WARN, STABILIZE, MANUAL), False, '(depth hold)'),
    Kind('attitude', 'timeout', 's', (DISABLED, WARN, MANUAL, NEUTRAL), False,
         'FS_EKF_ACTION'),
    Kind('pressure', 'limit', 'Pa', (DISABLED, WARN), False, 'FS_PRESS_ENABLE'),
    Kind('temperature', 'limit', 'degC', (DISABLED, WARN), False, 'FS_TEMP_ENABLE'),
)}


@dataclass(frozen=True)
class FailsafeSetting:
    """One failsafe's action and threshold (its ``Kind`` says what the threshold is)."""

    action: str
    threshold: float = math.nan   # [s], [V], [Pa] or [degC]; NaN for a kind without one
    time: float = 0.0             # [s] the condition must hold this long (battery only)


@dataclass(frozen=True)
class FailsafeSettings:
    """Every failsafe's setting, by name (``KINDS``)."""

    failsafes: Mapping[str, FailsafeSetting]

    def validate(self) -> None:
        """Raise ``ValueError`` naming the failsafe and its parameter when a value is wrong."""
        unknown = sorted(set(self.failsafes) - set(KINDS))
        if unknown:
            raise ValueError(f'unknown failsafe {unknown[0]!r} (known: {", ".join(KINDS)})')
        for name, s in self.failsafes.items():
            kind = KINDS[name]
            if s.action not in kind.actions:
                raise ValueError(f'{name}.action: {s.action!r} is not one of '
                                 f'{", ".join(kind.actions)}')
            if kind.threshold and not math.isfinite(s.threshold):
                raise ValueError(f'{name}.{kind.threshold}: {s.threshold} must be finite')
            if kind.threshold == 'timeout' and s.threshold <= 0.0:
                raise ValueError(f'{name}.timeout: {s.threshold} s must be > 0')
            if not (math.isfinite(s.time) and s.time >= 0.0):
                raise ValueError(f'{name}.time: {s.time} s must be finite and >= 0')
        low, critical = self.failsafes.get('battery_low'), self.failsafes.get('battery_critical')
        if low and critical and low.action != DISABLED and critical.action != DISABLED \
                and critical.threshold >= low.threshold:
            raise ValueError(f'battery_critical.voltage: {critical.threshold} V must be below '
                             f'battery_low.voltage ({low.threshold} V)')


@dataclass(frozen=True)
class Observation:
    """What the vehicle knows at one instant; None: that input was never heard.

    Ages are [s] since the input was last heard (the node counts from its start until then).
    """

    pilot_input_age: float
    surface_link_age: float
    leak: bool | None = None
    battery_voltage: float | None = None     # [V]
    depth_hold: bool = False                 # the pilot mode is depth_hold
    depth_age: float | None = None           # [s]
    attitude_problem: str | None = None      # why the attitude cannot be trusted, or None
    attitude_age: float = 0.0                # [s] since the attitude was last trusted
    pressure: float | None = None            # inside the hull [Pa]
    temperature: float | None = None         # inside the hull [degC]


@dataclass(frozen=True)
class Trip:
    """An active failsafe: its action, why, and when it tripped [s]."""

    name: str
    action: str
    reason: str
    since: float


@dataclass(frozen=True)
class Verdict:
    """The outcome of one evaluation."""

    action: str                    # the most severe active action, or NONE
    active: tuple[Trip, ...]       # the active failsafes, in KINDS order
    tripped: tuple[Trip, ...] = ()  # those that tripped in this evaluation
    cleared: tuple[str, ...] = ()  # names of those that cleared in it


def most_severe(actions: list[str]) -> str:
    """Return the most severe of ``actions`` (``SEVERITY``), or NONE when there is none."""
    acting = [a for a in actions if a != DISABLED]
    return max(acting, key=SEVERITY.__getitem__) if acting else NONE


@dataclass
class Supervisor:
    """Evaluates the failsafes (module docstring) and keeps which are active."""

    settings: FailsafeSettings
    active: dict[str, Trip] = field(default_factory=dict)
    _below_since: dict[str, float] = field(default_factory=dict)  # battery: voltage low since

    def __post_init__(self) -> None:
        self.settings.validate()

    def _condition(self, name: str, s: FailsafeSetting, o: Observation,
                   now: float) -> str | None:
        """Why failsafe ``name`` holds now, or None."""
        if name in ('pilot_input', 'surface_link'):
            age = o.pilot_input_age if name == 'pilot_input' else o.surface_link_age
            what = 'pilot input' if name == 'pilot_input' else 'message from the surface'
            return f'no {what} for {age:.1f} s (limit {s.threshold:g} s)' \
                if age > s.threshold else None
        if name == 'leak':
            return 'leak detected' if o.leak else None
        if name in ('battery_low', 'battery_critical'):
            v = o.battery_voltage
            if v is None or not math.isfinite(v) or v >= s.threshold:
                self._below_since.pop(name, None)
                return None
            since = self._below_since.setdefault(name, now)
            if now - since < s.time:
                return None
            return f'battery {v:.2f} V below {s.threshold:g} V for {now - since:.1f} s'
        if name == 'depth':
            if not o.depth_hold and 'depth' not in self.active:
                return None   # only depth hold needs the depth (the trip outlives the mode)
            if o.depth_age is None:
                return 'no depth sensor heard'
            return f'depth {o.depth_age:.1f} s old (limit {s.threshold:g} s)' \
                if o.depth_age > s.threshold else None
        if name == 'attitude':
            if o.attitude_problem is None or o.attitude_age <= s.threshold:
                return None
            return f'{o.attitude_problem} for {o.attitude_age:.1f} s (limit {s.threshold:g} s)'
        if name in ('pressure', 'temperature'):
            value = o.pressure if name == 'pressure' else o.temperature
            units = KINDS[name].units
            if value is None or not math.isfinite(value) or value <= s.threshold:
                return None
            return f'inside {name} {value:g} {units} above {s.threshold:g} {units}'
        raise AssertionError(name)   # validate() refuses unknown names

    def evaluate(self, o: Observation, now: float) -> Verdict:
        """Judge ``o`` at ``now`` [s]: trip, keep or clear each failsafe."""
        tripped: list[Trip] = []
        cleared: list[str] = []
        for name in KINDS:
            s = self.settings.failsafes.get(name)
            if s is None or s.action == DISABLED:
                self.active.pop(name, None)
                continue
            reason = self._condition(name, s, o, now)
            trip = self.active.get(name)
            if reason is not None and trip is None:
                trip = self.active[name] = Trip(name, s.action, reason, now)
                tripped.append(trip)
            elif reason is not None and trip is not None:
                self.active[name] = Trip(name, s.action, reason, trip.since)
            elif trip is not None and not KINDS[name].latches:
                del self.active[name]
                cleared.append(name)
        return self._verdict(tuple(tripped), tuple(cleared))

    def clear(self, o: Observation, now: float) -> tuple[Verdict, str]:
        """Clear (the operator) the latched failsafes whose condition no longer holds.

        Return the verdict and what was done (which cleared, which still hold and why).
        """
        cleared: list[str] = []
        kept: list[str] = []
        for name, trip in list(self.active.items()):
            if not KINDS[name].latches:
                continue
            s = self.settings.failsafes[name]
            self._below_since.pop(name, None)   # a voltage still low must hold `time` again
            reason = self._condition(name, replace_time(s), o, now)
            if reason is None:
                del self.active[name]
                cleared.append(name)
            else:
                kept.append(f'{name} ({reason})')
        said = ('cleared ' + ', '.join(cleared)) if cleared else 'nothing to clear'
        if kept:
            said += '; still holding: ' + ', '.join(kept)
        return self._verdict((), tuple(cleared)), said

    def _verdict(self, tripped: tuple[Trip, ...], cleared: tuple[str, ...]) -> Verdict:
        active = tuple(self.active[n] for n in KINDS if n in self.active)
        return Verdict(most_severe([t.action for t in active]), active, tripped, cleared)


def replace_time(s: FailsafeSetting) -> FailsafeSetting:
    """``s`` judged at once (time 0): a clear asks whether the condition holds now."""
    return FailsafeSetting(s.action, s.threshold, 0.0)


def describe(active: tuple[Trip, ...]) -> str:
    """One line for ``failsafe/active``: each trip's name, action, time and reason."""
    if not active:
        return NONE
    return '; '.join(f'{t.name}: {t.action} since {t.since:.2f} s ({t.reason})'
                     for t in active)
