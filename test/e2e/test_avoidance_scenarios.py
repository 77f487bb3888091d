"""End-to-end tier for the CS Saucer's collision avoidance: the ``ca_*`` scenarios run headless
on simulated time (``enbarr scenario``) through the whole chain: the simulated A1 scanning
the scenario's world, ``scan_obstacles``, the barrier functions in the guidance, the DP
controller and the allocation, on the simulated vessel. Each passes its own targets
(``scenario.targets``: the clearance from the world's ground truth first), and each is judged
again here on what makes it that scenario.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import subprocess
from typing import Any

from support.bags import read_bag
from support.cli import ENBARR

from enbarr_interfaces import avoidance

SAFETY_RADIUS = 0.2   # params/saucer_ca_core.yaml: hull to obstacle [m]
MARGIN = 0.04         # the range noise and pose error the targets allow (their comments) [m]


def scenario(name: str, out: Path, plot: bool = False) -> dict[str, Any]:
    # One run draws its PNG (seconds each); the others are judged by their figures alone.
    proc = subprocess.run([*ENBARR, 'scenario', name, '--output', str(out),
                           *(() if plot else ('--no-plot',))],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result['verdict'] == 'pass' and result['failed'] == []  # its own targets
    assert result['min_clearance_m'] >= SAFETY_RADIUS - MARGIN     # the hard bound
    assert result['all_waypoints_visited']
    assert ('plot' in result) == plot
    return result


def test_buoy_on_the_box_path_is_gone_round(tmp_path: Path) -> None:
    r = scenario('ca_buoy', tmp_path / 'out', plot=True)
    assert Path(r['plot']).stat().st_size > 10_000   # the world drawn on the path
    assert r['nearest_obstacle'] == 'buoy'
    assert r['avoidance_s'] > 5.0           # the filter steered, and let go again:
    assert r['cross_track_outside_avoidance_rms_m'] < 0.09
    assert r['infeasible_steps'] == 0 and r['blind_s'] == 0.0


def test_the_force_level_alone_keeps_the_buoy_clear(tmp_path: Path) -> None:
    """ca_buoy with avoidance.level force: the guidance leaves its reference through the buoy
    and the DP controller's force filter goes round it. The clearance is checked again here
    from the simulator's pose in the bag and the buoy of the scenario (ca_buoy.yaml: centre
    (1, 0), radius 0.15 m; the hull 0.15 m, saucer_ca_core.yaml)."""
    r = scenario('ca_buoy_force', tmp_path / 'out')
    msgs = read_bag(r['bag'])
    truth = [m.pose.pose.position for _, m in msgs['/sim/odometry']]
    clearance = min(math.hypot(p.x - 1.0, p.y - 0.0) - 0.15 - 0.15 for p in truth)
    assert clearance >= SAFETY_RADIUS - MARGIN
    assert clearance >= r['min_clearance_m'] - 1e-3 and r['nearest_obstacle'] == 'buoy'
    guidance = [avoidance.from_msg(m) for _, m in msgs['/guidance/avoidance']]
    force = [avoidance.from_msg(m) for _, m in msgs['/control/avoidance']]
    assert guidance and not any(s['engaged'] for s in guidance)   # the guidance filters nothing
    assert sum(s['engaged'] > 0.5 for s in force) > 100            # the force filter does
    assert r['avoidance_s'] > 2.0 and r['infeasible_steps'] == 0


def test_a_boat_head_on_is_given_way_to(tmp_path: Path) -> None:
    """The boat closes at 0.4 m/s: the filter acts on its tracked velocity."""
    r = scenario('ca_head_on', tmp_path / 'out')
    assert r['nearest_obstacle'] == 'boat'
    assert r['tracking_velocity_error_rms_mps'] < 0.15


def test_the_corridor_is_kept_to(tmp_path: Path) -> None:
    r = scenario('ca_corridor', tmp_path / 'out')
    assert r['cross_track_max_m'] < 0.05
    assert abs(r['clearance_by_obstacle']['wall_north']
               - r['clearance_by_obstacle']['wall_south']) < 0.05   # down the middle


def test_ten_scattered_buoys(tmp_path: Path) -> None:
    r = scenario('ca_ten_buoys', tmp_path / 'out')
    assert len(r['clearance_by_obstacle']) == 11   # ten buoys and the basin
    assert min(r['clearance_by_obstacle'].values()) == r['min_clearance_m']


def test_a_lidar_stalled_during_an_avoidance_stops_and_holds(tmp_path: Path) -> None:
    """Stalled 4-10 s: blind from 0.5 s after the last scan to the first confirmed one again,
    holding still; then on round the buoy."""
    r = scenario('ca_lidar_dropout', tmp_path / 'out')
    assert 5.0 <= r['blind_s'] <= 6.5
    assert r['blind_travel_m'] < 0.3
    assert r['nearest_obstacle'] == 'buoy'
