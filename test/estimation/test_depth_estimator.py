"""Depth and vertical velocity from pressure and accelerometer (pure): a dive with the sensors'
noise and an accelerometer bias the filter is not told, against the truth.

Noise figures typed here from their sources: the MS5837-30BA's resolution at OSR 4096 is
0.2 mbar = 20 Pa, about 2 mm of water (TE data sheet, "Resolution RMS"); the IMU's vertical
acceleration noise is taken at 0.02 m/s^2 RMS at 100 Hz, an LSM9DS1-class figure (about
200 ug/sqrt(Hz) over a 50 Hz band), and its bias at 0.05 m/s^2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.estimation.depth_estimator import DepthEstimator, DepthEstimatorSettings

pytestmark = pytest.mark.unit

SETTINGS = DepthEstimatorSettings(accel_noise=0.05, bias_walk=0.002, initial_bias_std=0.1,
                                  max_dt=0.5)
DEPTH_STD = 20.0 / (997.0 * 9.80665)     # 20 Pa in fresh water [m]
ACCEL_STD = 0.02
IMU_HZ, DEPTH_HZ = 100, 20


def dive(seconds: float = 40.0):
    """Truth at the IMU rate: rest, a 2 m dive with a smooth speed profile, hold, climb 1 m."""
    t = np.arange(0.0, seconds, 1.0 / IMU_HZ)

    def speed(t):   # w = z_dot [m/s], up positive
        w = np.zeros_like(t)
        down = (t >= 2.0) & (t < 12.0)
        w[down] = -0.2 * np.sin(math.pi * (t[down] - 2.0) / 10.0) * math.pi / 2.0
        up = (t >= 25.0) & (t < 35.0)
        w[up] = 0.1 * np.sin(math.pi * (t[up] - 25.0) / 10.0) * math.pi / 2.0
        return w
    w = speed(t)
    z = np.cumsum(w) / IMU_HZ
    a = np.gradient(w, 1.0 / IMU_HZ)
    return t, z, w, a


def run(bias: float, seed: int, accel_scale: float = 1.0, bias_rate: float = 0.0):
    rng = np.random.default_rng(seed)
    t, z, w, a = dive()
    est = DepthEstimator(SETTINGS)
    out = []
    for k in range(len(t)):
        stamp = int(round(t[k] * 1e9))
        b = bias + bias_rate * t[k]   # a bias that drifts (temperature)
        est.predict(accel_scale * a[k] + b + ACCEL_STD * rng.standard_normal(), stamp)
        if k % (IMU_HZ // DEPTH_HZ) == 0:
            est.update(-z[k] + DEPTH_STD * rng.standard_normal(), DEPTH_STD ** 2, stamp)
        out.append((est.depth, est.vertical_velocity, est.bias))
    return t, z, w, np.array(out)


@pytest.mark.parametrize('bias, scale', [(0.05, 1.0), (-0.08, 1.0), (0.05, 1.1)])
def test_a_dive_gives_depth_velocity_and_bias(bias, scale):
    t, z, w, est = run(bias, seed=3, accel_scale=scale)
    settled = t > 5.0
    depth_err = est[settled, 0] - (-z[settled])
    w_err = est[settled, 1] - w[settled]
    assert float(np.sqrt(np.mean(depth_err ** 2))) < DEPTH_STD      # better than one sample
    assert float(np.sqrt(np.mean(w_err ** 2))) < 0.01               # 1 cm/s
    assert float(np.max(np.abs(w_err))) < 0.04
    assert abs(est[-1, 2] - bias) < 0.02                            # the bias is found
    # the dive went 2 m down and came 1 m back
    assert est[int(20 * IMU_HZ), 0] == pytest.approx(2.0, abs=0.01)
    assert est[-1, 0] == pytest.approx(1.0, abs=0.01)


def test_a_drifting_bias_is_followed():
    # 0.05 -> 0.13 m/s^2 over the 40 s run: the bias is a random walk in the model
    t, z, w, est = run(0.05, seed=7, bias_rate=0.002)
    assert abs(est[-1, 2] - (0.05 + 0.002 * t[-1])) < 0.01
    settled = t > 5.0
    assert float(np.sqrt(np.mean((est[settled, 1] - w[settled]) ** 2))) < 0.01


def test_the_velocity_is_better_than_differentiated_depth():
    t, z, w, est = run(0.05, seed=5)
    settled = t > 5.0
    fused = float(np.sqrt(np.mean((est[settled, 1] - w[settled]) ** 2)))
    # the pressure alone: the depth samples differenced at 20 Hz
    rng = np.random.default_rng(5)
    samples = -z[::IMU_HZ // DEPTH_HZ] + DEPTH_STD * rng.standard_normal(len(z[::5]))
    diff = -np.diff(samples) * DEPTH_HZ
    alone = float(np.sqrt(np.mean((diff[25:] - w[::5][1:][25:]) ** 2)))
    assert fused < 0.25 * alone


def test_not_started_before_a_depth_and_bad_measurements_change_nothing():
    est = DepthEstimator(SETTINGS)
    est.predict(1.0, 10)
    assert not est.started and math.isnan(est.depth)
    assert not est.update(math.nan, 1e-4, 20)
    assert not est.update(1.0, 0.0, 20)
    assert est.update(1.5, 1e-4, 30) and est.depth == pytest.approx(1.5)
    assert est.vertical_velocity == 0.0
    before = est.depth
    assert not est.update(math.inf, 1e-4, 40)
    assert est.depth == before


def test_a_gap_longer_than_max_dt_resets():
    est = DepthEstimator(SETTINGS)
    est.update(1.0, 1e-4, 0)
    est.predict(0.0, 100_000_000)
    assert est.started
    est.predict(0.0, 100_000_000 + int(0.6e9))
    assert not est.started


def test_constant_acceleration_is_integrated_exactly():
    # no noise, no measurement: z = a t^2 / 2 and w = a t over 1 s of 0.1 m/s^2 steps
    est = DepthEstimator(SETTINGS)
    est.update(0.0, 1e-6, 0)
    for k in range(1, 11):
        est.predict(0.4, k * 100_000_000)
    assert est.vertical_velocity == pytest.approx(0.4)
    assert est.depth == pytest.approx(-0.2)


@pytest.mark.parametrize('field', ['accel_noise', 'bias_walk', 'initial_bias_std', 'max_dt'])
def test_settings_name_the_bad_field(field):
    values = {'accel_noise': 0.05, 'bias_walk': 0.002, 'initial_bias_std': 0.1, 'max_dt': 0.5,
              field: -1.0}
    with pytest.raises(ValueError, match=f'^{field}'):
        DepthEstimatorSettings(**values).validate()
