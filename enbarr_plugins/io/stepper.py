"""A step/dir stepper driver (A4988, DRV8825, TMC2208 ...) on Raspberry Pi GPIO pins.

The real twin of ``sim_stepper`` (the manipulator): an ``io_request`` int32 addressed to the
``executor`` name moves the target by that many steps, within ``[min_position,
max_position]`` (a request beyond them, or of another type, is refused and counted);
``io_state`` carries the position while it changes (at most every ``state_period``) and when
the move ends.

Pins (BCM numbers, gpiozero ``DigitalOutputDevice`` on ``pin_factory``, see ``io/pins.py``):
``step_pin`` gets one pulse per step (the driver steps on the rising edge; the pulse is as
long as two gpiozero writes, tens of microseconds, well above the 1-2 us minimum of the
A4988 and DRV8825 data sheets), ``dir_pin`` is high for positive steps, set before the first
step of a move, and ``enable_pin`` (-1: none wired; active low on those drivers, see
``enable_active_low``) enables the motor current only while moving or holding.

Steps are made on the node's own thread at ``max_rate`` steps/s with absolute deadlines, so
a request never blocks the executor or the publisher's thread. ``safe_state`` (every
bringup exit path and device faults) stops the motion where it is and disables the driver
(the motor then holds no torque: a manipulator that must hold a load needs a brake).
A pin that fails to be written, or a GPIO chip that cannot be opened, is a ``DeviceError``
naming the pins: reported on ``/diagnostics``, retried with backoff; the position counter is
kept (open loop: check it after a fault).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import threading
import time
from typing import Any

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec

from enbarr_plugins.io.base import IoPluginNode
from enbarr_plugins.io.pins import (
    PIN_FACTORY_SPEC, check_factory_name, close_quietly, gpio_errors, open_outputs, Output)

SPECS = [
    ParamSpec('executor', '', 'Executor name this stepper answers to (default: node name)',
              read_only=True),
    ParamSpec('step_pin', 18, 'BCM pin of STEP', '', 0, 27, read_only=True),
    ParamSpec('dir_pin', 23, 'BCM pin of DIR (high: positive steps)', '', 0, 27,
              read_only=True),
    ParamSpec('enable_pin', 24, 'BCM pin of ENABLE, -1 when not wired', '', -1, 27,
              read_only=True),
    ParamSpec('enable_active_low', True, 'ENABLE is active low (A4988, DRV8825)',
              read_only=True),
    ParamSpec('max_rate', 400.0, 'Step rate', 'steps/s', 1.0, 5000.0),
    ParamSpec('min_position', -10000, 'Lowest position (end stop)', 'steps', -2**31, 2**31 - 1),
    ParamSpec('max_position', 10000, 'Highest position (end stop)', 'steps', -2**31, 2**31 - 1),
    ParamSpec('state_period', 0.1, 'io_state at most this often while moving', 's', 0.01,
              10.0),
    PIN_FACTORY_SPEC,
]


@dataclass(frozen=True)
class StepperSettings:
    """Settings of ``StepperNode`` (see ``SPECS``)."""

    executor: str
    step_pin: int
    dir_pin: int
    enable_pin: int           # -1: not wired
    enable_active_low: bool
    max_rate: float           # [steps/s]
    min_position: int         # [steps]
    max_position: int         # [steps]
    state_period: float       # [s]
    pin_factory: str

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> StepperSettings:
        """Build from the declared parameters' values; ValueError names the parameter."""
        if v['min_position'] > v['max_position']:
            raise ValueError('min_position must not exceed max_position')
        pins = [v['step_pin'], v['dir_pin']] + ([v['enable_pin']] if v['enable_pin'] >= 0
                                                else [])
        if len(set(pins)) != len(pins):
            raise ValueError(f'step_pin/dir_pin/enable_pin: must differ, got {pins}')
        return cls(executor=v['executor'], step_pin=v['step_pin'], dir_pin=v['dir_pin'],
                   enable_pin=v['enable_pin'], enable_active_low=v['enable_active_low'],
                   max_rate=v['max_rate'], min_position=v['min_position'],
                   max_position=v['max_position'], state_period=v['state_period'],
                   pin_factory=check_factory_name(v['pin_factory']))


class StepperNode(IoPluginNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'manipulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: StepperSettings
        self.bind_settings(SPECS, StepperSettings.from_params, self._apply)
        s = self.settings
        self.executor_name = s.executor or self.get_name()
        en = f'/EN{s.enable_pin}' if s.enable_pin >= 0 else ''
        self.device = f'GPIO STEP{s.step_pin}/DIR{s.dir_pin}{en} ({s.pin_factory})'
        self.position = 0
        self.target = 0
        self.steps = 0
        self.factory: Any = None
        self._pins: tuple[Any, Any, Any] | None = None   # step, dir, enable
        self._cond = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._fault: DeviceError | None = None
        self._halted = False   # safe_state: stop where it is until the next request

    def _apply(self, settings: StepperSettings) -> None:
        self.settings = settings

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Open the pins (motor disabled) and start the stepping thread."""
        s = self.settings
        self.factory, opened = open_outputs(s.pin_factory, [
            Output(s.step_pin), Output(s.dir_pin),
            Output(s.enable_pin, active_high=not s.enable_active_low)], self.device)
        self._pins = (opened[0], opened[1], opened[2])
        self._fault = None
        with self._cond:
            self._stop = False
            self.target = self.position   # a move cut by a fault is not resumed blindly
        self._thread = threading.Thread(target=self._run, name=f'{self.get_name()}_steps',
                                        daemon=True)
        self._thread.start()

    def close_device(self) -> None:
        """Stop the stepping thread, release the pins."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(1.0)
        pins, self._pins = self._pins, None
        factory, self.factory = self.factory, None
        close_quietly(*(pins or ()), factory)

    def supervise(self) -> None:
        """Turn a failure of the stepping thread into a device fault."""
        fault = self._fault
        if fault is not None and self.connected:
            self._fault = None
            self.device_fault(fault)

    # -- requests ----------------------------------------------------------------------------
    def act(self, value: Any) -> str | None:
        """Move the target by ``value`` steps, within the end stops."""
        if isinstance(value, bool) or not isinstance(value, int):
            return 'expected an integer number of steps'
        s = self.settings
        with self._cond:
            target = self.target + value
            if not s.min_position <= target <= s.max_position:
                return f'target {target} is outside [{s.min_position}, {s.max_position}] steps'
            if not self.connected:
                return f'{self.device} is not connected ({self.last_fault})'
            self.target = target
            self._halted = False
            self._cond.notify()
        return None

    def safe_state(self) -> None:
        """Stop where it is and disable the motor driver."""
        with self._cond:
            self._halted = True
            self.target = self.position
        pins = self._pins
        if pins is not None and pins[2] is not None:
            try:
                pins[2].off()
            except gpio_errors():
                pass   # the fault is reported by whoever hit it

    # -- the stepping thread -----------------------------------------------------------------
    def _run(self) -> None:
        pins = self._pins
        if pins is None:
            return
        step, direction, enable = pins
        try:
            while True:
                with self._cond:
                    while self.target == self.position and not self._stop:
                        self._cond.wait()
                    if self._stop:
                        return
                self._move(step, direction, enable)
        except gpio_errors() as err:
            self._fault = DeviceError(f'{self.device}: writing a pin failed at position '
                                      f'{self.position}: {err}')

    def _move(self, step: Any, direction: Any, enable: Any) -> None:
        """Step toward the target until it is reached (the target may move meanwhile)."""
        sign = 0
        deadline = time.monotonic()
        last_state = 0.0
        while True:
            with self._cond:
                if self._halted:
                    self.target = self.position
                error = self.target - self.position
                if error == 0 or self._stop:
                    break
            if (error > 0) != (sign > 0) or sign == 0:
                if sign == 0 and enable is not None:
                    enable.on()
                sign = 1 if error > 0 else -1
                direction.value = sign > 0   # DIR before the step edge
            step.on()
            step.off()
            with self._cond:
                self.position += sign
            self.steps += 1
            now = time.monotonic()
            if now - last_state >= self.settings.state_period:
                last_state = now
                self.publish_state(self.position)
            deadline += 1.0 / self.settings.max_rate
            delay = deadline - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            else:
                deadline = time.monotonic()   # late: do not bunch the missed steps
        self.publish_state(self.position)

    def status_values(self) -> dict[str, Any]:
        """Return the request counters, position, target and steps made."""
        return {**super().status_values(), 'position': self.position, 'target': self.target,
                'steps': self.steps}
