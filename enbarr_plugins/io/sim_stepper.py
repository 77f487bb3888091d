"""Simulated stepper motor (the manipulator): ``io_request`` int32 = steps to move.

The position moves toward its target at ``max_rate`` steps/s, within ``[min_position,
max_position]`` (a request beyond them is refused, as a real manipulator's end stops would
demand); ``io_state`` carries the position while it changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from enbarr_core.framework.params import ParamSpec

from enbarr_plugins.io.base import IoPluginNode

SPECS = [
    ParamSpec('executor', '', 'Executor name this stepper answers to (default: node name)',
              read_only=True),
    ParamSpec('max_rate', 400.0, 'Step rate', 'steps/s', 1.0, 1e5),
    ParamSpec('min_position', -10000, 'Lowest position (end stop)', 'steps', -2**31, 2**31 - 1),
    ParamSpec('max_position', 10000, 'Highest position (end stop)', 'steps', -2**31, 2**31 - 1),
    ParamSpec('update_rate', 10.0, 'Rate of the simulated motion', 'Hz', 1.0, 1000.0,
              read_only=True),
]


@dataclass(frozen=True)
class SimStepperSettings:
    """Settings of ``SimStepperNode`` (see ``SPECS``)."""

    executor: str        # executor name ('' : the node name)
    max_rate: float      # [steps/s]
    min_position: int    # end stop [steps]
    max_position: int    # end stop [steps]
    update_rate: float   # rate of the simulated motion [Hz]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimStepperSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        if v['min_position'] > v['max_position']:
            raise ValueError('min_position must not exceed max_position')
        return cls(executor=v['executor'], max_rate=v['max_rate'],
                   min_position=v['min_position'], max_position=v['max_position'],
                   update_rate=v['update_rate'])


class SimStepperNode(IoPluginNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'manipulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimStepperSettings
        self.bind_settings(SPECS, SimStepperSettings.from_params, self._apply)
        self.executor_name = self.settings.executor or self.get_name()
        self.position = 0.0
        self.target = 0
        # Runs while a move is under way only: a stepper at rest costs no executor wake-up.
        self._mover = self.create_timer(1.0 / self.settings.update_rate, self._move,
                                        autostart=False)

    def _apply(self, settings: SimStepperSettings) -> None:
        self.settings = settings

    def act(self, value: Any) -> str | None:
        """Move the target by ``value`` steps, within the end stops."""
        if isinstance(value, bool) or not isinstance(value, int):
            return 'expected an integer number of steps'
        target = self.target + value
        s = self.settings
        if not s.min_position <= target <= s.max_position:
            return f'target {target} is outside [{s.min_position}, {s.max_position}] steps'
        self.target = target
        if target != self.position and self._mover.is_canceled():
            self._mover.reset()
        return None

    def _move(self) -> None:
        error = self.target - self.position
        if error == 0:
            self._mover.cancel()
            if self.target != self.position:  # a move asked for meanwhile (another thread)
                self._mover.reset()
            return
        step = self.settings.max_rate / self.settings.update_rate
        self.position = float(self.target) if abs(error) <= step else (
            self.position + step * (1 if error > 0 else -1))
        self.publish_state(int(round(self.position)))
