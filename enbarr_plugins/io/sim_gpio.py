"""Simulated Raspberry Pi GPIO output (the README's lights): ``io_request`` bool on
``gpio_<pin>`` sets the pin high or low; ``io_state`` reports the level."""

from __future__ import annotations

from typing import Any

from enbarr_core.framework.params import ParamSpec

from enbarr_plugins.io.base import IoPluginNode

SPECS = [
    ParamSpec('pin', 12, 'BCM pin number; the executor name is gpio_<pin>', '', 0, 27,
              read_only=True),
    ParamSpec('initial', False, 'Level at start', read_only=True),
]


class SimGpioNode(IoPluginNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'lights', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        v = self.bind_settings(SPECS, lambda v: v, lambda _: None).settings
        self.executor_name = f'gpio_{v["pin"]}'
        self.level = v['initial']
        self.connect()

    def act(self, value: Any) -> str | None:
        if not isinstance(value, bool):
            return 'expected a boolean (true = high)'
        self.level = value
        self.publish_state(value)
        return None
