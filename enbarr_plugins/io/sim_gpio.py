"""Simulated Raspberry Pi GPIO output (the lights).

An ``io_request`` bool on ``gpio_<pin>`` sets the pin high or low; ``io_state`` reports the
level.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from enbarr_core.framework.params import ParamSpec

from enbarr_plugins.io.base import IoPluginNode

SPECS = [
    ParamSpec('pin', 12, 'BCM pin number; the executor name is gpio_<pin>', '', 0, 27,
              read_only=True),
    ParamSpec('initial', False, 'Level at start', read_only=True),
]


@dataclass(frozen=True)
class SimGpioSettings:
    """Settings of ``SimGpioNode`` (see ``SPECS``)."""

    pin: int        # BCM pin number
    initial: bool   # level at start

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimGpioSettings:
        """Build from the declared parameters' values."""
        return cls(pin=v['pin'], initial=v['initial'])


class SimGpioNode(IoPluginNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'lights', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimGpioSettings
        self.bind_settings(SPECS, SimGpioSettings.from_params, self._apply)
        self.executor_name = f'gpio_{self.settings.pin}'
        self.level = self.settings.initial

    def _apply(self, settings: SimGpioSettings) -> None:
        self.settings = settings

    def act(self, value: Any) -> str | None:
        """Set the level; refuse what is not a bool."""
        if not isinstance(value, bool):
            return 'expected a boolean (true = high)'
        self.level = value
        self.publish_state(value)
        return None
