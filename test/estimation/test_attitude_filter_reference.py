"""The attitude filter's step against a straightforward formulation of the same maths.

``AttitudeFilter.step`` does its per-sample bookkeeping (quaternions, 3x3 rotations, the
filling of F, Q, H and R) in plain floats and cached matrices, because numpy's overhead per
call dominates arithmetic on 3- and 4-vectors at 400 Hz. ``ReferenceFilter`` below writes the
same filter the obvious way: every quantity a numpy array, every rotation through
``kinematics``, every matrix built afresh each step, filterpy for predict and update. Both are
driven with one long random sequence (tumbling, accelerating, gated and ungated, with missing,
zero and vertical magnetometer samples, jittered dt, settings swapped and the filter reset
along the way); every estimate must agree to rounding. A speed-up that changes the maths
(a sign, an index, a stale cached matrix) fails here even where the behavioural tests of
``test_attitude_filter.py`` would still pass.
"""

from __future__ import annotations

from dataclasses import replace
import math

import numpy as np

from enbarr_core.estimation.attitude_filter import (
    AttitudeEstimate,
    AttitudeFilter,
    AttitudeFilterSettings,
)
from enbarr_core.estimation.filterpy_kalman import KalmanFilter
from enbarr_core.framework.kinematics import (
    quat_from_euler,
    quat_from_rotvec,
    quat_integrate,
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    skew,
    ssa,
)

I3 = np.eye(3)
G = 9.81
M_WORLD = np.array([0.0, 2e-5, -4.5e-5])      # north (+y), downward inclination [T]
FS = 400.0


class ReferenceFilter:
    """The multiplicative EKF of ``attitude_filter``'s docstring, written plainly."""

    def __init__(self, settings: AttitudeFilterSettings) -> None:
        self.settings = settings
        self.kf = KalmanFilter(dim_x=6, dim_z=4)
        self.reset()

    def reset(self) -> None:
        self.initialized = False
        self.heading_known = False
        self.accel_rejected = 0.0
        self.q = np.array([0.0, 0.0, 0.0, 1.0])
        self.b = np.zeros(3)
        self.kf.x = np.zeros((6, 1))
        self.kf.P = np.eye(6)

    def initialize(self, a: np.ndarray, m: np.ndarray | None) -> None:
        s = self.settings
        roll = math.atan2(a[1], a[2])
        pitch = math.atan2(-a[0], math.hypot(a[1], a[2]))
        tilt_std = max(s.accel_noise, s.accel_gate) / s.gravity
        self.q = quat_normalize(quat_from_euler(roll, pitch, 0.0))
        self.b = np.zeros(3)
        R = quat_to_rotmat(self.q)
        P = np.zeros((6, 6))
        P[:3, :3] = R.T @ np.diag([tilt_std ** 2, tilt_std ** 2, 0.0]) @ R
        P[3:, 3:] = s.initial_bias_std ** 2 * I3
        self.kf.x = np.zeros((6, 1))
        self.kf.P = P
        self.heading_known = False
        self.accel_rejected = 0.0
        self.initialized = True
        if s.use_magnetometer and m is not None:
            self.align_heading(m)

    def align_heading(self, m: np.ndarray) -> bool:
        m_norm = np.linalg.norm(m)
        if m_norm <= 1e-12:
            return False
        m_w = quat_to_rotmat(self.q) @ m
        horizontal = math.hypot(m_w[0], m_w[1])
        if horizontal <= 0.05 * m_norm:
            return False
        dpsi = ssa(0.5 * math.pi - math.atan2(m_w[1], m_w[0]))
        self.q = quat_normalize(quat_multiply(quat_from_rotvec([0.0, 0.0, dpsi]), self.q))
        T = np.zeros((6, 6))
        T[:3, :3] = quat_to_rotmat(self.q)
        T[3:, 3:] = I3
        Pw = T @ self.kf.P @ T.T
        tilt_var = max(Pw[0, 0], Pw[1, 1])
        Pw[2, :] = 0.0
        Pw[:, 2] = 0.0
        Pw[2, 2] = self.settings.mag_noise ** 2 + (m_w[2] / horizontal) ** 2 * tilt_var
        self.kf.P = T.T @ Pw @ T
        self.heading_known = True
        return True

    def step(self, w_m: np.ndarray, a: np.ndarray, m: np.ndarray | None,
             dt: float) -> AttitudeEstimate:
        s = self.settings
        kf = self.kf
        if not self.initialized:
            self.initialize(a, m)
            return self.estimate(w_m - self.b, dt, False, False)
        # Predict: F and Q of the module docstring, built in full.
        w = w_m - self.b
        self.q = quat_integrate(self.q, w, dt)
        sg2, sb2 = s.gyro_noise ** 2, s.gyro_bias_walk ** 2
        F = np.block([[quat_to_rotmat(quat_from_rotvec(w * dt)).T,       # exp(-S(w dt))
                       -dt * (I3 - 0.5 * skew(w * dt))],
                      [np.zeros((3, 3)), I3]])
        Q = np.kron(np.array([[sg2 * dt + sb2 * dt ** 3 / 3.0, -0.5 * sb2 * dt * dt],
                              [-0.5 * sb2 * dt * dt, sb2 * dt]]), I3)
        kf.predict(F=F, Q=Q)
        # Update: gravity and heading rows, stacked.
        R_wb = quat_to_rotmat(self.q)
        H_rows, z, r = [], [], []
        accel_used = abs(np.linalg.norm(a) - s.gravity) <= s.accel_gate
        if accel_used:
            h = R_wb.T @ np.array([0.0, 0.0, s.gravity])
            y = a - h
            ra = s.accel_noise ** 2
            if s.use_innovation_gate:
                accel_used = self.gravity_consistent(skew(h), h, y, ra, dt)
            if accel_used:
                H_rows.append(np.hstack([skew(h), np.zeros((3, 3))]))
                z.extend(y)
                r.extend([ra] * 3)
        mag_used = False
        if s.use_magnetometer and m is not None and np.linalg.norm(m) > 1e-12:
            m_w = R_wb @ m
            horizontal = math.hypot(m_w[0], m_w[1])
            if horizontal > 0.05 * np.linalg.norm(m):
                mag_used = True
                if self.heading_known:
                    e_z = np.array([0.0, 0.0, 1.0])
                    H_rows.append(np.hstack([e_z @ R_wb, np.zeros(3)])[None, :])
                    z.append(ssa(0.5 * math.pi - math.atan2(m_w[1], m_w[0])))
                    r.append(s.mag_noise ** 2)
        if H_rows:
            kf.update(np.array(z)[:, None], R=np.diag(r), H=np.vstack(H_rows))
            dtheta, db = kf.x[:3, 0].copy(), kf.x[3:, 0].copy()
            self.q = quat_normalize(quat_multiply(self.q, quat_from_rotvec(dtheta)))
            self.b = self.b + db
            Gm = np.block([[I3 - skew(0.5 * dtheta), np.zeros((3, 3))], [np.zeros((3, 3)), I3]])
            P = Gm @ kf.P @ Gm.T
            kf.P = 0.5 * (P + P.T)
            kf.x = np.zeros((6, 1))
        if mag_used and not self.heading_known and m is not None:
            mag_used = self.align_heading(m)
        return self.estimate(w_m - self.b, dt, accel_used, mag_used)

    def gravity_consistent(self, Hg: np.ndarray, h: np.ndarray, y: np.ndarray, ra: float,
                           dt: float) -> bool:
        s = self.settings
        S = Hg @ self.kf.P[:3, :3] @ Hg.T + ra * I3
        nis = y @ np.linalg.inv(S) @ y - (y @ h) ** 2 / (ra * s.gravity ** 2)
        if nis <= s.accel_innovation_gate:
            self.accel_rejected = 0.0
            return True
        if self.accel_rejected < s.accel_gate_timeout:
            self.accel_rejected += dt
            return False
        return True

    def estimate(self, omega: np.ndarray, dt: float, accel_used: bool,
                 mag_used: bool) -> AttitudeEstimate:
        P = self.kf.P
        return AttitudeEstimate(
            q=self.q.copy(), omega=omega, gyro_bias=self.b.copy(),
            orientation_cov=P[:3, :3].copy(),
            omega_cov=P[3:, 3:] + self.settings.gyro_noise ** 2 / dt * I3,
            accel_used=accel_used, mag_used=mag_used)


DEFAULT = AttitudeFilterSettings()
# (sample index, action) applied to both filters before that sample. The settings swaps fall
# inside runs of a steady dt (see tumbling_imu), so that only the swap can change Q.
EVENTS: dict[int, object] = {
    450: replace(DEFAULT, use_innovation_gate=True, accel_gate_timeout=0.4),
    850: replace(DEFAULT, use_magnetometer=False, gyro_noise=0.01, accel_noise=0.2),
    1000: 'reset',                      # re-initialised without magnetometer: heading unknown
    1250: replace(DEFAULT, mag_noise=0.02, gyro_bias_walk=1e-4, accel_gate=2.0),
    1650: 'initialize without mag',     # then aligned by the first usable sample
    2050: replace(DEFAULT, use_innovation_gate=True, accel_innovation_gate=6.0),
}
# Samples whose gyro reads exactly zero: right after the reset the bias is still zero, so the
# predicted rotation is exactly zero (the small-angle branch of the rotation vector).
ZERO_GYRO = range(1000, 1003)
N_SAMPLES = 2400


def tumbling_imu(n: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray],
                                              list[np.ndarray | None], list[float]]:
    """gyro, accel, mag, dt of a vehicle tumbling (rates up to ~6 rad/s), accelerating in
    bursts (some beyond accel_gate), with jittered dt and unusable magnetometer samples."""
    rng = np.random.default_rng(seed)
    q = quat_from_euler(0.3, -0.2, 1.0)
    rate = np.zeros(3)
    force = np.zeros(3)
    bias = rng.normal(0.0, 0.02, 3)
    gyro, accel, mag, dts = [], [], [], []
    for k in range(n):
        # Runs of 200 samples of a steady dt (Q built once), runs of jitter.
        dt = 1.0 / FS if (k // 200) % 2 == 0 else rng.uniform(0.6, 1.4) / FS
        rate += rng.normal(0.0, 0.15, 3) - 0.002 * rate
        if k % 400 == 300:
            rate = rng.normal(0.0, 4.0, 3)                      # a sudden spin
        q = quat_integrate(q, rate, dt)
        if k % 100 == 0:                                        # a new specific force
            force = rng.normal(0.0, 0.4 if rng.uniform() < 0.7 else 2.0, 3)
        R = quat_to_rotmat(q)
        gyro.append(np.zeros(3) if k in ZERO_GYRO else
                    rate + bias + rng.normal(0.0, 0.003 * math.sqrt(FS), 3))
        accel.append(R.T @ (np.array([0.0, 0.0, G]) + force) + rng.normal(0.0, 0.05, 3))
        u = rng.uniform()
        if u < 0.03:
            mag.append(None)
        elif u < 0.04:
            mag.append(np.zeros(3))
        elif u < 0.05:
            mag.append(R.T @ np.array([0.0, 0.0, -4.5e-5]))    # vertical: no heading
        else:
            mag.append(R.T @ M_WORLD + rng.normal(0.0, 1e-6, 3))
        dts.append(dt)
    return gyro, accel, mag, dts


FIELDS = ('q', 'omega', 'gyro_bias', 'orientation_cov', 'omega_cov')


def assert_same(new: list[AttitudeEstimate], ref: list[AttitudeEstimate]) -> None:
    """Equal flags, and arrays equal to rounding: the two formulations differ only in the
    order of a few additions per step (atol 1e-10 on unit quaternions and rates, a relative
    1e-8 on covariances whose entries span several decades). Names the first sample that
    differs and what differs there."""
    flags = np.array([(e.accel_used, e.mag_used) for e in new])
    bad = {'accel_used/mag_used': (flags != [(e.accel_used, e.mag_used) for e in ref]).any(1)}
    for name in FIELDS:
        a = np.array([getattr(e, name) for e in new]).reshape(len(new), -1)
        b = np.array([getattr(e, name) for e in ref]).reshape(len(ref), -1)
        if name.endswith('cov'):
            tol = 1e-8 * np.abs(b) + 1e-12 * np.abs(b).max(axis=1, keepdims=True)
        else:
            tol = np.full(b.shape, 1e-10)
        bad[name] = (np.abs(a - b) > tol).any(axis=1)
    first = min((int(np.argmax(v)) for v in bad.values() if v.any()), default=None)
    assert first is None, (f'sample {first}: '
                           f'{[name for name, v in bad.items() if v[first]]} differ')


def test_step_matches_the_reference_formulation() -> None:
    gyro, accel, mag, dts = tumbling_imu(N_SAMPLES, seed=1)
    new, ref = AttitudeFilter(DEFAULT), ReferenceFilter(DEFAULT)
    est_new: list[AttitudeEstimate] = []
    est_ref: list[AttitudeEstimate] = []
    seen = {'accel used': 0, 'accel gated by magnitude': 0, 'accel gated by innovation': 0,
            'mag used': 0, 'mag unusable': 0, 'heading aligned': 0}
    for k in range(N_SAMPLES):
        event = EVENTS.get(k)
        if isinstance(event, AttitudeFilterSettings):
            new.settings = ref.settings = event
        elif event == 'reset':
            new.reset()
            ref.reset()
        elif event == 'initialize without mag':
            new.initialize(accel[k], None)
            ref.initialize(accel[k], None)
        heading_known, was_initialized = new.heading_known, new.initialized
        e_new = new.step(gyro[k], accel[k], mag[k], dts[k])
        est_new.append(e_new)
        est_ref.append(ref.step(gyro[k], accel[k], mag[k], dts[k]))
        assert (new.heading_known, new.initialized) == (ref.heading_known, ref.initialized)
        gated_by_magnitude = abs(np.linalg.norm(accel[k]) - new.settings.gravity) > \
            new.settings.accel_gate
        seen['accel used'] += e_new.accel_used
        seen['accel gated by magnitude'] += gated_by_magnitude
        seen['accel gated by innovation'] += was_initialized and not (
            e_new.accel_used or gated_by_magnitude)
        seen['mag used'] += e_new.mag_used
        seen['mag unusable'] += mag[k] is not None and not e_new.mag_used
        seen['heading aligned'] += e_new.mag_used and not heading_known
    assert_same(est_new, est_ref)
    # The sequence went through every branch of the step, more than once.
    assert min(seen.values()) >= 2, seen
