"""A lidar revolution: its samples collected, then binned into the rays of a LaserScan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_plugins.lidar.scan import bearing, bin_revolution, RevolutionAssembler

#: The A1's range [m] (A1M8 datasheet: 0.15-12 m), as the driver passes it.
MIN, MAX = 0.15, 12.0


def bins(angles, distances, n=360):
    return bin_revolution(np.array(angles, dtype=float), np.array(distances, dtype=float), n,
                          MIN, MAX)


def test_rays_are_in_the_lidars_own_frame():
    """x along the 0 deg mark, z up: the lidar's clockwise angles are bearings with the sign
    turned (REP-103); nothing of where the lidar sits on the vessel enters."""
    r = bins([0.0], [1000.0])
    assert r[180] == pytest.approx(1.0)                    # ray 180 is 0 rad
    # 90 deg clockwise is -pi/2 (ray 90), 270 deg clockwise +pi/2 (ray 270)
    r = bins([90.0, 270.0], [2000.0, 3000.0])
    assert r[90] == pytest.approx(2.0) and r[270] == pytest.approx(3.0)
    # just short of a full turn is just left of the mark; the ray at -pi takes 180 deg
    r = bins([359.0, 180.0], [1500.0, 2500.0])
    assert r[181] == pytest.approx(1.5) and r[0] == pytest.approx(2.5)
    assert np.degrees(bearing(np.array([0.0, 90.0, 180.0, 359.0]))) == pytest.approx(
        [0.0, -90.0, -180.0, 1.0])
    # the nearest of two returns in one ray wins
    assert bins([0.2, 0.1], [3000.0, 2000.0])[180] == pytest.approx(2.0)


def test_special_readings_follow_rep_117():
    """REP-117 (www.ros.org/reps/rep-0117.html): a detection too close to measure is -Inf,
    an erroneous one NaN, no return (nothing within range) +Inf; a real measurement lies in
    [range_min, range_max]."""
    r = bins([10.0, 20.0, 30.0, 40.0, 50.0], [100.0, 0.0, 12500.0, math.nan, 150.0])
    assert r[170] == -math.inf         # 0.10 m: too close
    assert r[160] == math.inf          # 0: the A1's invalid measurement, read as no return
    assert r[150] == math.inf          # 12.5 m: beyond range_max, no return
    assert math.isnan(r[140])          # erroneous (a quality too low)
    assert r[130] == pytest.approx(0.15)  # range_min itself is a measurement
    assert math.isnan(r[0]) and np.isnan(np.delete(r, [130, 140, 150, 160, 170])).all()
    # in one ray: a return too close or too far never replaces a measurement ...
    assert bins([95.0, 95.2, 95.4], [3000.0, 47.5, 13000.0])[85] == pytest.approx(3.0)
    # ... a too-close one tells more than no return; anything more than nothing
    assert bins([95.0, 95.2], [0.0, 47.5])[85] == -math.inf
    assert bins([95.0, 95.2], [math.nan, 0.0])[85] == math.inf


def test_a_revolution_begins_where_the_angle_wraps():
    asm = RevolutionAssembler(min_samples=3)
    a = np.array([300.0, 330.0, 10.0, 100.0, 200.0, 300.0])   # mid-revolution, then a wrap
    s = np.array([0, 0, 1, 0, 0, 0], bool)
    assert asm.add(s, a, a + 1, 100) == []                    # before the first start: dropped
    revs = asm.add(np.array([1, 0, 0], bool), np.array([5.0, 90.0, 180.0]), np.ones(3), 200)
    assert len(revs) == 1 and revs[0].stamp_ns == 100
    assert revs[0].angle_deg.tolist() == [10.0, 100.0, 200.0, 300.0]
    assert revs[0].duration == pytest.approx(1e-7)
    # a start flag where the angle goes on rising is no start (a stream out of step passed
    # it): ignored and counted; an angle of 360 deg or more is dropped and counted
    revs = asm.add(np.array([0, 1, 0, 0], bool), np.array([200.0, 250.0, 400.0, 350.0]),
                   np.ones(4), 300)
    assert revs == [] and asm.false_starts == 1 and asm.invalid == 1
    # the angle wraps without a start flag (its sample was lost): a new revolution all the
    # same, counted; the angles of every revolution increase
    revs = asm.add(np.array([0, 0, 0], bool), np.array([2.0, 100.0, 300.0]), np.ones(3), 400)
    assert len(revs) == 1 and asm.missed_starts == 1
    assert revs[0].angle_deg.tolist() == [5.0, 90.0, 180.0, 200.0, 250.0, 350.0]
    # too few samples between two starts (most of it lost): dropped, counted
    revs = asm.add(np.array([1, 0, 1], bool), np.array([1.0, 2.0, 0.5]), np.ones(3), 500)
    assert len(revs) == 1 and revs[0].angle_deg.tolist() == [2.0, 100.0, 300.0]
    assert asm.dropped == 1


def test_a_revolution_is_dated_by_its_first_sample():
    asm = RevolutionAssembler(min_samples=1)
    # a start read with 3 samples after it was taken 3 sample periods before the read
    a = np.array([100.0, 200.0, 300.0, 1.0, 2.0, 3.0, 4.0])
    s = np.array([0, 0, 0, 1, 0, 0, 0], bool)
    assert asm.add(s, a, np.ones(7), 10_000, 1000) == []
    revs = asm.add(np.array([1, 0], bool), np.array([0.5, 1.0]), np.ones(2), 20_000, 1000)
    assert revs[0].stamp_ns == 7000 and revs[0].duration == pytest.approx(12_000e-9)
