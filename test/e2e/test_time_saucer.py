"""The CS Saucer keeps station in automatic while an outside process sends motion-capture
poses stamped 20 s ahead and in the past.

Before the time policy one such pose became the observer's time base: the good poses after it were
dropped as old for 20 s, the controller saturated and fell to manual, and the vessel drifted
0.6-1 m with the current while the observer said "ok, age 0.0".

The observer runs in its own process group, so ``mocap/pose`` reaches it over DDS (a fast
topic goes over the in-process link bus, and a link subscription takes DDS messages only when
no publisher of the topic is in its process): this test's publisher reaches it too.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from std_msgs.msg import String
from support.participant import Participant
from support.processes import bringup, stop
from support.waiting import poll_until

from enbarr_interfaces import convert, topics

PROFILE = """
include: [saucer_sim]
nodes:
  observer: {group: estimation}
  joystick:
    parameters:
      script: ['0.0 sticks 0.0 0.0 0.0', '1.0 press triangle']
groups:
  estimation: {restart_limit: 0}
"""
CURRENT = 0.03  # [m/s] saucer_sim.yaml's current: manual with zero force drifts this fast
AHEAD_S = 8.0  # how far ahead the bad pose is stamped; the run watches that long after it
# Bound on the position error: params/scenarios/station_keeping.yaml judges station keeping
# within 0.05 m; twice that for real time on a loaded machine. Losing control for the time
# the bad pose was ahead drifts CURRENT * AHEAD_S = 0.24 m (0.6-1 m over 20 s before the
# time policy).
MAX_ERROR = 0.1


class Watcher(Participant):
    """This test's ROS side: the vessel's truth, the mode, the observer's diagnostics."""

    def __init__(self) -> None:
        super().__init__('outsider')
        self.lock = threading.Lock()
        self.truth: list[tuple[float, np.ndarray]] = []  # (wall time, eta)
        self.modes: list[str] = []
        self.observer: list[dict[str, str]] = []
        self.node.create_subscription(Odometry, topics.SIM_ODOMETRY.name, self._on_truth,
                                      topics.SIM_ODOMETRY.qos)
        self.node.create_subscription(String, topics.MODE.name,
                                      lambda m: self.modes.append(m.data), topics.MODE.qos)
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                                      self._on_diagnostics, topics.DIAGNOSTICS.qos)
        self.pose_pub = self.node.create_publisher(PoseStamped, topics.MOCAP_POSE.name,
                                                   topics.MOCAP_POSE.qos)
        self.spin_in_background(0.1)

    def _on_truth(self, msg: Odometry) -> None:
        with self.lock:
            self.truth.append((time.monotonic(), convert.pose_to_eta(msg.pose.pose)))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name == '/observer':
                self.observer.append({'message': s.message, 'level': str(s.level[0]),
                                      **{kv.key: kv.value for kv in s.values}})

    def wait(self, condition: Any, timeout: float, what: str) -> None:
        if not poll_until(condition, timeout):
            raise AssertionError(f'{what} within {timeout} s (modes {self.modes}, '
                                 f'{len(self.truth)} truths, observer {self.observer[-1:]})')

    def latest(self) -> np.ndarray:
        with self.lock:
            return self.truth[-1][1]

    def since(self, t: float) -> np.ndarray:
        with self.lock:
            return np.array([eta for when, eta in self.truth if when >= t])

    def inject(self, offset_s: float) -> None:
        """One pose of where the vessel is, stamped ``offset_s`` from now."""
        msg = PoseStamped()
        convert.ns_to_stamp(time.time_ns() + round(offset_s * 1e9), msg.header.stamp)
        msg.header.frame_id = topics.WORLD_FRAME
        convert.set_pose_eta(msg.pose, self.latest())
        self.pose_pub.publish(msg)


def test_station_is_kept_through_future_and_past_poses(tmp_path: Path) -> None:
    profile = tmp_path / 'split.yaml'
    profile.write_text(PROFILE)
    with bringup('--profile', str(profile)) as (proc, out):
        w = Watcher()
        try:
            w.wait(lambda: 'automatic' in w.modes and len(w.truth) > 100, 90,
                   'automatic mode and the vessel truth')
            w.wait(lambda: any(d.get('mocap/pose.accepted') for d in w.observer), 30,
                   'the observer taking poses over DDS')
            time.sleep(5.0)  # settle on the held pose
            t0 = time.monotonic()
            held = w.since(t0 - 2.0)[:, :2].mean(axis=0)
            w.inject(AHEAD_S)
            time.sleep(3.0)
            w.inject(-1.0)
            time.sleep(AHEAD_S)
            etas = w.since(t0)
            error = np.linalg.norm(etas[:, :2] - held, axis=1)
            modes_after = list(w.modes[w.modes.index('automatic'):])
            time.sleep(1.5)  # the observer's next report
            last = w.observer[-1]
        finally:
            w.close()
            code = stop(proc, session=True)
        out.wait_closed(5.0)
    output = out.text
    print(f'max position error {error.max():.4f} m over {len(etas)} truth samples; '
          f'modes {modes_after}; observer: {last}')
    assert modes_after == ['automatic'], f'left automatic: {modes_after}\n{output[-3000:]}'
    assert len(etas) > 50 * AHEAD_S, 'too few truth samples to judge'
    assert error.max() < MAX_ERROR, (
        f'position error up to {error.max():.3f} m (bound {MAX_ERROR} m)\n{output[-3000:]}')
    assert int(last.get('mocap/pose.future', 0)) == 1, last
    assert int(last.get('mocap/pose.not_newer', 0)) >= 1, last
    assert last['level'] == '0' and last['age'] != 'none' and float(last['age']) < 0.1, last
    assert 'math domain error' not in output and 'Traceback' not in output, output[-3000:]
    assert code == 0, output[-3000:]
