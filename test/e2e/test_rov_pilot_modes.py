"""The Enbarr ROV's depth and heading hold in the whole simulated profile (``enbarr scenario``
as a user runs it): the pilot's script selects depth_hold, dives with the heave stick, turns
with the yaw stick and lets go, in a 0.2 m/s current; the truth (``sim/odometry``) is judged
from the bag, with a plant 30 % heavier, draggier and 2 N light (rov_depth_hold, the model's
plant, runs the same script: it is judged by test/control/test_pilot_hold.py's closed loop
and its figures are in docs/benchmarks.md; one scenario here keeps the suite's time).

Targets (the pilot modes' figures): once settled, the depth within 2 cm RMS of where it is
held and the heading within 1 deg.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.scenarios import run_scenario

from enbarr_core.framework.kinematics import quat_to_euler, ssa

pytestmark = pytest.mark.e2e

SETTLED = (25.0, 45.0)   # s of the run: 8 s after the yaw stick is released, to the end
START_DEPTH = 0.5        # m, the scenarios' initial position


@pytest.fixture(scope='module', params=['rov_depth_hold_heavy'])
def run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
        ) -> dict[str, Any]:
    out: Path = tmp_path_factory.mktemp(request.param)
    return run_scenario(request.param, out)


def truth(run: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    od = run['msgs']['/sim/odometry']
    t = np.array([s * 1e-9 for s, _ in od])
    depth = np.array([-m.pose.pose.position.z for _, m in od])
    yaw = np.array([quat_to_euler([m.pose.pose.orientation.x, m.pose.pose.orientation.y,
                                   m.pose.pose.orientation.z, m.pose.pose.orientation.w])[2]
                    for _, m in od])
    return t - t[0], depth, yaw


def test_the_pilot_selected_depth_hold_and_nothing_was_refused(run):
    modes = [m.data for _, m in run['msgs']['/pilot_mode']]
    assert modes == ['velocity', 'depth_hold']
    assert not run['msgs'].get('/pilot_mode/reason')


def test_depth_is_held_within_2_cm_rms_after_the_dive(run):
    t, depth, _ = truth(run)
    assert depth[t < 1.0].max() < START_DEPTH + 0.05
    w = (t >= SETTLED[0]) & (t < SETTLED[1])
    assert w.sum() > 500
    held = depth[w]
    assert held.mean() > START_DEPTH + 0.8                       # the dive happened
    rms = float(np.sqrt(np.mean((held - held.mean()) ** 2)))
    assert rms <= 0.02, f'depth RMS {rms:.4f} m about {held.mean():.3f} m'


def test_heading_is_held_within_1_deg_after_the_turn(run):
    t, _, yaw = truth(run)
    before = yaw[(t >= 10.0) & (t < 15.0)]
    w = (t >= SETTLED[0]) & (t < SETTLED[1])
    after = yaw[w]
    mean = math.atan2(float(np.sin(after).mean()), float(np.cos(after).mean()))
    assert abs(ssa(mean - float(before.mean()))) > math.radians(20.0)   # the turn happened
    worst = max(abs(ssa(a - mean)) for a in after.tolist())
    assert math.degrees(worst) <= 1.0, f'heading {math.degrees(worst):.2f} deg off'
