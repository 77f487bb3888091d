"""Print the command receiver's failsafe state as it changes, one line each (run as a script).

A probe for tests that run a vessel in a process they cannot look into (another network
namespace): it subscribes to ``/diagnostics`` in the ROS domain and discovery range of its
environment and prints ``failsafe True`` or ``failsafe False`` whenever the receiver's report
changes (with the wall-clock time it saw it), flushed, until it is stopped (SIGINT or
SIGTERM).
"""

from __future__ import annotations

import signal
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import ExternalShutdownException

from enbarr_interfaces import topics

RECEIVER = 'command_receiver'


def main() -> None:
    """Spin until stopped, printing every change of the receiver's ``failsafe`` value."""
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # ends the spin as SIGINT
    rclpy.init()
    node = rclpy.create_node('failsafe_watch')
    last: list[str] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id != RECEIVER:
                continue
            value = {kv.key: kv.value for kv in status.values}.get('failsafe')
            if value is not None and (not last or last[-1] != value):
                last.append(value)
                print(f'failsafe {value} at {time.time():.3f}', flush=True)  # wall clock [s]

    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name, on_diagnostics,
                             topics.DIAGNOSTICS.qos)
    print('watching', flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
