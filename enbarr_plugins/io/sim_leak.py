"""Simulated leak sensor: the ``leak`` topic of ``leak_gpio``, flooding at a chosen time.

``leak_at`` [s of world time, ``EnbarrNode.world_time``]: from then on a leak is latched and
published, as the driver publishes a debounced leak; negative: never. For exercising what acts
on a leak (the failsafe, the console) without water. Published once at start (dry) and on the
change, transient-local like the driver's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from std_msgs.msg import Bool

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics

SPECS = [
    ParamSpec('leak_at', -1.0, 'World time at which the hull floods (negative: never)', 's',
              -1.0, 1e6),
]


@dataclass(frozen=True)
class SimLeakSettings:
    """Settings of ``SimLeakNode`` (see ``SPECS``)."""

    leak_at: float  # [s], negative: never

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimLeakSettings:
        """Build from the declared parameters' values."""
        return cls(leak_at=float(v['leak_at']))


class SimLeakNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'leak', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimLeakSettings
        self.bind_settings(SPECS, SimLeakSettings.from_params, self._apply)
        self.leak = False
        self._published: bool | None = None
        self._pub = self.create_topic_publisher(topics.LEAK)
        self.create_periodic(0.1, self._tick)

    def _apply(self, settings: SimLeakSettings) -> None:
        self.settings = settings

    def _tick(self) -> None:
        if not self.started:
            return
        at = self.settings.leak_at
        self.leak = self.leak or (at >= 0.0 and self.world_time() >= at)  # latched
        if self.leak != self._published:
            self._published = self.leak
            self._pub.publish(Bool(data=self.leak))
            if self.leak:
                self.get_logger().error(f'LEAK (simulated, leak_at {at:g} s)')
