"""A node in an rclpy context of its own: another DDS participant, as another process is.

It plays what the ROS graph sees from outside (``ros2 topic info``, ``ros2 topic echo``, a
publisher in another process): it meets the nodes under test only through DDS, never through
their context's link bus.
"""

from __future__ import annotations

import threading

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


class Participant:
    """``node`` in a context of its own, with its executor; ``close`` ends all three."""

    def __init__(self, name: str) -> None:
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def spin_in_background(self, step: float = 0.05) -> None:
        """Spin the executor on a thread of its own until ``close`` (``step``: the longest
        one spin waits for work [s])."""
        def spin() -> None:
            while not self._stop.is_set():
                self.executor.spin_once(timeout_sec=step)
        self._thread = threading.Thread(target=spin, daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop spinning, destroy the node and shut the context down."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)
