"""Leak detector on a Raspberry Pi GPIO input (Blue Robotics SOS leak sensor), through gpiozero.

The SOS sensor's board drives its signal wire high while a probe is wet (``active_high``
true, the default; false for a sensor that pulls low when wet), with the pin's own pull
(``pull``: down, up or none) holding the level while the wire is disconnected. The pin is a
gpiozero ``Pin`` read as an input on the backend named by ``pin_factory`` (``io/pins.py``),
polled every ``poll_period`` on the executor (a GPIO read does not block).

Debounce (``LeakLatch``): the pin must read wet for ``debounce`` seconds in a row before a leak
is declared, so a splash on the connector or a glitch on a long wire is not a leak. Latch: a
declared leak stays reported until the pin has read dry for ``dry_hold`` seconds in a row, so
an intermittent drip (wet, dry, wet) stays one leak and the failsafe acting on it does not
toggle; the operator clears a leak by drying the probe. Dry-hold rather than an operator
"clear" command because it needs no new service or request and cannot clear a probe that is
still wet; ``dry_hold`` is long by default.

Published: ``leak`` (``std_msgs/Bool``, transient-local: a failsafe or a console that starts
late still learns that the hull is flooding; ``sensor_msgs`` has no leak message and a Bool is
what a failsafe needs), on every change and once when the pin is opened. While a leak is
latched the node's ``/diagnostics`` status is ERROR naming the pin.

Faults: a GPIO chip that cannot be opened or a pin that cannot be read is a ``DeviceError``
(``/diagnostics``, retried with backoff); the latch is kept across a fault.
References: gpiozero 2.0 documentation, "API - Pins" (``Pin.function``, ``Pin.pull``,
``Pin.state``); Blue Robotics, "SOS Leak Sensor" technical details (signal high when wet).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import time
from typing import Any

from std_msgs.msg import Bool

from enbarr_core.framework.driver import DeviceNode, ERROR, OK
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.io.pins import (
    check_factory_name, close_quietly, gpio_errors, make_factory, PIN_FACTORY_SPEC)

#: Values of the ``pull`` parameter, as gpiozero's ``Pin.pull`` names them.
PULLS = {'down': 'down', 'up': 'up', 'none': 'floating'}

SPECS = [
    ParamSpec('pin', 27, 'BCM pin number of the leak sensor signal', '', 0, 27,
              read_only=True),
    ParamSpec('active_high', True, 'True: the pin is high while wet (Blue Robotics SOS)',
              read_only=True),
    ParamSpec('pull', 'down', "The pin's pull resistor: 'down', 'up' or 'none'",
              read_only=True),
    ParamSpec('debounce', 0.2, 'A leak is declared after the pin reads wet this long', 's',
              0.0, 10.0),
    ParamSpec('dry_hold', 60.0, 'A declared leak clears after the pin reads dry this long',
              's', 0.0, 3600.0),
    ParamSpec('poll_period', 0.1, 'Pin read period (a whole multiple of 0.1 s)', 's', 0.1,
              1.0, read_only=True),
    PIN_FACTORY_SPEC,
]


@dataclass(frozen=True)
class LeakSettings:
    """Settings of ``LeakGpioNode`` (see ``SPECS``)."""

    pin: int
    active_high: bool
    pull: str           # gpiozero's name: 'down', 'up' or 'floating'
    debounce: float     # [s]
    dry_hold: float     # [s]
    poll_period: float  # [s]
    pin_factory: str

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> LeakSettings:
        """Build from the declared parameters' values; ValueError names the parameter."""
        if v['pull'] not in PULLS:
            raise ValueError(f'pull: one of {", ".join(PULLS)}, got {v["pull"]!r}')
        return cls(pin=v['pin'], active_high=v['active_high'], pull=PULLS[v['pull']],
                   debounce=float(v['debounce']), dry_hold=float(v['dry_hold']),
                   poll_period=round(float(v['poll_period']), 1),
                   pin_factory=check_factory_name(v['pin_factory']))


class LeakLatch:
    """Debounced, latched leak state from raw wet/dry readings (no ROS, explicit time).

    ``update(wet, now)`` returns whether a leak is declared: after ``debounce`` seconds of wet
    readings in a row, until ``dry_hold`` seconds of dry readings in a row.
    """

    def __init__(self, debounce: float, dry_hold: float) -> None:
        self.debounce = debounce
        self.dry_hold = dry_hold
        self.leak = False
        self.leaks = 0                       # leaks declared
        self._since: float | None = None     # start of the run of readings opposing the state

    def update(self, wet: bool, now: float) -> bool:
        """Take one reading at ``now`` [s, monotonic]; return the leak state."""
        if wet == self.leak:
            self._since = None               # the reading agrees: no change pending
            return self.leak
        if self._since is None:
            self._since = now
        if now - self._since >= (self.dry_hold if self.leak else self.debounce):
            self.leak = wet
            self._since = None
            if wet:
                self.leaks += 1
        return self.leak


class LeakGpioNode(DeviceNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'leak', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: LeakSettings
        self.latch = LeakLatch(0.0, 0.0)
        self.bind_settings(SPECS, LeakSettings.from_params, self._apply)
        s = self.settings
        self.device = f'GPIO{s.pin} ({s.pin_factory})'
        self.factory: Any = None
        self.input: Any = None
        self.wet = False                     # the last raw reading
        self._published: bool | None = None
        self._pub = self.create_topic_publisher(topics.LEAK)
        self.create_periodic(s.poll_period, self._poll_now)

    def _apply(self, settings: LeakSettings) -> None:
        self.settings = settings
        self.latch.debounce, self.latch.dry_hold = settings.debounce, settings.dry_hold

    def open_device(self) -> None:
        """Open the pin factory and claim the pin as an input with its pull."""
        s = self.settings
        factory = make_factory(s.pin_factory)
        pin = None
        try:
            pin = factory.pin(s.pin)
            pin.function = 'input'
            pin.pull = s.pull
        except gpio_errors() as err:
            close_quietly(pin, factory)
            raise DeviceError(f'{self.device}: cannot use the pin as an input with pull '
                              f'{s.pull}: {err}') from err
        self.factory, self.input = factory, pin
        self._published = None               # a late joiner gets the state after a reopen

    def close_device(self) -> None:
        """Release the pin and the factory."""
        pin, factory = self.input, self.factory
        self.input = self.factory = None
        close_quietly(pin, factory)

    def _poll_now(self) -> None:
        if self.started:
            self.poll(time.monotonic())

    def poll(self, now: float) -> None:
        """Read the pin once at ``now`` [s, monotonic], update the latch, publish a change."""
        pin = self.input
        if not self.connected or pin is None:
            return
        try:
            level = bool(pin.state)
        except gpio_errors() as err:
            self.device_fault(DeviceError(f'{self.device}: reading the pin failed: {err}'))
            return
        self.wet = level == self.settings.active_high
        leak = self.latch.update(self.wet, now)
        if leak != self._published:
            self._published = leak
            self._pub.publish(Bool(data=leak))
            if leak:
                self.get_logger().error(f'LEAK at {self.device}')
            else:
                self.get_logger().info(f'{self.device}: dry for {self.latch.dry_hold:g} s, '
                                       'leak cleared')

    def status(self) -> tuple[int, str]:
        """ERROR naming the pin while a leak is latched, else the device's status."""
        level, message = super().status()
        if self.latch.leak:
            return ERROR, f'LEAK at {self.device}' + ('' if level == OK else f'; {message}')
        return level, message

    def status_values(self) -> dict[str, Any]:
        """Return the leak state, the raw reading and the count of leaks declared."""
        return {'leak': self.latch.leak, 'wet': self.wet, 'leaks': self.latch.leaks}
