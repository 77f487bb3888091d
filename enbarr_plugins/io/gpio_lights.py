"""Lights (or any on/off load) on a Raspberry Pi GPIO pin, through gpiozero.

The real twin of ``sim_gpio``: an ``io_request`` bool addressed to ``gpio_<pin>`` sets the pin
high (true) or low; ``io_state`` reports the level once it is on the pin. Requests for other
executors are ignored, other types refused and counted (``io/base.py``). The pin is a
gpiozero ``DigitalOutputDevice`` (``active_high`` false for a load switched on by a low
level), on the backend named by ``pin_factory`` (``io/pins.py``). IO outputs hold on
``safe_state`` like the simulated twin (lights are not a hazard; the thrusters go neutral).

Faults: a GPIO chip that cannot be opened (no Pi, no permission: a ``DeviceError`` naming the
backend and the reason) or a pin that fails to be written are reported on ``/diagnostics`` and
retried with backoff; the level last asked for is set again when the pin comes back.
References: gpiozero 2.0 documentation, "API - Output Devices" (``DigitalOutputDevice``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec

from enbarr_plugins.io.base import IoPluginNode
from enbarr_plugins.io.pins import (
    PIN_FACTORY_SPEC, check_factory_name, close_quietly, gpio_errors, open_outputs, Output)

SPECS = [
    ParamSpec('pin', 12, 'BCM pin number; the executor name is gpio_<pin>', '', 0, 27,
              read_only=True),
    ParamSpec('initial', False, 'Level at start', read_only=True),
    ParamSpec('active_high', True, 'True: the load is on when the pin is high',
              read_only=True),
    PIN_FACTORY_SPEC,
]


@dataclass(frozen=True)
class GpioLightsSettings:
    """Settings of ``GpioLightsNode`` (see ``SPECS``)."""

    pin: int
    initial: bool
    active_high: bool
    pin_factory: str

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> GpioLightsSettings:
        """Build from the declared parameters' values; ValueError names the parameter."""
        return cls(pin=v['pin'], initial=v['initial'], active_high=v['active_high'],
                   pin_factory=check_factory_name(v['pin_factory']))


class GpioLightsNode(IoPluginNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'lights', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: GpioLightsSettings
        self.bind_settings(SPECS, GpioLightsSettings.from_params, self._apply)
        s = self.settings
        self.executor_name = f'gpio_{s.pin}'
        self.device = f'GPIO{s.pin} ({s.pin_factory})'
        self.level = s.initial
        self.factory: Any = None
        self.output: Any = None

    def _apply(self, settings: GpioLightsSettings) -> None:
        self.settings = settings

    def open_device(self) -> None:
        """Open the pin factory and the pin as an output at the level last asked for."""
        s = self.settings
        self.factory, (self.output,) = open_outputs(
            s.pin_factory, [Output(s.pin, s.active_high, self.level)], self.device)

    def close_device(self) -> None:
        """Release the pin and the factory."""
        output, factory = self.output, self.factory
        self.output = self.factory = None
        close_quietly(output, factory)

    def act(self, value: Any) -> str | None:
        """Set the level; refuse what is not a bool."""
        if not isinstance(value, bool):
            return 'expected a boolean (true = on)'
        self.level = value
        output = self.output
        if output is None:
            return None   # not connected: set when the pin comes back
        try:
            output.value = value
        except gpio_errors() as err:
            self.device_fault(DeviceError(f'{self.device}: writing the pin failed: {err}'))
            return None
        self.publish_state(value)
        return None
