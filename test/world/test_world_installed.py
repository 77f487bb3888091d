"""Node tier: bringup gives every node of a process the profile's world and its epoch
(``composed`` installs it as it installs the frame tree; a scenario's epoch is its start)."""

from __future__ import annotations

from pathlib import Path
import textwrap
import time

import pytest

from enbarr_core.bringup.compose import composed, validate
from enbarr_core.bringup.profile import load_profile
from enbarr_core.world.model import Circle

pytestmark = pytest.mark.node


def profile(tmp_path: Path):
    path = tmp_path / 'p.yaml'
    path.write_text(textwrap.dedent("""
        environment: {ROS_AUTOMATIC_DISCOVERY_RANGE: LOCALHOST}
        nodes:
          lidar: {plugin: sim_lidar}
        frames:
          odom: {}
          base_link: {parent: odom}
          laser: {parent: base_link, xyz: [0.0, 0.0, 0.15]}
        world:
          buoy: {kind: circle, center: [3.0, 1.0], radius: 0.3}
        """))
    return load_profile(str(path))


def test_composed_nodes_get_the_profiles_world_and_epoch(tmp_path: Path) -> None:
    p = profile(tmp_path)
    with composed(p, world_epoch_ns=5_000_000_000) as c:
        [lidar] = c.nodes
        assert lidar.world is p.world and lidar.world.obstacles[0].shape == Circle(
            (3.0, 1.0), 0.3)
        assert lidar.world_time(7_500_000_000) == pytest.approx(2.5)
    before = time.time_ns()
    with composed(p) as c:  # bringup: the world time starts when the process composes
        t = c.nodes[0].world_time()
        assert 0.0 <= t <= (time.time_ns() - before) * 1e-9
    assert validate(p).nodes == 1  # a check builds the node with the world too
