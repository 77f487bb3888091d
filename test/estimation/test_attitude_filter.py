"""Tests of the multiplicative EKF in ``enbarr_core.estimation.attitude_filter`` (no rclpy).

Ground truth is an analytic attitude trajectory (ZYX Euler angles as smooth functions of time,
built and converted with scipy's ``Rotation``, independent of ``kinematics``). IMU samples are
synthesised from it at 400 Hz with seeded noise, so every figure below is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from enbarr_core.framework.kinematics import ssa
from enbarr_core.estimation.attitude_filter import (
    AttitudeEstimate,
    AttitudeFilter,
    AttitudeFilterSettings,
)

FS = 400.0                                  # IMU rate [Hz]
DT = 1.0 / FS                               # [s]
G = 9.81                                    # [m/s^2]
M_WORLD = np.array([0.0, 2e-5, -4.5e-5])    # north (+y) with downward inclination [T]
GYRO_BIAS = np.array([0.01, -0.02, 0.015])  # injected constant gyro bias [rad/s]
SETTINGS = AttitudeFilterSettings()
GYRO_STD = SETTINGS.gyro_noise / math.sqrt(DT)  # per-sample gyro noise [rad/s]
ACCEL_STD = SETTINGS.accel_noise                # [m/s^2]
MAG_STD = 1e-6                                  # per axis [T]: ~0.05 rad heading noise
CONVERGED = 10.0                                # statistics are taken for t >= this [s]

# Bounds stated by the tests (the measured figures are far inside them).
ROLL_PITCH_RMS_DEG = 0.5
YAW_RMS_DEG = 1.0
BIAS_TOL = 1e-3                             # [rad/s] per axis, mean over the last 10 s
NEES_BAND = (1.0, 6.0)                      # mean NEES of the 3-DOF attitude error (ideal: 3)


# --- ground truth -------------------------------------------------------------------------


def euler(t: np.ndarray, yaw0: float = 0.4) -> tuple[np.ndarray, ...]:
    """Roll, pitch, yaw [rad] and their rates [rad/s]: rocking plus a continuing yaw turn
    from the heading ``yaw0``."""
    w1, w2, w3 = 2 * math.pi * 0.1, 2 * math.pi * 0.07, 2 * math.pi * 0.03
    roll = math.radians(15.0) * np.sin(w1 * t)
    pitch = math.radians(10.0) * np.sin(w2 * t + 0.5)
    yaw = yaw0 + 0.15 * t + 0.5 * np.sin(w3 * t)    # ~9 rad in 60 s: crosses +-pi often
    droll = math.radians(15.0) * w1 * np.cos(w1 * t)
    dpitch = math.radians(10.0) * w2 * np.cos(w2 * t + 0.5)
    dyaw = 0.15 + 0.5 * w3 * np.cos(w3 * t)
    return roll, pitch, yaw, droll, dpitch, dyaw


def true_rotation(t: np.ndarray, yaw0: float = 0.4) -> Rotation:
    roll, pitch, yaw, *_ = euler(t, yaw0)
    return Rotation.from_euler('ZYX', np.column_stack([yaw, pitch, roll]))


def true_rate(t: np.ndarray) -> np.ndarray:
    """Body rate [rad/s] from the ZYX Euler rates: w = T(roll, pitch)^-1 d/dt[roll, pitch, yaw]."""
    roll, pitch, _, droll, dpitch, dyaw = euler(t)
    return np.column_stack([
        droll - dyaw * np.sin(pitch),
        dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll),
        -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll),
    ])


@dataclass(frozen=True)
class Imu:
    t: np.ndarray       # (n,) sample times [s]
    rot: Rotation       # true attitude at t
    rate: np.ndarray    # (n, 3) true body rate at t [rad/s]
    gyro: np.ndarray    # (n, 3) gyro sample covering (t - DT, t] [rad/s]
    accel: np.ndarray   # (n, 3) [m/s^2]
    mag: np.ndarray     # (n, 3) [T]


def synthesize(duration: float, seed: int, yaw0: float = 0.4) -> Imu:
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * FS)) + 1) * DT
    rot = true_rotation(t, yaw0)
    # The gyro holds one rate over the interval ending at t: the mid-interval rate.
    gyro = true_rate(t - 0.5 * DT) + GYRO_BIAS + rng.normal(0.0, GYRO_STD, (len(t), 3))
    accel = rot.inv().apply([0.0, 0.0, G]) + rng.normal(0.0, ACCEL_STD, (len(t), 3))
    mag = rot.inv().apply(M_WORLD) + rng.normal(0.0, MAG_STD, (len(t), 3))
    return Imu(t, rot, true_rate(t), gyro, accel, mag)


def perturbed_init_sample(rot: Rotation, droll: float, dpitch: float,
                          dyaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free accel and mag of an attitude off by the given Euler errors [rad]."""
    yaw, pitch, roll = rot.as_euler('ZYX')
    wrong = Rotation.from_euler('ZYX', [yaw + dyaw, pitch + dpitch, roll + droll])
    return wrong.inv().apply([0.0, 0.0, G]), wrong.inv().apply(M_WORLD)


@dataclass(frozen=True)
class Run:
    imu: Imu
    est: list[AttitudeEstimate]     # est[k] belongs to imu sample k (k >= 1)

    def mask(self) -> np.ndarray:
        return self.imu.t[1:] >= CONVERGED

    def q(self) -> np.ndarray:
        return np.array([e.q for e in self.est])

    def euler_errors(self) -> np.ndarray:
        """(n, 3) roll, pitch, yaw errors [rad] (estimate minus truth, wrapped)."""
        true = self.imu.rot[1:].as_euler('ZYX')[:, ::-1]
        est = Rotation.from_quat(self.q()).as_euler('ZYX')[:, ::-1]
        return ssa(est - true)

    def body_errors(self) -> np.ndarray:
        """(n, 3) dtheta with q_true = q_est (x) q{dtheta}: the filter's error [rad]."""
        return (Rotation.from_quat(self.q()).inv() * self.imu.rot[1:]).as_rotvec()


def run(imu: Imu, settings: AttitudeFilterSettings = SETTINGS, use_mag: bool = True,
        init: tuple[np.ndarray, np.ndarray] | None = None) -> Run:
    f = AttitudeFilter(settings)
    if init is None:
        f.step(imu.gyro[0], imu.accel[0], imu.mag[0] if use_mag else None, DT)
    else:
        f.initialize(*init)
    assert f.initialized
    est = [f.step(imu.gyro[k], imu.accel[k], imu.mag[k] if use_mag else None, DT)
           for k in range(1, len(imu.t))]
    return Run(imu, est)


@pytest.fixture(scope='module')
def imu60() -> Imu:
    return synthesize(60.0, seed=7)


@pytest.fixture(scope='module')
def imu30() -> Imu:
    """30 s: 20 s of statistics after CONVERGED, for the runs that need no more."""
    return synthesize(30.0, seed=7)


@pytest.fixture(scope='module')
def mag_run(imu60: Imu) -> Run:
    """60 s with magnetometer, started 6/-6/30 deg (roll/pitch/yaw) off the truth."""
    init = perturbed_init_sample(imu60.rot[0], math.radians(6.0), math.radians(-6.0),
                                 math.radians(30.0))
    return run(imu60, init=init)


def rms_deg(a: np.ndarray) -> np.ndarray:
    return np.degrees(np.sqrt(np.mean(a ** 2, axis=0)))


# --- the truth itself ---------------------------------------------------------------------


def test_truth_rates_match_the_attitude_trajectory() -> None:
    """The synthetic gyro is the derivative of the synthetic attitude (checks the test)."""
    t = np.linspace(0.0, 60.0, 50)
    h = 1e-5
    rot0, rot1 = true_rotation(t - h), true_rotation(t + h)
    numeric = (rot0.inv() * rot1).as_rotvec() / (2 * h)
    np.testing.assert_allclose(numeric, true_rate(t), atol=1e-6)


# --- accuracy and consistency (60 s, 400 Hz, magnetometer) --------------------------------


@pytest.mark.sim
def test_attitude_converges_and_tracks(mag_run: Run) -> None:
    """From a 6/6/30 deg initial error: after 10 s, RMS roll/pitch < 0.5 deg, yaw < 1 deg."""
    err = mag_run.euler_errors()[mag_run.mask()]
    roll, pitch, yaw = rms_deg(err)
    assert roll < ROLL_PITCH_RMS_DEG and pitch < ROLL_PITCH_RMS_DEG, (roll, pitch)
    assert yaw < YAW_RMS_DEG, yaw
    angle = np.degrees(np.linalg.norm(mag_run.body_errors()[mag_run.mask()], axis=1))
    assert angle.max() < 2.0 * YAW_RMS_DEG


def test_gyro_bias_converges(mag_run: Run) -> None:
    """The bias estimate averaged over the last 10 s is within 1e-3 rad/s of the truth."""
    bias = np.array([e.gyro_bias for e in mag_run.est])
    last = mag_run.imu.t[1:] >= 50.0
    np.testing.assert_allclose(bias[last].mean(axis=0), GYRO_BIAS, atol=BIAS_TOL)
    # ... and the reported bias std covers the remaining error.
    bias_std = np.sqrt(np.diag(mag_run.est[-1].omega_cov) - SETTINGS.gyro_noise ** 2 / DT)
    assert np.all(np.abs(bias[-1] - GYRO_BIAS) < 4.0 * bias_std)


def test_orientation_covariance_is_consistent(mag_run: Run) -> None:
    """Mean NEES e' P^-1 e of the body-frame attitude error is near its ideal value 3."""
    e = mag_run.body_errors()
    P = np.array([est.orientation_cov for est in mag_run.est])
    nees = np.einsum('ni,ni->n', e, np.linalg.solve(P, e[:, :, None])[:, :, 0])
    mean_nees = nees[mag_run.mask()].mean()
    assert NEES_BAND[0] < mean_nees < NEES_BAND[1], mean_nees
    # The covariances are symmetric positive definite throughout.
    np.testing.assert_allclose(P, np.transpose(P, (0, 2, 1)), atol=1e-15)
    assert np.linalg.eigvalsh(P).min() > 0.0


def test_omega_is_bias_corrected_with_consistent_covariance(mag_run: Run) -> None:
    omega = np.array([e.omega for e in mag_run.est])
    var = np.array([np.diag(e.omega_cov) for e in mag_run.est])
    err = (omega - mag_run.imu.rate[1:])[mag_run.mask()]
    # Mean error is the residual bias error only; the normalised variance is ~1.
    assert np.all(np.abs(err.mean(axis=0)) < BIAS_TOL)
    normalised = np.mean(err ** 2 / var[mag_run.mask()], axis=0)
    assert np.all((normalised > 0.8) & (normalised < 1.2)), normalised


def test_estimate_arrays_are_read_only(mag_run: Run) -> None:
    e = mag_run.est[-1]
    for a in (e.q, e.omega, e.gyro_bias, e.orientation_cov, e.omega_cov):
        with pytest.raises(ValueError):
            a[0] = 1.0
    assert e.accel_used and e.mag_used


# --- without magnetometer -----------------------------------------------------------------


@pytest.mark.sim
@pytest.mark.parametrize('use_magnetometer, pass_mag', [(False, True), (True, False)])
def test_roll_pitch_converge_without_magnetometer(imu30: Imu, use_magnetometer: bool,
                                                  pass_mag: bool) -> None:
    """Disabled in the settings, or enabled but never sent: roll/pitch still converge (30 s:
    the error is inside its bound within CONVERGED, the yaw drift grows for 20 s more)."""
    settings = replace(SETTINGS, use_magnetometer=use_magnetometer)
    accel0, _ = perturbed_init_sample(imu30.rot[0], math.radians(6.0), math.radians(-6.0), 0.0)
    r = run(imu30, settings, use_mag=pass_mag, init=(accel0, None))
    roll, pitch, _ = rms_deg(r.euler_errors()[r.mask()])
    assert roll < ROLL_PITCH_RMS_DEG and pitch < ROLL_PITCH_RMS_DEG, (roll, pitch)
    assert not any(e.mag_used for e in r.est)
    # Yaw is relative to the initial heading: it keeps the initial offset (0 - yaw_true(0))
    # and drifts with the unobserved gyro error, within 3 sigma of its reported variance
    # (world-z component), which starts at ~zero and grows.
    yaw_var = [(Rotation.from_quat(e.q).as_matrix() @ e.orientation_cov
                @ Rotation.from_quat(e.q).as_matrix().T)[2, 2] for e in (r.est[0], r.est[-1])]
    assert 0.0 < yaw_var[0] < math.radians(0.1) ** 2 < yaw_var[1]
    drift = ssa(r.euler_errors()[-1, 2] + imu30.rot[0].as_euler('ZYX')[0])
    assert abs(drift) < 3.0 * math.sqrt(yaw_var[1]), (drift, yaw_var[1])


# --- heading from any start heading ---------------------------------------------------------

START_HEADINGS = [-math.pi + 0.02, -2.0, -0.7, 1.2, math.pi - 0.02]


@pytest.mark.sim
@pytest.mark.parametrize('yaw0', START_HEADINGS)
def test_heading_is_found_from_any_start_heading(yaw0: float) -> None:
    """The vehicle starts at heading yaw0 (rocking, turning 0.15 rad/s, so the near-pi starts
    cross +-pi at once). Initialised from its first sample, the yaw error is bounded from the
    start by the one-sample heading noise, and after CONVERGED within the module's yaw bound.
    A filter that ignored the magnetometer would be off by about yaw0 (yaw relative to the
    start heading). Budget of the first 10 s: the initial heading std is
    hypot(mag_noise, tan(inclination) tilt_std) ~ 3.1 deg from one noisy sample (see
    test_initialize_static_vehicle_from_one_sample); 4 sigma = 12.5 deg.
    """
    imu = synthesize(15.0, seed=11, yaw0=yaw0)
    r = run(imu)
    yaw_err = np.degrees(r.euler_errors()[:, 2])
    assert np.abs(yaw_err).max() < 12.5
    assert rms_deg(np.radians(yaw_err[r.mask()])) < YAW_RMS_DEG


@pytest.mark.sim
@pytest.mark.parametrize('yaw0', START_HEADINGS)
def test_heading_error_converges_through_the_wrap(yaw0: float) -> None:
    """Started 20 deg off in heading (and 3 deg in roll and pitch): the magnetometer's Kalman
    updates, not only the first alignment, must pull the heading in, across +-pi where the
    truth or the estimate wraps. After CONVERGED the module's yaw bound holds."""
    imu = synthesize(15.0, seed=12, yaw0=yaw0)
    init = perturbed_init_sample(imu.rot[0], math.radians(3.0), math.radians(-3.0),
                                 math.radians(20.0))
    r = run(imu, init=init)
    assert rms_deg(r.euler_errors()[r.mask(), 2]) < YAW_RMS_DEG


def test_first_magnetometer_sample_aligns_heading() -> None:
    """Initialised without mag (relative yaw); the first mag sample snaps yaw to north."""
    truth = Rotation.from_euler('ZYX', [2.5, 0.1, -0.2])
    accel = truth.inv().apply([0.0, 0.0, G])
    mag = truth.inv().apply(M_WORLD)
    f = AttitudeFilter()
    first = f.step(np.zeros(3), accel, None, DT)
    assert f.initialized and not f.heading_known
    assert abs(Rotation.from_quat(first.q).as_euler('ZYX')[0]) < 1e-12
    second = f.step(np.zeros(3), accel, mag, DT)
    assert f.heading_known and second.mag_used
    err = (truth.inv() * Rotation.from_quat(second.q)).magnitude()
    assert err < math.radians(0.1), math.degrees(err)


# --- initialisation -----------------------------------------------------------------------


@pytest.mark.parametrize('roll, pitch, yaw', [
    (0.0, 0.0, 0.0),
    (0.0, 0.0, 90.0),
    (10.0, -20.0, 135.0),
    (-30.0, 15.0, -100.0),
    (5.0, 40.0, 179.9),
    (170.0, 0.0, 45.0),          # upside down
])
def test_initialize_static_vehicle_from_one_sample(roll: float, pitch: float,
                                                   yaw: float) -> None:
    truth = Rotation.from_euler('ZYX', np.radians([yaw, pitch, roll]))
    accel, mag = truth.inv().apply([0.0, 0.0, G]), truth.inv().apply(M_WORLD)
    f = AttitudeFilter()
    assert not f.initialized
    f.initialize(accel, mag)
    assert f.initialized and f.heading_known
    # The first step() of a fresh filter initialises the same way.
    e = AttitudeFilter().step([0.1, 0.2, 0.3], accel, mag, DT)
    assert not e.accel_used
    np.testing.assert_allclose(e.omega, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(e.gyro_bias, 0.0)
    assert (truth.inv() * Rotation.from_quat(e.q)).magnitude() < 1e-9
    np.testing.assert_allclose(e.omega_cov, (SETTINGS.initial_bias_std ** 2
                                             + SETTINGS.gyro_noise ** 2 / DT) * np.eye(3))
    # Covariance of a one-sample initialisation, about world axes: the tilt std is the
    # accel gate over g (the sample may include acceleration); the heading std is at least
    # mag_noise, plus the tilt error leaking in by tan(inclination) = 2.25.
    R = Rotation.from_quat(e.q).as_matrix()
    std_world = np.sqrt(np.diag(R @ e.orientation_cov @ R.T))
    tilt_std = SETTINGS.accel_gate / G
    np.testing.assert_allclose(std_world[:2], tilt_std, rtol=1e-9)
    assert std_world[2] == pytest.approx(math.hypot(SETTINGS.mag_noise, 2.25 * tilt_std),
                                         rel=1e-6)


def test_yaw_convention_body_x_north_is_plus_half_pi() -> None:
    """Magnetic north is world +y (ENU): body x pointing north gives yaw = +pi/2."""
    mag_body_x_north = np.array([2e-5, 0.0, -4.5e-5])      # field along +x, pointing down
    f = AttitudeFilter()
    e = f.step(np.zeros(3), [0.0, 0.0, G], mag_body_x_north, DT)
    rot = Rotation.from_quat(e.q)
    assert rot.as_euler('ZYX')[0] == pytest.approx(math.pi / 2, abs=1e-12)
    np.testing.assert_allclose(rot.apply([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-12)


def test_reset_forgets_the_state() -> None:
    f = AttitudeFilter()
    f.step(np.zeros(3), [0.0, 0.0, G], M_WORLD, DT)
    f.reset()
    assert not f.initialized and not f.heading_known
    e = f.step(np.zeros(3), [0.0, G * math.sin(0.3), G * math.cos(0.3)], None, DT)
    assert Rotation.from_quat(e.q).as_euler('ZYX')[2] == pytest.approx(0.3, abs=1e-12)


# --- gating and odd inputs ----------------------------------------------------------------


def _level_static_filter(settings: AttitudeFilterSettings = SETTINGS,
                         seconds: float = 2.0) -> AttitudeFilter:
    f = AttitudeFilter(settings)
    for _ in range(int(seconds * FS)):
        f.step(np.zeros(3), [0.0, 0.0, G], [0.0, 2e-5, -4.5e-5], DT)
    return f


def test_accelerating_vehicle_is_gated_out() -> None:
    """| |a| - g | = 1.7 m/s^2 > gate: no gravity update, the tilt is not pulled."""
    surge = [6.0, 0.0, G]
    gated = _level_static_filter()
    # The control arm opens both gates: the magnitude gate and the innovation gate.
    ungated = _level_static_filter(replace(SETTINGS, accel_gate=100.0,
                                           accel_innovation_gate=1e9))
    for _ in range(200):
        eg = gated.step(np.zeros(3), surge, M_WORLD, DT)
        eu = ungated.step(np.zeros(3), surge, M_WORLD, DT)
    assert not eg.accel_used and eg.mag_used and eu.accel_used
    pitch_gated = Rotation.from_quat(eg.q).as_euler('ZYX')[1]
    pitch_ungated = Rotation.from_quat(eu.q).as_euler('ZYX')[1]
    assert abs(pitch_gated) < math.radians(0.01)
    assert abs(pitch_ungated) > math.radians(1.0)


# --- acceleration across gravity: the innovation gate -----------------------------------------

TAN_INCLINATION = -M_WORLD[2] / M_WORLD[1]          # 2.25: tilt error -> heading error
SURGE_ACCEL = 0.5                                   # [m/s^2], the ROV's max_accel
BURSTS = ((10.0, 10.8, SURGE_ACCEL), (13.8, 14.6, -SURGE_ACCEL))  # speed 0 -> 0.4 -> 0 m/s


# The innovation gate is an option (off by default, see the filter's docstring); the tests
# of this section are the option's.
GATED = replace(SETTINGS, use_innovation_gate=True)


def surge_run(yaw0: float, settings: AttitudeFilterSettings = GATED) -> tuple[
        np.ndarray, list[AttitudeEstimate]]:
    """Level vehicle at heading ``yaw0``, gyro bias GYRO_BIAS, 10 s at rest, then the ROV's
    drive: +0.5 m/s^2 surge for 0.8 s, 3 s at 0.4 m/s, -0.5 m/s^2 for 0.8 s, 5.4 s at rest.
    It never rotates: every rate the filter publishes is gyro error. Returns the sample times
    and the estimates (``est[k]`` belongs to ``t[k]``)."""
    rng = np.random.default_rng(3)
    t = np.arange(int(20.0 * FS) + 1) * DT
    n = len(t)
    surge = np.zeros(n)
    for start, end, a in BURSTS:
        surge[(t >= start) & (t < end)] = a
    rot = Rotation.from_euler('ZYX', [yaw0, 0.0, 0.0])
    gyro = GYRO_BIAS + rng.normal(0.0, GYRO_STD, (n, 3))
    # Specific force of a level vehicle accelerating along body x: [a, 0, g] (REP-145).
    accel = np.column_stack([surge, np.zeros(n), np.full(n, G)]) \
        + rng.normal(0.0, ACCEL_STD, (n, 3))
    mag = rot.inv().apply(M_WORLD) + rng.normal(0.0, MAG_STD, (n, 3))
    f = AttitudeFilter(settings)
    est = [f.step(gyro[k], accel[k], mag[k], DT) for k in range(n)]
    return t, est


@pytest.mark.sim
@pytest.mark.parametrize('yaw0', [0.0, math.pi, -2.0, math.pi / 2])
def test_surge_acceleration_does_not_turn_heading_or_yaw_rate(yaw0: float) -> None:
    """Driving off and stopping (0.5 m/s^2 along body x, 0.8 s each) must not move the tilt,
    the heading or the gyro bias: the ROV's yaw loop holds the published rate gyro - b at
    zero, so a z-bias error is a real turn of the vehicle.

    A 0.5 m/s^2 acceleration across gravity changes | |a| - g | by only a^2 / 2g = 0.013
    m/s^2, far inside accel_gate; without the innovation gate the tilt follows the specific
    force to a/g = 51 mrad of pitch, the tilt-compensated magnetometer turns that into a
    heading error of tan(inclination) a/g |cos(yaw)| = 115 mrad when driving east or west,
    and the heading updates feed it into the z bias (seen: 74 mrad, 6.7 mrad/s at yaw 0).
    Heading north the pitch error is about the east axis and leaves the heading alone; that
    case is the control (the coupling, not the acceleration, moves the heading).

    Budget, from the filter's converged state at t = 10 s (its covariance is checked against
    the truth by test_orientation_covariance_is_consistent): with the gravity update skipped
    while accelerating, the tilt runs on the gyro alone, off by at most 4 sigma_b per second
    for 0.8 s; a tilt error reaches the heading multiplied by tan(inclination). So
      pitch error   <= 4 sigma_tilt + 4 sigma_b 0.8 s
      heading error <= 4 sigma_psi + tan(inclination) 4 sigma_b 0.8 s
      z-bias error  <= 4 sigma_b (the rate error the yaw loop sees)
    """
    t, est = surge_run(yaw0)
    rest = np.searchsorted(t, BURSTS[0][0]) - 1
    R = Rotation.from_quat(est[rest].q).as_matrix()
    sigma_world = np.sqrt(np.diag(R @ est[rest].orientation_cov @ R.T))   # tilt, tilt, psi
    sigma_b = math.sqrt(est[rest].omega_cov[2, 2] - SETTINGS.gyro_noise ** 2 / DT)
    gyro_only = 4.0 * sigma_b * (BURSTS[0][1] - BURSTS[0][0])
    after = slice(rest, None)
    q = np.array([e.q for e in est[after]])
    yaw, pitch, roll = Rotation.from_quat(q).as_euler('ZYX').T
    bias_z = np.array([e.gyro_bias[2] for e in est[after]])
    assert np.abs(pitch).max() < 4.0 * sigma_world[1] + gyro_only, np.abs(pitch).max()
    assert np.abs(ssa(yaw - yaw0)).max() < 4.0 * sigma_world[2] + TAN_INCLINATION * gyro_only
    assert np.abs(bias_z - GYRO_BIAS[2]).max() < 4.0 * sigma_b
    # The gate is what did it: (nearly) every accelerating sample skipped, and at rest the
    # chi-square gate at 13.8 (2 dof) drops 0.1 % of the samples (budget 0.5 %).
    accelerating = np.zeros(len(t), dtype=bool)
    for start, end, _ in BURSTS:
        accelerating |= (t >= start) & (t < end)
    used = np.array([e.accel_used for e in est])
    assert used[accelerating].mean() < 0.01
    assert used[~accelerating][1:].mean() > 0.995


def test_innovation_gate_threshold_is_the_chi_square_value() -> None:
    """A steady horizontal specific force d on a level, resting filter: the tilt innovation
    is y = [d, 0, 0] with S_xx = g^2 P_yy + accel_noise^2 (the pitch error about body y
    moves gravity along body x), so NIS = d^2 / S_xx (closed form for a level vehicle; the
    inputs are noise-free and the tilt-bias cross term of the predict is < 0.1 % of P_yy).
    1 % below the gate's d is used, 1 % above is skipped: the margin is finer than the share
    of g^2 P_yy in S_xx (3 %), so S must hold the attitude uncertainty, not R alone. The
    vertical 0.5 m/s^2 (heave, inside accel_gate) must not count: gravity's magnitude
    carries no tilt."""
    gate = GATED.accel_innovation_gate
    for factor, expected in ((0.99, True), (1.01, False)):
        f = _level_static_filter(GATED, seconds=3.0)
        e = f.step(np.zeros(3), [0.0, 0.0, G], M_WORLD, DT)
        # P after the predict of the next step: the covariance grows by the gyro noise of one
        # step (Q = gyro_noise^2 dt on the attitude).
        p_yy = e.orientation_cov[1, 1] + SETTINGS.gyro_noise ** 2 * DT
        d = factor * math.sqrt(gate * (G ** 2 * p_yy + SETTINGS.accel_noise ** 2))
        assert f.step(np.zeros(3), [d, 0.0, G + 0.5], M_WORLD, DT).accel_used is expected


def _sin2_pulse(t: np.ndarray, start: float, length: float,
                peak: float) -> tuple[np.ndarray, np.ndarray]:
    """peak sin^2(pi (t - start) / length) on [start, start + length] and its integral."""
    s = np.clip((t - start) / length, 0.0, 1.0)
    value = np.where((t > start) & (t < start + length), peak * np.sin(np.pi * s) ** 2, 0.0)
    return value, peak * length * (s / 2.0 - np.sin(2.0 * np.pi * s) / (4.0 * np.pi))


PULSE = 1.6          # [s] each speed change: 0 -> 0.4 m/s at up to 0.5 m/s^2, and back
TURN_RATE = -0.16    # [rad/s] the turn the simulated ROV made while driving


def pendulous_drive(gyro_density: float, seed: int = 5, yaw0: float = 0.3) -> tuple[
        np.ndarray, Rotation, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """A hull whose CG hangs below its CB drives off 0.1 s after the filter starts, the way
    the simulated ROV does: it leans into its acceleration (pitch = atan(u' / g), so the
    accelerometer keeps reading "level" while the gyro sees the pitch), turns at TURN_RATE
    for ~5 s while at 0.4 m/s (centripetal u r across the hull), stops, and rests.
    Returns t, the true attitude, the true body rates, gyro (bias GYRO_BIAS, white noise of
    ``gyro_density``), accel, mag, and the largest angle between the true vertical and the
    specific force [rad]."""
    rng = np.random.default_rng(seed)
    t = 9.9 + np.arange(int(16.0 * FS) + 1) * DT
    a1, u1 = _sin2_pulse(t, 10.0, PULSE, 0.5)
    a2, u2 = _sin2_pulse(t, 17.0, PULSE, -0.5)
    udot, u = a1 + a2, u1 + u2
    edge = np.clip(np.minimum(t - 10.5, 16.5 - t), 0.0, 1.0)   # 1 s smooth edges
    r = TURN_RATE * np.sin(0.5 * np.pi * edge) ** 2
    yaw = yaw0 + np.concatenate(([0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * DT)))
    rot = Rotation.from_euler('ZYX', np.column_stack([yaw, np.arctan2(udot, G), 0.0 * t]))
    # World acceleration of a hull driving along its heading: u' ahead, u r to the side.
    acc = np.column_stack([udot * np.cos(yaw) - u * r * np.sin(yaw),
                           udot * np.sin(yaw) + u * r * np.cos(yaw), 0.0 * t])
    rate = np.zeros((len(t), 3))
    rate[1:] = (rot[:-1].inv() * rot[1:]).as_rotvec() / DT    # mean rate over (t - DT, t]
    gyro = rate + GYRO_BIAS + rng.normal(0.0, gyro_density / math.sqrt(DT), (len(t), 3))
    accel = rot.inv().apply(acc + [0.0, 0.0, G]) + rng.normal(0.0, ACCEL_STD, (len(t), 3))
    mag = rot.inv().apply(M_WORLD) + rng.normal(0.0, MAG_STD, (len(t), 3))
    alpha = float(np.max(np.arctan2(np.hypot(acc[:, 0], acc[:, 1]), G)))
    return t, rot, rate, gyro, accel, mag, alpha


@pytest.mark.sim
@pytest.mark.parametrize('gyro_noise', [1e-4, SETTINGS.gyro_noise], ids=['matched', 'default'])
def test_fresh_filter_on_a_pendulous_hull_keeps_gravity(gyro_noise: float) -> None:
    """The simulated ROV with the filter's gyro_noise matched to its gyro (1e-4) drove off at
    once, leaned into its acceleration, and the filter with the innovation gate wrote the
    real pitch and turn into the gyro bias, then refused gravity for accel_gate_timeout
    while the heading ran off (50 deg). By default gravity is always used: the estimate is
    pulled toward the apparent vertical and back to the truth.

    Budget. The accelerometer's apparent vertical is at most alpha (the largest angle
    between the specific force and gravity, from the truth) off the true vertical; the
    bias the filter learns from it can carry the tilt further by at most what a bias error
    of 4 initial_bias_std integrates over one speed change (PULSE). A tilt error reaches
    the compensated heading times tan(inclination), on top of the heading of the first
    magnetometer sample (4 mag_noise):
        tilt    <= alpha + 4 initial_bias_std PULSE                     (10.2 deg here)
        heading <= tan(inclination) (tilt bound) + 4 mag_noise          (34 deg here)
    Measured without the gate: tilt 3.4 / 3.1 deg, heading 8.5 / 7.5 deg (matched /
    default); with it (matched): tilt 20 deg, heading 46 deg."""
    settings = replace(SETTINGS, gyro_noise=gyro_noise)
    t, rot, rate, gyro, accel, mag, alpha = pendulous_drive(gyro_noise)
    f = AttitudeFilter(settings)
    est = [f.step(gyro[k], accel[k], mag[k], DT) for k in range(len(t))]
    q_est = Rotation.from_quat([e.q for e in est])
    z_true, z_est = rot.apply([0.0, 0.0, 1.0]), q_est.apply([0.0, 0.0, 1.0])
    tilt = np.arccos(np.clip(np.einsum('ni,ni->n', z_true, z_est), -1.0, 1.0))
    heading = np.abs(ssa(q_est.as_euler('ZYX')[:, 0] - rot.as_euler('ZYX')[:, 0]))
    tilt_bound = alpha + 4.0 * SETTINGS.initial_bias_std * PULSE
    heading_bound = TAN_INCLINATION * tilt_bound + 4.0 * SETTINGS.mag_noise
    assert math.degrees(alpha) == pytest.approx(2.92, abs=0.05)  # the drive is the one meant
    assert tilt.max() < tilt_bound, (math.degrees(tilt.max()), math.degrees(tilt_bound))
    assert heading.max() < heading_bound, (math.degrees(heading.max()),
                                           math.degrees(heading_bound))
    assert np.mean([e.accel_used for e in est[1:]]) > 0.99


@pytest.mark.sim
def test_innovation_gate_gives_way_after_its_timeout() -> None:
    """Two 3 s accelerations (0.6 of accel_gate_timeout each, rest between) are skipped
    whole: the count of failed samples starts again after a passing one. A 5 deg roll step
    the gyro did not see (a tilt error, not an acceleration) is skipped for exactly
    accel_gate_timeout, then gravity is used again and the roll converges."""
    timeout = GATED.accel_gate_timeout
    burst = int(0.6 * timeout * FS)
    f = _level_static_filter(GATED, seconds=3.0)
    for _ in range(2):
        used = [f.step(np.zeros(3), [1.0, 0.0, G], M_WORLD, DT).accel_used
                for _ in range(burst)]
        assert not any(used)
        used = [f.step(np.zeros(3), [0.0, 0.0, G], M_WORLD, DT).accel_used
                for _ in range(int(2.0 * FS))]
        assert all(used[int(0.5 * FS):])   # back to rest: the tilt the gyro held is right
    truth = Rotation.from_euler('ZYX', [0.0, 0.0, math.radians(5.0)])
    accel, mag = truth.inv().apply([0.0, 0.0, G]), truth.inv().apply(M_WORLD)
    est = [f.step(np.zeros(3), accel, mag, DT) for _ in range(int((timeout + 2.0) * FS))]
    used = np.array([e.accel_used for e in est])
    first = int(np.argmax(used))
    assert first == pytest.approx(timeout * FS, abs=1)
    assert used[first:].all()
    err = (truth.inv() * Rotation.from_quat(est[-1].q)).magnitude()
    assert err < math.radians(0.1), math.degrees(err)


@pytest.mark.parametrize('mag', [np.zeros(3), np.array([0.0, 0.0, -4.5e-5])])
def test_unusable_magnetometer_is_skipped(mag: np.ndarray) -> None:
    """All-zero or vertical field: no heading update, no error."""
    f = _level_static_filter()
    e = f.step(np.zeros(3), [0.0, 0.0, G], mag, DT)
    assert e.accel_used and not e.mag_used


@pytest.mark.parametrize('gyro, accel, mag, dt', [
    ([math.nan, 0.0, 0.0], [0.0, 0.0, G], None, DT),
    ([0.0, 0.0, 0.0], [0.0, math.inf, G], None, DT),
    ([0.0, 0.0, 0.0], [0.0, 0.0, G], [0.0, math.nan, 0.0], DT),
    ([0.0, 0.0, 0.0], [0.0, 0.0, G], None, 0.0),
    ([0.0, 0.0, 0.0], [0.0, 0.0, G], None, -DT),
    ([0.0, 0.0, 0.0], [0.0, 0.0, G], None, math.nan),
    ([0.0, 0.0, 0.0], [0.0, 0.0, G], None, math.inf),
    ([0.0, 0.0], [0.0, 0.0, G], None, DT),
])
def test_bad_input_raises_and_leaves_state(gyro: list[float], accel: list[float],
                                           mag: list[float] | None, dt: float) -> None:
    f = _level_static_filter(seconds=0.1)
    before = f.step(np.zeros(3), [0.0, 0.0, G], None, DT)
    with pytest.raises(ValueError):
        f.step(gyro, accel, mag, dt)
    after = f.step(np.zeros(3), [0.0, 0.0, G], None, DT)
    np.testing.assert_allclose(after.q, before.q, atol=1e-6)
    # A fresh filter refuses bad input on its initialising step too.
    with pytest.raises(ValueError):
        AttitudeFilter().step(gyro, accel, mag, dt)


def test_initialize_rejects_free_fall() -> None:
    with pytest.raises(ValueError, match='accel'):
        AttitudeFilter().initialize(np.zeros(3))


# --- settings -----------------------------------------------------------------------------


BOOL_FIELDS = ['use_magnetometer', 'use_innovation_gate']
NUMERIC_FIELDS = [f.name for f in fields(AttitudeFilterSettings) if f.name not in BOOL_FIELDS]


@pytest.mark.parametrize('name', NUMERIC_FIELDS)
@pytest.mark.parametrize('bad', [0.0, -1.0, math.nan, math.inf, '1.0'])
def test_validate_names_the_bad_field(name: str, bad: object) -> None:
    settings = replace(SETTINGS, **{name: bad})
    with pytest.raises(ValueError, match=name):
        settings.validate()
    with pytest.raises(ValueError, match=name):
        AttitudeFilter(settings)
    f = AttitudeFilter()
    with pytest.raises(ValueError, match=name):
        f.settings = settings
    assert f.settings == SETTINGS


@pytest.mark.parametrize('name', BOOL_FIELDS)
def test_validate_switches_must_be_bool(name: str) -> None:
    with pytest.raises(ValueError, match=name):
        replace(SETTINGS, **{name: 'yes'}).validate()
    SETTINGS.validate()
    replace(SETTINGS, **{name: not getattr(SETTINGS, name)}).validate()


def test_swapping_settings_keeps_state_and_changes_behaviour() -> None:
    """accel_noise x10 after convergence: same state, then slower roll correction."""
    fast = _level_static_filter(seconds=3.0)
    slow = _level_static_filter(seconds=3.0)
    before = slow.step(np.zeros(3), [0.0, 0.0, G], M_WORLD, DT)
    slow.settings = replace(SETTINGS, accel_noise=10.0 * SETTINGS.accel_noise)
    assert slow.initialized and slow.heading_known
    assert slow.settings.accel_noise == pytest.approx(0.5)
    fast.step(np.zeros(3), [0.0, 0.0, G], M_WORLD, DT)
    # The vehicle now sits at 0.5 deg roll (a step the gyro did not see). Innovation
    # g sin(0.5 deg) = 0.086 m/s^2: NIS ~ 0.086^2 / (accel_noise^2 + (g sigma_tilt)^2) ~ 3,
    # inside the innovation gate (a 5 deg step is rejected as an acceleration, see
    # test_innovation_gate_gives_way_after_its_timeout).
    truth = Rotation.from_euler('ZYX', [0.0, 0.0, math.radians(0.5)])
    accel, mag = truth.inv().apply([0.0, 0.0, G]), truth.inv().apply(M_WORLD)
    e_fast = fast.step(np.zeros(3), accel, mag, DT)
    e_slow = slow.step(np.zeros(3), accel, mag, DT)
    # The state survived the swap: one step moved the slow filter less, but from `before`.
    assert (Rotation.from_quat(before.q).inv() * Rotation.from_quat(e_slow.q)).magnitude() < \
        (Rotation.from_quat(before.q).inv() * Rotation.from_quat(e_fast.q)).magnitude()
    for _ in range(int(0.5 * FS)):
        e_fast = fast.step(np.zeros(3), accel, mag, DT)
        e_slow = slow.step(np.zeros(3), accel, mag, DT)
    err_fast = (truth.inv() * Rotation.from_quat(e_fast.q)).magnitude()
    err_slow = (truth.inv() * Rotation.from_quat(e_slow.q)).magnitude()
    assert err_slow > 2.0 * err_fast, (math.degrees(err_slow), math.degrees(err_fast))
    # Bigger R also shows in the covariance: the slow filter is less sure of its tilt.
    assert np.trace(e_slow.orientation_cov) > np.trace(e_fast.orientation_cov)
