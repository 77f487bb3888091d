"""The contract every device driver meets, real or simulated.

ros2_control's hardware interfaces play the same part.

A driver is an ``EnbarrNode`` with a device behind it. The base classes own what every driver
must get right, so a new driver writes only its device's bytes:

- **lifecycle**: constructing a driver opens nothing (it declares and validates its
  parameters and creates its topics): ``bringup --check`` builds every node of a profile and
  must touch no device. ``start()`` opens the device (``connect()`` -> ``open_device()``)
  before it starts the sources, the line ROS 2 managed nodes draw between *configure* and
  *activate*; ``stop()`` stops the sources; destruction closes the device. A ``DeviceError``
  from ``open_device()`` (device absent) or from ``device_fault()`` later (unplugged, stalled,
  corrupted frames, wrong identity) closes the device, counts the fault, logs it, puts the
  actuators in their safe state and retries ``open_device()`` with exponential backoff
  (``reconnect.initial_delay`` doubling up to ``reconnect.max_delay``) until the device
  returns. The process and the other nodes keep running. A simulated twin has nothing to
  open and never faults.
- **confirmation**: a device is back when it has answered, not when it could be opened.
  Where ``open_device()`` reads the device's identity (I2C chips, the Arduino's handshake),
  opening confirms it. A driver whose open only starts a reader (a serial stream, a TCP
  client) sets ``confirmed_by_open = False`` and calls ``device_confirmed()`` on the first
  valid sample or identity answer (a ``SensorDriver`` does so in ``sample_received()``); until
  then the retry delay keeps growing, so a dead server is not "back" every half second.
- **diagnostics**: one ``diagnostic_msgs/DiagnosticArray`` status per node on
  ``/diagnostics`` every ``REPORT_PERIOD``: OK while the device works, ERROR with the last
  fault while it does not, WARN while a sensor's samples are late; the values are the
  driver's counters (``status_values()``).
- **actuators** (``ActuatorDriver``): a ``CommandWatchdog`` that puts the outputs in their
  safe state when commands stop for ``command_timeout`` (wall clock, like an ESC's own
  watchdog), ``safe_state()`` on every bringup exit path, and neutral at start. The command
  period is measured: a ``command_timeout`` shorter than two periods (the watchdog would trip
  between commands) is refused when set live, and reported (WARN) when a start value is.
- **sensors** (``SensorDriver``): ``sample_received()`` per sample; no sample for
  ``sample_timeout`` is reported as stale.

One supervision timer per driver runs the watchdog, the reconnect schedule and the report
(every executor wake-up costs CPU): every ``WATCHDOG_PERIOD`` for actuators, every
``SUPERVISION_PERIOD`` for the others.
"""

from __future__ import annotations

from collections.abc import Callable
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.health import IntervalMeter, too_short_for_rate
from enbarr_core.framework.node import EnbarrNode, RateLoop, WATCHDOG_PERIOD
from enbarr_core.framework.params import ParamSpec

#: How often a driver reports on ``/diagnostics`` [s].
REPORT_PERIOD = 1.0
#: Supervision period of drivers without a command watchdog [s]: the reconnect schedule's
#: resolution.
SUPERVISION_PERIOD = 0.5

OK = DiagnosticStatus.OK[0] if isinstance(DiagnosticStatus.OK, bytes) else DiagnosticStatus.OK
WARN = (DiagnosticStatus.WARN[0] if isinstance(DiagnosticStatus.WARN, bytes)
        else DiagnosticStatus.WARN)
ERROR = (DiagnosticStatus.ERROR[0] if isinstance(DiagnosticStatus.ERROR, bytes)
         else DiagnosticStatus.ERROR)

RECONNECT_SPECS = [
    ParamSpec('reconnect.initial_delay', 0.5, 'First retry after a device fault', 's', 0.01,
              60.0),
    ParamSpec('reconnect.max_delay', 10.0, 'Longest wait between retries (the delay doubles '
              'after each failed attempt)', 's', 0.01, 600.0),
]


class Backoff:
    """Exponential retry schedule: ``initial``, 2x, 4x ... capped at ``maximum`` [s]."""

    def __init__(self, initial: float, maximum: float) -> None:
        self.initial = initial
        self.maximum = max(maximum, initial)
        self.delay = initial
        self.next_ns: int | None = None  # monotonic time of the next attempt, None: idle

    def schedule(self, now_ns: int) -> float:
        """Plan the next attempt after a failure; return its delay [s]."""
        delay = self.delay
        self.next_ns = now_ns + int(delay * 1e9)
        self.delay = min(self.delay * 2.0, self.maximum)
        return delay

    def due(self, now_ns: int) -> bool:
        """Whether the next attempt is due at ``now_ns``."""
        return self.next_ns is not None and now_ns >= self.next_ns

    def reset(self) -> None:
        """Back to the initial delay, nothing scheduled (the device works)."""
        self.delay = self.initial
        self.next_ns = None


class CommandWatchdog:
    """Neutral when commands stop: the guard of every actuator.

    The driver applies each command with ``lock`` held and calls ``fed()``. ``check()`` (run
    by the driver's supervision timer) tests, under the same lock, whether the output is not
    already neutral and no command came for ``timeout`` seconds; then it calls
    ``go_neutral()`` (lock held), counts it in ``timeouts`` and returns True.
    Wall-clock (monotonic) time, like the watchdog of a real ESC or Arduino firmware.
    """

    def __init__(self, is_neutral: Callable[[], bool], go_neutral: Callable[[], None]) -> None:
        self.lock = threading.Lock()
        self.timeout_ns = 0
        self.timeouts = 0
        self.period = IntervalMeter()  # of the commands, on the monotonic clock
        self._last_ns = 0
        self._is_neutral = is_neutral
        self._go_neutral = go_neutral

    def set_timeout(self, seconds: float) -> None:
        """Set the command timeout [s]."""
        self.timeout_ns = int(seconds * 1e9)

    def fed(self) -> None:
        """Note a command applied just now (call with ``lock`` held)."""
        self._last_ns = time.monotonic_ns()
        self.period.add(self._last_ns)

    def __enter__(self) -> CommandWatchdog:
        """Apply one command (``with watchdog:``): the lock held, the watchdog fed."""
        # A plain context manager, not a @contextmanager generator: entered for every command
        # (a generator's machinery cost more than the lock and the feed).
        self.lock.acquire()
        try:
            self.fed()
        except BaseException:
            self.lock.release()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.lock.release()

    def check(self) -> bool:
        """Go neutral if commands stopped; True when it did."""
        with self.lock:
            if self._is_neutral() or time.monotonic_ns() - self._last_ns <= self.timeout_ns:
                return False
            self.timeouts += 1
            self._go_neutral()
        return True


class DeviceNode(EnbarrNode):
    """A node with a device behind it; see the module docstring.

    Subclasses override ``open_device``/``close_device`` (nothing to do for a simulated
    twin), call ``device_fault(err)`` when the device fails at run time, and add their
    counters in ``status_values``. Their constructor opens nothing: ``start()`` connects.
    Their ``safe_state`` must not raise while the device is gone (it runs on every fault).
    """

    #: Whether a successful ``open_device()`` proves the device is there (it read an
    #: identity). False for drivers whose open only starts a reader: they call
    #: ``device_confirmed()`` on the first valid sample or answer.
    confirmed_by_open = True

    def __init__(self, node_name: str, *, device: str = 'simulated', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        #: What the device is, for people: 'simulated', '/dev/ttyACM0', 'i2c-1 0x40' ...
        self.device = device
        self.connected = False    # open_device() succeeded and no fault since
        self.confirmed = False    # ... and the device answered (see confirmed_by_open)
        self.faults = 0
        self.last_fault = ''
        self._report_ns = 0
        self._open_loop: RateLoop | None = None
        self._open_requested = False
        self._backoff = self.bind_settings(RECONNECT_SPECS, self._build_backoff,
                                           self._apply_backoff).settings
        self.create_periodic(self.supervision_period, self._supervise)

    #: Period of the supervision timer [s].
    supervision_period = SUPERVISION_PERIOD

    # -- what a driver implements -----------------------------------------------------------
    def open_device(self) -> None:
        """Open and check the device; raise ``DeviceError`` naming it when it cannot."""

    def close_device(self) -> None:
        """Release the device (after a fault and on destruction); must not raise."""

    def status_values(self) -> dict[str, Any]:
        """Counters and states for ``/diagnostics``."""
        return {}

    def supervise(self) -> None:
        """Periodic check of the subclass (every ``WATCHDOG_PERIOD``)."""

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Open the device (unless open, or a retry is scheduled), then start the sources.

        Actuators are put in their safe state in between: neutral before the first command,
        also after a restart.
        """
        if not self.connected and self._backoff.next_ns is None:
            self.connect()
        self.safe_state()
        super().start()

    def open_on(self, loop: RateLoop) -> None:
        """Open the device on ``loop``'s thread once the loop runs, never on the executor's.

        For a driver whose open may block (a stalled bus, a camera): the first open, in
        ``start`` before the loop runs, is made in place, so that an absent device is reported
        at once; a later one (a reconnect) is left to the loop, whose callback calls
        ``open_if_requested()`` while the device is not connected.
        """
        self._open_loop = loop

    def open_if_requested(self) -> None:
        """On the loop of ``open_on``: open the device now if a reconnect asked for it."""
        if self._open_requested:
            self._open_requested = False
            self.connect()

    def connect(self) -> bool:
        """Try to open the device now; on failure schedule a retry. True when connected.

        With ``open_on``, a call from another thread than the running loop's only asks the
        loop to open it (and returns False).
        """
        loop = self._open_loop
        if loop is not None and loop.running and threading.current_thread().name != loop.name:
            self._open_requested = True
            return False
        try:
            self.open_device()
        except DeviceError as err:
            self._fail(err)
            return False
        self.connected = True
        if self.confirmed_by_open:
            self.device_confirmed()
        return True

    def device_confirmed(self) -> None:
        """Note that the device answered (a valid sample, its identity): back, backoff reset.

        Called from the driver's reader thread; cheap when already confirmed.
        """
        if self.confirmed or not self.connected:
            return
        self.confirmed = True
        self._backoff.reset()
        if self.faults:
            self.get_logger().info(f'{self.device}: device back')

    def device_fault(self, err: DeviceError) -> None:
        """Handle a run-time failure of the device: safe state, close, retry with backoff."""
        if not self.connected:
            return
        self._fail(err)

    def _fail(self, err: DeviceError) -> None:
        self.connected = self.confirmed = False
        self.faults += 1
        self.last_fault = str(err)
        self.safe_state()
        try:
            self.close_device()
        except Exception as close_err:  # noqa: BLE001 - a dying device may raise anything
            self.get_logger().warn(f'{self.device}: close failed: {close_err!r}')
        delay = self._backoff.schedule(time.monotonic_ns())
        text = str(err)  # transport errors name the device already: say it once
        where = '' if text.startswith(self.device) else f'{self.device}: '
        self.get_logger().error(f'{where}{text} (fault {self.faults}; retry in {delay:.2g} s)',
                                throttle_duration_sec=1.0)

    def _supervise(self) -> None:
        if not self.started:  # nothing is open before start, nothing to report after stop
            return
        now = time.monotonic_ns()
        if not self.connected and self._backoff.due(now):
            self.connect()
        self.supervise()
        if now - self._report_ns >= REPORT_PERIOD * 1e9:
            self._report_ns = now
            level, message = self.status()
            self.publish_diagnostics(level, message, {
                'device': self.device, 'connected': self.connected,
                'confirmed': self.confirmed, 'faults': self.faults, **self.status_values()})

    def status(self) -> tuple[int, str]:
        """Diagnostic level and message of the driver now."""
        if not self.connected:
            return ERROR, f'device fault: {self.last_fault}'
        if not self.confirmed:
            return WARN, 'opened, waiting for the device to answer'
        return OK, 'ok'

    @staticmethod
    def _build_backoff(v: dict[str, Any]) -> Backoff:
        if v['reconnect.max_delay'] < v['reconnect.initial_delay']:
            raise ValueError('reconnect.max_delay must not be shorter than '
                             'reconnect.initial_delay')
        return Backoff(v['reconnect.initial_delay'], v['reconnect.max_delay'])

    def _apply_backoff(self, backoff: Backoff) -> None:
        old = getattr(self, '_backoff', None)
        if old is not None:
            backoff.next_ns = old.next_ns
        self._backoff = backoff

    def destroy_node(self) -> None:
        """Close the device, then destroy the node."""
        if self.connected:
            self.connected = self.confirmed = False
            try:
                self.close_device()
            except Exception:  # noqa: BLE001 - destruction goes on
                pass
        super().destroy_node()


class ActuatorDriver(DeviceNode):
    """A driver of outputs: command watchdog, safe state, neutral at start.

    Subclasses implement ``is_neutral()`` and ``write_neutral()`` (called with
    ``watchdog.lock`` held) and apply each command inside ``with self.commanding():``.
    """

    supervision_period = WATCHDOG_PERIOD

    def __init__(self, node_name: str, *, command_timeout: float = 0.25,
                 timeout_message: str = 'commands stopped: outputs neutral',
                 **kwargs: Any) -> None:
        self.watchdog = CommandWatchdog(self.is_neutral, self.write_neutral)
        self._timeout_message = timeout_message
        super().__init__(node_name, **kwargs)
        self.bind_settings([ParamSpec(
            'command_timeout', command_timeout, 'Outputs neutral when commands stop for this '
            'long', 's', 0.005, 10.0)], self._build_timeout, self.watchdog.set_timeout)

    def _build_timeout(self, v: dict[str, Any]) -> float:
        timeout: float = v['command_timeout']
        reason = self._timeout_too_short(timeout)
        if reason:
            raise ValueError(reason)
        return timeout

    def _timeout_too_short(self, timeout: float) -> str | None:
        """Why ``timeout`` [s] is too short for the measured command period, or None."""
        return too_short_for_rate('command_timeout', timeout, 'its commands',
                                  self.watchdog.period.period, 'the watchdog would put the '
                                  'outputs neutral between commands')

    def is_neutral(self) -> bool:
        """Whether the outputs are in their safe state now."""
        raise NotImplementedError

    def write_neutral(self) -> None:
        """Put the outputs in their safe state (``watchdog.lock`` held)."""
        raise NotImplementedError

    @property
    def timeouts(self) -> int:
        """How often the watchdog put the outputs neutral."""
        return self.watchdog.timeouts

    def commanding(self) -> CommandWatchdog:
        """Apply one command (``with self.commanding():``): the watchdog's lock held, fed."""
        return self.watchdog

    def safe_state(self) -> None:
        """Put the outputs neutral now (every bringup exit path, device faults)."""
        with self.watchdog.lock:
            self.write_neutral()

    def supervise(self) -> None:
        """Run the command watchdog."""
        if self.watchdog.check():
            self.get_logger().warn(self._timeout_message)

    def status(self) -> tuple[int, str]:
        """Return the device status, WARN when command_timeout is too short for the commands."""
        level, message = super().status()
        reason = self._timeout_too_short(self.watchdog.timeout_ns * 1e-9)
        if level == OK and reason:
            return WARN, reason
        return level, message

    def status_values(self) -> dict[str, Any]:
        """Return whether the outputs are neutral and the watchdog count."""
        return {'neutral': self.is_neutral(), 'timeouts': self.timeouts}


class SensorDriver(DeviceNode):
    """A driver of measurements: reports stale when samples stop for ``sample_timeout``."""

    def __init__(self, node_name: str, *, sample_timeout: float = 1.0, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.samples = 0
        self._last_sample_ns: int | None = None
        self._sample_timeout_ns = int(self.bind_settings([ParamSpec(
            'sample_timeout', sample_timeout, 'Reported stale when no sample comes for this '
            'long', 's', 0.01, 600.0)], lambda v: v['sample_timeout'],
            self._apply_sample_timeout).settings * 1e9)

    def _apply_sample_timeout(self, seconds: float) -> None:
        self._sample_timeout_ns = int(seconds * 1e9)

    def sample_received(self) -> None:
        """Count one valid sample published (call from the sample path; cheap).

        The first one after an open confirms the device (``device_confirmed``).
        """
        self.samples += 1
        self._last_sample_ns = time.monotonic_ns()
        if not self.confirmed:
            self.device_confirmed()

    @property
    def stale(self) -> bool:
        """No sample for ``sample_timeout`` (or none yet)."""
        last = self._last_sample_ns
        return last is None or time.monotonic_ns() - last > self._sample_timeout_ns

    def status(self) -> tuple[int, str]:
        """Return ERROR while faulted, WARN while samples are late, else OK."""
        level, message = super().status()
        if level == OK and self.stale:
            return WARN, 'no samples' if self._last_sample_ns is None else 'samples stopped'
        return level, message

    def status_values(self) -> dict[str, Any]:
        """Return the sample count."""
        return {'samples': self.samples}
