"""The node of a chaos run in this process: it watches control and the actuators, and injects.

Control outputs (``thruster_commands``, ``pwm/duty_cycle``) are timed on receipt; actuator
outputs are kept with their own stamps and whether they were neutral; the operator's goals,
io requests, modes and forces are kept to tell whether an injected command was executed.
"""

from __future__ import annotations

from collections.abc import Callable
import threading
import time
from typing import Any

#: Operator command topics: an injection there is also a second source (see ``judge``).
COMMAND_TOPICS = ('surface_command/twist', 'surface_command/io', 'joy')


class Observer:
    """A node in this process that watches the control and actuator outputs and injects."""

    CONTROL_TOPICS = ('thruster_commands', 'pwm/duty_cycle')
    ACTUATOR_TOPICS = ('thruster_output', 'sim/azimuth_command')

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        from enbarr_interfaces import topics

        self.topics = {t.name: t for t in topics.ALL_TOPICS}
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node('enbarr_chaos', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.control: list[int] = []                   # receive ns of control outputs
        self.actuators: list[tuple[int, bool]] = []    # (stamp ns, neutral)
        self.goals: list[tuple[int, Any]] = []         # trajectory_request
        self.io: list[tuple[int, Any]] = []            # io_request
        self.modes: list[tuple[int, str]] = []
        self.latest: dict[str, Any] = {}               # last sample of each watched input
        self._subs: list[Any] = []
        for name in self.CONTROL_TOPICS:
            self._watch(name, lambda m: self.control.append(time.time_ns()))
        for name in self.ACTUATOR_TOPICS:
            self._watch(name, self._on_actuator)
        self._watch('trajectory_request', lambda m: self.goals.append((time.time_ns(), m)))
        self._watch('io_request', lambda m: self.io.append((time.time_ns(), m)))
        self._watch('mode', lambda m: self.modes.append((time.time_ns(), m.data)))
        self.forces: list[tuple[int, float]] = []      # force_command surge [N]
        if 'force_command' in self.topics:
            self._watch('force_command', lambda m: self.forces.append(
                (time.time_ns(), m.wrench.force.x)))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _watch(self, name: str, callback: Callable[[Any], None]) -> None:
        spec = self.topics[name]
        self._subs.append(self.node.create_subscription(spec.msg_type, name, callback,
                                                        spec.qos))

    def _on_actuator(self, msg: Any) -> None:
        from enbarr_interfaces.convert import stamp_to_ns
        stamp = stamp_to_ns(msg.header.stamp) or time.time_ns()
        self.actuators.append((stamp, not any(msg.effort)))

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - a shutdown race at the end of a run
                if self._stop.is_set():
                    return
                raise

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        import rclpy
        self._stop.set()
        self._thread.join(5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # -- state -----------------------------------------------------------------------------
    def busy(self, within_s: float = 0.3) -> bool:
        """Control output flowing and the actuators driving (not neutral) right now."""
        now = time.time_ns()
        recent = self.control and now - self.control[-1] < within_s * 1e9
        return bool(recent and self.actuators and not self.actuators[-1][1]
                    and now - self.actuators[-1][0] < within_s * 1e9)

    def wait_busy(self, timeout: float, steady_s: float = 0.5) -> bool:
        """Wait until ``busy()`` has held for ``steady_s``."""
        deadline = time.monotonic() + timeout
        since: float | None = None
        while time.monotonic() < deadline:
            if self.busy():
                since = since or time.monotonic()
                if time.monotonic() - since >= steady_s:
                    return True
            else:
                since = None
            time.sleep(0.05)
        return False

    def stamped_inputs(self, control_nodes: frozenset[str]) -> list[str]:
        """Contract topics with a header that a control node takes from outside its group."""
        found = []
        for name, spec in self.topics.items():
            if 'header' not in spec.msg_type.get_fields_and_field_types():
                continue
            topic = '/' + name.lstrip('/')
            subs = self.node.get_subscriptions_info_by_topic(topic)
            # Fed from outside the control group: a fast topic produced inside it reaches its
            # subscribers in-process (their graph readers are never read), so a sample
            # injected over DDS would never arrive there.
            pubs = self.node.get_publishers_info_by_topic(topic)
            if any(s.node_name in control_nodes for s in subs) and \
                    any(p.node_name not in control_nodes for p in pubs):
                found.append(name)
        return found

    def command_topics(self, control_nodes: frozenset[str]) -> list[str]:
        """Name the operator command topics a control node subscribes to, someone publishes."""
        found = []
        for name in COMMAND_TOPICS:
            subs = self.node.get_subscriptions_info_by_topic('/' + name)
            if any(s.node_name in control_nodes for s in subs) and \
                    self.node.count_publishers('/' + name) > 0:
                found.append(name)
        return found

    def sample_of(self, name: str, timeout: float = 3.0) -> Any | None:
        """Return the last real sample of input ``name`` (subscribing on first use)."""
        if name not in self.latest:
            self.latest[name] = None
            self._watch(name, lambda m, n=name: self.latest.__setitem__(n, m))
        deadline = time.monotonic() + timeout
        while self.latest[name] is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.latest[name]

    def publisher(self, name: str, timeout: float = 5.0) -> Any:
        """Return a publisher on ``name`` once every existing subscriber matched it."""
        spec = self.topics[name]
        pub = self.node.create_publisher(spec.msg_type, name, spec.qos)
        want = len([s for s in self.node.get_subscriptions_info_by_topic('/' + name)
                    if s.node_name != self.node.get_name()])
        deadline = time.monotonic() + timeout
        while pub.get_subscription_count() < want and time.monotonic() < deadline:
            time.sleep(0.02)
        return pub
