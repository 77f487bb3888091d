"""A tf2 listener in a process of its own: what RViz, Foxglove or ``tf2_ros`` would receive.

Run with ``tf2_msgs`` importable (``support.tf2_msgs_build``). Subscribes to ``/tf`` and the
observer's ``observer/odometry`` at once and to ``/tf_static`` only after the first ``/tf``
message, so that the static frames arrive only if their publisher keeps them for a listener
that joins late (transient local). Prints one JSON object per line on stdout, flushed:

- ``{"kind": "ready"}`` once subscribed;
- ``{"kind": "tf" | "tf_static", "transforms": [[parent, child, stamp_ns, [x, y, z],
  [qx, qy, qz, qw]], ...]}`` per message;
- ``{"kind": "odom", "stamp_ns": ..., "xyz": [...], "quaternion": [...]}`` per estimate;
- ``{"kind": "endpoints", "topic": ..., "publishers": [{"node", "type", "hash",
  "durability", "reliability"}, ...]}`` for each tf topic when its subscription is made;
- ``{"kind": "static_subscribed", "after_tf": n}``.

Stops on SIGINT or SIGTERM (rclpy's own handlers end the spin).
"""

from __future__ import annotations

import json
import sys
from typing import Any

from nav_msgs.msg import Odometry
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

# The listener QoS of tf2_ros (tf2_ros/qos.hpp, Jazzy): DynamicListenerQoS is
# rclcpp::QoS(100) (keep last 100, reliable, volatile); StaticListenerQoS adds transient local.
DYNAMIC_LISTENER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                  reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.VOLATILE)
STATIC_LISTENER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The estimate is offered best effort; a deep queue here keeps this process from dropping any.
ESTIMATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                          reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)


def emit(record: dict[str, Any]) -> None:
    """Print one record as a JSON line, at once (the test reads the pipe after a signal)."""
    sys.stdout.write(json.dumps(record) + '\n')
    sys.stdout.flush()


def stamp_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class Listener(Node):
    """Records ``/tf``, ``/tf_static`` (subscribed late) and the estimate."""

    def __init__(self) -> None:
        super().__init__('tf_listener_test')
        self.tf_count = 0
        self._static: Any = None
        self.create_subscription(TFMessage, '/tf', self._on_tf, DYNAMIC_LISTENER_QOS)
        self.create_subscription(Odometry, '/observer/odometry', self._on_odom, ESTIMATE_QOS)

    def _on_tf(self, msg: TFMessage) -> None:
        self.tf_count += 1
        emit({'kind': 'tf', 'transforms': transforms(msg)})
        if self._static is None:
            self._endpoints('/tf')
            self._static = self.create_subscription(TFMessage, '/tf_static', self._on_static,
                                                    STATIC_LISTENER_QOS)
            emit({'kind': 'static_subscribed', 'after_tf': self.tf_count})
            self._endpoints('/tf_static')

    def _on_static(self, msg: TFMessage) -> None:
        emit({'kind': 'tf_static', 'transforms': transforms(msg)})

    def _on_odom(self, msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        emit({'kind': 'odom', 'stamp_ns': stamp_ns(msg.header.stamp), 'frame': msg.header.frame_id,
              'xyz': [p.x, p.y, p.z], 'quaternion': [q.x, q.y, q.z, q.w]})

    def _endpoints(self, topic: str) -> None:
        emit({'kind': 'endpoints', 'topic': topic, 'publishers': [
            {'node': info.node_name, 'type': info.topic_type, 'hash': str(info.topic_type_hash),
             'durability': info.qos_profile.durability.name,
             'reliability': info.qos_profile.reliability.name}
            for info in self.get_publishers_info_by_topic(topic)]})


def transforms(msg: TFMessage) -> list[list[Any]]:
    """A ``TFMessage`` as plain lists."""
    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        out.append([t.header.frame_id, t.child_frame_id, stamp_ns(t.header.stamp),
                    [tr.x, tr.y, tr.z], [q.x, q.y, q.z, q.w]])
    return out


def main() -> None:
    """Listen until SIGINT or SIGTERM."""
    rclpy.init()
    node = Listener()
    emit({'kind': 'ready'})
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
