"""A lidar revolution: samples collected between start flags, binned into rays."""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_plugins.lidar.scan import bearing, bin_revolution, RevolutionAssembler


def test_rays_are_in_the_lidars_own_frame():
    """x along the 0 deg mark, z up: the lidar's clockwise angles are bearings with the sign
    turned (REP-103); nothing of where the lidar sits on the vessel enters."""
    r = bin_revolution(np.array([0.0]), np.array([1000.0]), 360)
    assert r[180] == pytest.approx(1.0) and np.isinf(np.delete(r, 180)).all()  # ray 180: 0 rad
    # 90 deg clockwise is -pi/2 (ray 90), 270 deg clockwise +pi/2 (ray 270)
    r = bin_revolution(np.array([90.0, 270.0]), np.array([2000.0, 3000.0]), 360)
    assert r[90] == pytest.approx(2.0) and r[270] == pytest.approx(3.0)
    # just short of a full turn is just left of the mark; the ray at -pi takes 180 deg
    r = bin_revolution(np.array([359.0, 180.0]), np.array([1500.0, 2500.0]), 360)
    assert r[181] == pytest.approx(1.5) and r[0] == pytest.approx(2.5)
    assert np.degrees(bearing(np.array([0.0, 90.0, 180.0, 359.0]))) == pytest.approx(
        [0.0, -90.0, -180.0, 1.0])
    # no return (0) stays inf; the nearest of two returns in one ray wins
    r = bin_revolution(np.array([0.0, 0.2, 0.1]), np.array([0.0, 3000.0, 2000.0]), 360)
    assert r[180] == pytest.approx(2.0)


def test_revolutions_start_at_a_start_flag():
    asm = RevolutionAssembler(min_samples=3)
    a = np.arange(6) * 60.0
    assert asm.add(np.array([0, 0, 1, 0, 0, 0], bool), a, a + 1, 100) == []  # before: dropped
    revs = asm.add(np.array([0, 1, 0], bool), a[:3], a[:3] + 1, 200)
    assert len(revs) == 1 and revs[0].stamp_ns == 100
    assert revs[0].angle_deg.tolist() == [120.0, 180.0, 240.0, 300.0, 0.0]
    assert revs[0].duration == pytest.approx(1e-7)
    # a start flag too soon after the last (a stream out of step) and an angle >= 360 deg:
    # ignored and counted
    revs = asm.add(np.array([0, 1, 0, 0, 1], bool), np.array([10.0, 20.0, 400.0, 30.0, 40.0]),
                   np.ones(5), 300)
    assert len(revs) == 1 and revs[0].angle_deg.tolist() == [60.0, 120.0, 10.0]
    assert asm.false_starts == 1 and asm.invalid == 1
    # a start read with 3 samples after it was taken 3 sample periods before the read
    revs = asm.add(np.array([0, 0, 0, 1, 0, 0, 0], bool), np.zeros(7), np.ones(7), 10_000, 1000)
    assert revs[0].stamp_ns == 300 and revs[0].duration == pytest.approx((7000 - 300) * 1e-9)
    revs = asm.add(np.array([1, 0], bool), np.zeros(2), np.ones(2), 20_000, 1000)
    assert revs[0].stamp_ns == 7000 and revs[0].duration == pytest.approx(12_000e-9)


