"""The node around a device emulator that measures the simulated vessel (lidar, motion capture).

Such an emulator serves its device on an endpoint (a pty path, a loopback address) and
measures the vessel where the simulator says it is. ``DeviceEmulatorNode`` is what their
nodes share: the settings, the emulator made from them, its endpoint offered under the
node's ``name`` in ``emulation`` when it is plugged in (``start``) and withdrawn when it
goes, the truth from ``sim/odometry``, a report on ``/diagnostics`` every second, and the
emulator stopped when the node is destroyed. Constructing the node opens nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from nav_msgs.msg import Odometry

from enbarr_core.framework.driver import OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation

#: How often the emulator reports what it received and sent [s].
REPORT_PERIOD = 1.0


class Emulator(Protocol):
    """What the node needs of an emulator."""

    def start(self) -> Any:
        """Plug the device in: open its endpoint (again) and serve it."""

    def stop(self) -> None:
        """Unplug it: close the endpoint and every connection."""

    def set_pose(self, x: float, y: float, psi: float) -> None:
        """Set the vessel's pose in odom [m, m, rad]."""


class DeviceEmulatorNode(EnbarrNode):
    """A device emulator's node; see the module docstring.

    A subclass names its endpoint ``kind`` (``emulation.KINDS``) and ``device`` (for
    people), builds its emulator in ``make_emulator`` with the two callbacks to call when
    the endpoint appears and goes, applies live settings in ``apply`` and says what it did in
    ``report``. Its settings carry the emulator's ``name``.
    """

    device_emulator = True  # bringup builds and starts it before the drivers
    kind = ''
    device = ''

    def __init__(self, node_name: str, specs: Sequence[ParamSpec],
                 build: Callable[[dict[str, Any]], Any], **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: Any
        self.emulator: Any = None
        self.bind_settings(specs, build, self._apply)
        self.emulator = self.make_emulator(self.settings, self._plugged, self._unplugged)
        self.poses = 0
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)
        self.create_periodic(REPORT_PERIOD, self._report)

    # -- what a subclass implements -----------------------------------------------------------
    def make_emulator(self, settings: Any, plugged: Callable[[Any], None],
                      unplugged: Callable[[Any], None]) -> Emulator:
        """Build the emulator (nothing opened yet)."""
        raise NotImplementedError

    def apply(self, settings: Any) -> None:
        """Hand changed settings to the running emulator."""

    def report(self) -> tuple[str, dict[str, Any]]:
        """Return what the emulator is doing (the status message) and its counters."""
        raise NotImplementedError

    # -- the shared part ----------------------------------------------------------------------
    def start(self) -> None:
        """Plug the device in (its endpoint opens), then start the sources."""
        self.emulator.start()
        super().start()

    def _apply(self, settings: Any) -> None:
        self.settings = settings
        if self.emulator is not None:
            self.apply(settings)

    def _plugged(self, endpoint: Any) -> None:
        emulation.register(self.kind, self.settings.name, endpoint, owner=self)
        self.get_logger().info(f'{self.device} emulator {self.settings.name!r} on '
                               f'{describe(endpoint)}')

    def _unplugged(self, endpoint: Any) -> None:
        emulation.unregister(self.kind, self.settings.name, endpoint)

    def _on_truth(self, msg: Odometry) -> None:
        eta = convert.pose_to_eta(msg.pose.pose)
        self.emulator.set_pose(float(eta[0]), float(eta[1]), float(eta[2]))
        self.poses += 1

    def _report(self) -> None:
        message, values = self.report()
        self.publish_diagnostics(OK, message, {**values, 'poses': self.poses})

    def destroy_node(self) -> None:
        """Unplug the device (its endpoint is withdrawn), then destroy the node."""
        if self.emulator is not None:
            self.emulator.stop()
        super().destroy_node()


def describe(endpoint: Any) -> str:
    """Name an endpoint for people: a path as it is, a (host, port) as ``tcp://host:port``."""
    if isinstance(endpoint, tuple) and len(endpoint) == 2:
        return f'tcp://{endpoint[0]}:{endpoint[1]}'
    return str(endpoint)


def commands_line(commands: dict[str, int]) -> str:
    """``NAME=COUNT`` of the commands an emulator received, sorted, for ``/diagnostics``."""
    return ' '.join(f'{k}={v}' for k, v in sorted(commands.items()))
