"""Depth and heading hold for a piloted ROV, as ArduSub's pilots know them. Pure (no ROS).

Both are outer loops around the body-velocity loop (``control.velocity_control``): they turn
a stick and a measured depth or heading into the heave or yaw-rate goal the velocity loop
tracks, so the velocity loop's integral takes up what the model does not know (a vehicle a
little light or heavy, a current).

Depth (ArduSub's ALT_HOLD: a position loop over a climb-rate loop, the throttle stick
commanding the climb rate). With the stick outside ``deadband`` the vehicle climbs or dives at
stick x ``max_climb`` and the target is not held. When the stick comes back to the centre, or
the mode is entered while the vehicle moves, the vehicle is first brought to a stop from the
climb rate it had (the stick's, or on entering the measured vertical velocity w0), as
ArduSub's ALT_HOLD brings the vehicle to its stopping point before holding it; then the target
is taken where the vehicle is, and held: w_goal = clamp(k (z_target - z), +- ``max_climb``).
The stop is the critically damped run-down w_goal(t) = w0 (1 + t/T) exp(-t/T), T =
``stop_time``: its acceleration (``goal_accel``, which the velocity loop feeds forward through
the vehicle's inertia) starts at zero, peaks at |w0| / (e T) and dies out, so the thrust has
no step; the vehicle travels 2 w0 T meanwhile. After ``STOP_SPAN`` T (the goal down to 4 % of
w0) the target is taken where the vehicle is and held. Taking the target at the release
instant instead steps the goal from the climb rate to zero: the velocity loop's proportional
term steps the thrust by k_p w0, and the vehicle still overshoots the target by its stopping
distance. z is up (odom ENU: z = -depth). The heave goal is the world's vertical velocity,
handed to the body's heave axis: the leveling of the velocity loop keeps the two within
cos(tilt) of each other.

Heading (ArduSub's STABILIZE and ALT_HOLD yaw): the yaw stick commands a yaw rate; when it
comes back to the centre the vehicle first lets its yaw rate die out (the "rate-zero phase",
until |r| < ``settle_rate`` or ``settle_time`` has passed) and then holds the heading it has
at that moment: r_goal = clamp(k (psi_target - psi) wrapped, +- ``max_rate``). Holding the
heading at the instant the stick is released would pull the vehicle back through the turn it
was still making.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from enbarr_core.framework.kinematics import ssa

#: [m/s] A climb rate below this needs no stop: the depth is taken at once.
STOPPED = 0.005
#: A stop hands over to the hold after this many ``stop_time``: its goal is down to 4 % of w0,
#: and what is left of the run-down (w0 T 7 e^-5, under 5 % of its travel) the hold takes up.
STOP_SPAN = 5.0


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f'{name}: {value} must be finite and > 0')


@dataclass(frozen=True)
class DepthHoldSettings:
    """Settings of :class:`DepthHold`."""

    gain: float        # k: climb rate per metre of depth error [1/s]
    max_climb: float   # climb or dive rate at full stick, and the hold's limit [m/s]
    deadband: float    # |stick| at or below this is centred (0..1)
    integral_gain: float = 0.0    # k_i: climb rate per metre-second of error [1/s^2]
    integral_limit: float = 0.0   # |k_i integral| at most this [m/s]
    stop_time: float = 0.4        # T of the stop's run-down [s]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` naming the first bad field."""
        _check_positive(gain=self.gain, max_climb=self.max_climb, stop_time=self.stop_time)
        for name in ('integral_gain', 'integral_limit'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name}: {value} must be finite and >= 0')
        if not 0.0 <= self.deadband < 1.0:
            raise ValueError(f'deadband: {self.deadband} must be in [0, 1)')


class DepthHold:
    """The depth loop of the module docstring."""

    def __init__(self, settings: DepthHoldSettings) -> None:
        settings.validate()
        self.settings = settings
        self.target: float | None = None   # z to hold [m, up]; None while the stick drives
        # k_i times the integral of the error [m/s]: what a load the model does not know
        # (a sample picked up, a vehicle trimmed light) needs beyond the velocity loop's own
        # integral. Kept while the stick drives: the load is still there at the next hold.
        self.integral = 0.0
        #: d(w_goal)/dt of the last step [m/s^2]: the stop's, for the velocity loop's inertia
        #: feed-forward (0 while the stick drives or the depth is held).
        self.goal_accel = 0.0
        self._stop: tuple[float, float] | None = None   # (w0 [m/s], time into the stop [s])
        self._driving: float | None = None    # the stick's goal at the previous step [m/s]

    def engage(self, z: float) -> None:
        """Hold ``z`` from now (the vehicle is known to be still, there)."""
        self.target, self._stop, self._driving = z, None, None

    def release(self) -> None:
        """Forget the target: entering the mode, the next steps stop the vehicle, then hold."""
        self.target, self._stop, self._driving = None, None, None

    @property
    def stopping(self) -> bool:
        """Whether the vehicle is being brought to a stop (no target yet)."""
        return self._stop is not None

    def step(self, stick: float, z: float, dt: float = 0.0, w: float = math.nan) -> float:
        """Return the vertical velocity goal [m/s, up] for heave ``stick`` (-1..1) at ``z``.

        ``dt`` [s] since the previous step integrates the error and runs a stop (0: no
        integration and no stop, the depth taken at once); ``w`` [m/s, up]: the measured
        vertical velocity, where a stop starts on entering the mode (NaN: unknown, none).
        """
        s = self.settings
        self.goal_accel = 0.0
        if not math.isfinite(stick):
            stick = 0.0
        stick = max(-1.0, min(1.0, stick))
        if abs(stick) > s.deadband:
            self.target, self._stop = None, None
            self._driving = stick * s.max_climb
            return self._driving
        timed = dt > 0.0 and math.isfinite(dt)
        if self.target is None:
            if self._stop is None:
                w0 = self._driving if self._driving is not None else w
                self._driving = None
                if timed and math.isfinite(w0) and abs(w0) >= STOPPED:
                    self._stop = (max(-s.max_climb, min(s.max_climb, w0)), 0.0)
            if self._stop is not None and timed:
                w0, t = self._stop
                x = (t + dt) / s.stop_time
                if x < STOP_SPAN:
                    self._stop = (w0, t + dt)
                    self.goal_accel = -w0 * x * math.exp(-x) / s.stop_time
                    return w0 * (1.0 + x) * math.exp(-x)
            self.target, self._stop = z, None
        error = self.target - z
        if timed:
            self.integral = max(-s.integral_limit, min(
                s.integral_limit, self.integral + s.integral_gain * error * dt))
        return max(-s.max_climb, min(s.max_climb, s.gain * error + self.integral))


@dataclass(frozen=True)
class HeadingHoldSettings:
    """Settings of :class:`HeadingHold`."""

    gain: float          # k: yaw rate per radian of heading error [1/s]
    max_rate: float      # yaw rate at full stick, and the hold's limit [rad/s]
    deadband: float      # |stick| at or below this is centred (0..1)
    settle_rate: float   # the rate-zero phase ends below this yaw rate [rad/s]
    settle_time: float   # ... or after this long [s]

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` naming the first bad field."""
        _check_positive(gain=self.gain, max_rate=self.max_rate, settle_rate=self.settle_rate,
                        settle_time=self.settle_time)
        if not 0.0 <= self.deadband < 1.0:
            raise ValueError(f'deadband: {self.deadband} must be in [0, 1)')


class HeadingHold:
    """The heading loop of the module docstring."""

    def __init__(self, settings: HeadingHoldSettings) -> None:
        settings.validate()
        self.settings = settings
        self.target: float | None = None     # heading to hold [rad]
        self._settling: float | None = None  # time spent in the rate-zero phase [s]

    def engage(self, psi: float) -> None:
        """Hold ``psi`` from now."""
        self.target, self._settling = psi, None

    def step(self, stick: float, psi: float, r: float, dt: float) -> float:
        """Return the yaw-rate goal [rad/s] for yaw ``stick`` at heading ``psi``, rate ``r``."""
        s = self.settings
        if not math.isfinite(stick):
            stick = 0.0
        stick = max(-1.0, min(1.0, stick))
        if abs(stick) > s.deadband:
            self.target, self._settling = None, None
            return stick * s.max_rate
        if self.target is None:
            # the rate-zero phase: command no rate until the turn has died out
            self._settling = (self._settling or 0.0) + max(dt, 0.0)
            if abs(r) >= s.settle_rate and self._settling < s.settle_time:
                return 0.0
            self.target, self._settling = psi, None
        return max(-s.max_rate, min(s.max_rate, s.gain * ssa(self.target - psi)))
