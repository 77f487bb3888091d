"""The time policy across processes: one early IMU sample must not stop control.

The core nodes run in their own group (a split profile), so ``imu/data_raw`` reaches the
filter over DDS and a publisher in this test process reaches it too (a link subscription
falls back to DDS only when no publisher of its topic is in its process: see
``enbarr_interfaces/links.py``). Before the fix, one sample stamped 20 s ahead stopped
``thruster_commands`` for 20 s (the thrusters' 0.25 s watchdog went neutral), and one stamped
0.4 s ahead was enough to trip the watchdog.

"Control continues" is bound as: in the 3 s after each injected sample the thrusters'
watchdog never fires (its ``timeouts`` count on ``/diagnostics`` does not move), no
``thruster_output`` is neutral, and at least 30 outputs reach this process (10 Hz: DDS to a
third process on a loaded 2-core machine delivers far fewer than the 400 Hz the chain runs
at, so gaps between the outputs seen here say nothing; the watchdog's count does).
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import threading
import time
from typing import Any

import numpy as np
import pytest
from support.processes import Output
from support.cli import ENBARR

pytestmark = pytest.mark.e2e

SPLIT_PROFILE = """
include: [enbarr_sim]
nodes:
  filtering: {group: control}
  control_loop: {group: control}
  thruster_converter: {group: control}
  thruster_control:
    parameters: {command_timeout: 1.0}
  surface:
    parameters:
      script: ['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.0']
groups:
  control: {restart_limit: 0}
"""


class Listener:
    """This process on the run's graph: thruster_output and /diagnostics in, imu/data_raw out."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions
        from diagnostic_msgs.msg import DiagnosticArray
        from enbarr_interfaces import topics
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node('hostile_sensor', context=self.context)
        self.outputs: list[tuple[int, bool]] = []  # (stamp [ns], neutral)
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.node.create_subscription(topics.THRUSTER_OUTPUT.msg_type, topics.THRUSTER_OUTPUT.name,
                                      self._on_output, topics.THRUSTER_OUTPUT.qos)
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                                      self._on_diagnostics, topics.DIAGNOSTICS.qos)
        self.imu_pub = self.node.create_publisher(topics.IMU_RAW.msg_type, topics.IMU_RAW.name,
                                                  topics.IMU_RAW.qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _on_output(self, msg: Any) -> None:
        from enbarr_interfaces import convert
        self.outputs.append((convert.stamp_to_ns(msg.header.stamp), not np.any(msg.effort)))

    def _on_diagnostics(self, msg: Any) -> None:
        for s in msg.status:
            self.diagnostics[s.name] = {kv.key: kv.value for kv in s.values}

    def value(self, node: str, key: str) -> int | None:
        v = self.diagnostics.get(node, {}).get(key)
        return None if v is None else int(v)

    def inject(self, ahead_s: float) -> None:
        """One level sample at rest stamped ``ahead_s`` ahead of the clock."""
        from sensor_msgs.msg import Imu
        from enbarr_interfaces import convert
        msg = Imu()
        convert.ns_to_stamp(time.time_ns() + round(ahead_s * 1e9), msg.header.stamp)
        msg.header.frame_id = 'imu_link'
        msg.orientation_covariance[0] = -1.0
        msg.linear_acceleration.z = 9.81
        self.imu_pub.publish(msg)

    def close(self) -> None:
        import rclpy
        self._stop.set()
        self._thread.join(5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def wait(condition: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.05)
    raise AssertionError(f'{what} within {timeout} s')


def test_one_early_imu_sample_from_another_process_does_not_stop_control(tmp_path: Path):
    profile = tmp_path / 'split.yaml'
    profile.write_text(SPLIT_PROFILE)
    proc = subprocess.Popen([*ENBARR, 'bringup', '--profile', str(profile)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, env=os.environ)
    out = Output(proc)
    listener = None
    try:
        out.wait_for(r'group control started', 60)
        out.wait_for(r'thrust +[1-9]\d*\.\d N', 90)  # the chain drives over DDS
        listener = Listener()
        wait(lambda: listener.imu_pub.get_subscription_count() > 0, 30,
             "the filter never matched this process's imu/data_raw publisher")
        wait(lambda: len(listener.outputs) > 200
             and listener.value('/thruster_control', 'timeouts') is not None, 30,
             'no thruster_output or thruster diagnostics')
        for ahead in (20.0, 2.0):
            timeouts = listener.value('/thruster_control', 'timeouts')
            first = len(listener.outputs)
            listener.inject(ahead)
            time.sleep(3.0)
            window = listener.outputs[first:]
            assert len(window) >= 30, f'+{ahead} s: {len(window)} outputs in 3 s'
            assert not any(neutral for _, neutral in window), f'+{ahead} s: went neutral'
            wait(lambda t=timeouts: listener.value('/thruster_control', 'timeouts') is not None,
                 5, 'thruster diagnostics')
            assert listener.value('/thruster_control', 'timeouts') == timeouts, \
                f'+{ahead} s: the watchdog fired'
        # The filter refused both (and said so on /diagnostics).
        wait(lambda: (listener.value('/filtering', 'imu/data_raw.future') or 0) >= 2, 15,
             'the filter did not report the two future samples')
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0, ''.join(out.lines)[-3000:]
    finally:
        if listener is not None:
            listener.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert 'Traceback' not in ''.join(out.lines)
