"""Attitude and gyro-bias estimation from a 9-DOF IMU: a multiplicative (error-state) EKF.

Frames and conventions follow :mod:`enbarr_core.framework.kinematics`: world ENU, body FLU,
quaternions ``[x, y, z, w]`` rotating body vectors into the world frame. The accelerometer
reads specific force (``[0, 0, +g]`` at rest and level, REP-145). Magnetic north is world +y,
so a vehicle whose body x axis points north has yaw +pi/2.

Why an error-state filter
-------------------------
A unit quaternion has four numbers but three degrees of freedom, so a Kalman filter run on
the quaternion itself carries a singular 4x4 covariance and needs ad-hoc renormalisation.
The multiplicative EKF (Markley 2003; Sola 2017, "Quaternion kinematics for the error-state
Kalman filter", sec. 7) keeps the *nominal* attitude ``q`` and gyro bias ``b`` outside the
filter and estimates only the small error

    q_true = q (x) q{dtheta},        b_true = b + db,        x = [dtheta, db] (6,)

where ``dtheta`` [rad] is a rotation vector about the body axes and ``q{.}`` is
``kinematics.quat_from_rotvec``. The 6x6 covariance of ``x``
is well conditioned and has exactly the meaning ROS wants in
``sensor_msgs/Imu.orientation_covariance`` (attitude error about body x, y, z).

Each step:

1. Predict. The nominal state is integrated exactly (``kinematics.quat_integrate``) with the
   bias-corrected rate ``w = gyro - b``; the error covariance is propagated by filterpy's
   ``KalmanFilter.predict`` with (Sola 2017, sec. 7; Farrenkopf's gyro model for Q)

       F = [[R(w dt)', -dt (I - S(w dt) / 2)],      dtheta' = -S(w) dtheta - db - n_g
            [0,         I                  ]]       db'     = n_b
       Q = [[sg^2 dt + sb^2 dt^3 / 3, -sb^2 dt^2 / 2],
            [-sb^2 dt^2 / 2,          sb^2 dt       ]] (x) I3

   with ``sg = gyro_noise``, ``sb = gyro_bias_walk`` (continuous densities).
2. Update, one filterpy ``KalmanFilter.update`` call whose measurement stacks what is
   available this step (``x`` is zero after the reset, so ``z`` is passed as the innovation):

   - gravity: ``h = R' [0, 0, g]`` (body), ``y = accel - h``, ``H = [S(h), 0]``. The component
     of ``y`` along ``h`` (the specific-force magnitude) is in the null space of ``H P H'`` and
     gets exactly zero gain, so only the direction of gravity corrects roll and pitch. The
     update is skipped when ``| |accel| - g | > accel_gate`` (the vehicle is accelerating).
     An acceleration a across gravity changes ``|accel|`` by only a^2 / 2g but tilts the
     measured gravity by a / g, and through the tilt-compensated magnetometer that becomes a
     heading error of tan(inclination) a / g, which the heading updates write into the z
     gyro bias (a 0.5 m/s^2 surge at 69 deg inclination: 51 mrad of pitch, 136 mrad of
     heading). The accelerometer's noise model is white, so no setting of this filter tells
     such a sustained specific force from a tilt; the error it leaves is bounded by the
     specific force, a / g, and decays once the vehicle stops accelerating.

     Optionally (``use_innovation_gate``, off by default) the update is also skipped when
     the tilt part of its innovation fails a chi-square test (normalized innovation
     squared, 2 degrees of freedom, above ``accel_innovation_gate``), and after
     ``accel_gate_timeout`` of failures in a row gravity is used again until a sample
     passes. That removes the surge error of a *converged* filter on a hull that does not
     pitch, but the gate trusts the filter's tilt, and that trust can be wrong: a fresh
     filter (gyro bias still uncertain) on a pendulous hull, which leans into its own
     acceleration so that the accelerometer keeps reading "level" while the gyro sees the
     pitch, writes the real rotation into the bias within a second; the tilt error then
     exceeds the gate, gravity is refused for ``accel_gate_timeout`` while the magnetometer
     (compensated with the wrong tilt) keeps feeding the heading error into the z bias, and
     a yaw-rate loop on the published rate turns the vehicle (seen in the simulated ROV
     with ``gyro_noise`` matched to its gyro: 50 deg of heading error in 5 s). Without the
     gate the same start leaves a transient that gravity pulls back. A gate that is safe
     needs a model of the vehicle's own acceleration in the filter (a Gauss-Markov
     specific-force state), which this filter does not have.
   - heading: the magnetometer is rotated to the world frame with the estimated attitude and
     its horizontal part compared with north, ``y = ssa(pi/2 - atan2(m_w,y, m_w,x))``; that is
     the tilt-compensated heading minus the estimated yaw. A yaw error is a rotation about
     world z, so ``H = [e_z' R, 0]`` and the magnetometer corrects heading only: a magnetic
     disturbance (thrusters, a steel hull) cannot pull roll and pitch off the gravity vector.
     The heading error caused by the tilt error (factor tan(inclination)) is small next to
     ``mag_noise`` once the tilt has converged and is treated as part of that noise.

   While the heading is unknown (no usable magnetometer sample yet) yaw is referenced to the
   heading at initialisation and carries zero initial variance; the first usable magnetometer
   sample then rotates the estimate about world z onto north and sets the heading variance,
   instead of a Kalman update. A yaw variance of order pi^2 would be far outside the
   linearisation: every small tilt correction leaks it into the tilt axes, and the gravity
   updates then "observe" yaw and turn it by tens of degrees (seen in simulation).

   filterpy applies the Joseph form ``P = (I-KH)P(I-KH)' + KRK'``, which keeps ``P``
   symmetric positive definite for any gain.
3. Inject and reset: ``q <- q (x) q{dtheta}``, ``b <- b + db``, ``x <- 0`` and
   ``P <- G P G'`` with ``G = blockdiag(I - S(dtheta / 2), I)`` (Sola 2017, sec. 7).

The step does a 6x6 predict and one small update: no scipy and no per-step allocation of the
filter object, so it runs at IMU rate (400 Hz) on a Raspberry Pi. What is not a matrix
product of the filter (the nominal quaternion and bias, rotations of 3-vectors, the entries
of ``F``, ``H`` and ``G``) is computed in Python floats, where a numpy call would cost more
than its arithmetic; what depends only on the settings and ``dt`` (``Q``, ``R``) is built
once and rebuilt when they change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from enbarr_core.estimation.filterpy_kalman import KalmanFilter
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.kinematics import (
    quat_from_euler,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    quat_to_rotmat,
    skew,
    ssa,
)

Vector = NDArray[np.float64]
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]          # [x, y, z, w]
RotMat = tuple[float, float, float, float, float, float, float, float, float]  # row-major

# A magnetometer vector shorter than this is "no reading" (a driver publishing zeros).
_MIN_MAG_NORM = 1e-12
# Skip the heading update when the horizontal field is less than this fraction of the field
# (inclination above ~87 deg, i.e. near a magnetic pole): the heading would be mostly noise.
_MIN_MAG_HORIZONTAL_FRACTION = 0.05
# Below this the accelerometer carries no gravity direction to initialise from [m/s^2].
_MIN_ACCEL_NORM = 1e-6

_I3 = np.eye(3)
# Switches among the settings; every other field is a positive finite number.
_BOOL_FIELDS = ('use_magnetometer', 'use_innovation_gate')


@dataclass(frozen=True)
class AttitudeFilterSettings:
    """Noise model and options of :class:`AttitudeFilter`.

    gyro_noise: gyro white-noise density [rad/s/sqrt(Hz)] (angle random walk).
    gyro_bias_walk: gyro bias random-walk density [rad/s^2/sqrt(Hz)].
    accel_noise: accelerometer noise std per sample [m/s^2].
    mag_noise: std of the heading from the tilt-compensated magnetometer [rad].
    accel_gate: skip the gravity update when | |a| - g | exceeds this [m/s^2].
    use_innovation_gate: also gate the gravity update on its innovation (off by default: it
        can lock a fresh filter out of gravity, see the module docstring).
    accel_innovation_gate: with ``use_innovation_gate``, skip the gravity update when the
        normalized innovation squared of its tilt part (chi-square, 2 dof) exceeds this;
        13.8 drops 0.1 % of the samples of a vehicle at rest.
    accel_gate_timeout: after the innovation gate has failed this long in a row, use
        gravity again [s]. 5 s covers the ROV's reference accelerating at 0.5 m/s^2 from
        full reverse to full ahead (2 m/s: 4 s).
    use_magnetometer: correct heading with the magnetometer (else yaw drifts with the gyro).
    initial_bias_std: std of the gyro bias at initialisation [rad/s].
    gravity: magnitude of gravity [m/s^2].
    """

    gyro_noise: float = 0.003
    gyro_bias_walk: float = 1e-5
    accel_noise: float = 0.05
    mag_noise: float = 0.05
    accel_gate: float = 1.0
    use_innovation_gate: bool = False
    accel_innovation_gate: float = 13.8
    accel_gate_timeout: float = 5.0
    use_magnetometer: bool = True
    initial_bias_std: float = 0.02
    gravity: float = 9.81

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first field that is not a positive finite number."""
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in _BOOL_FIELDS:
                if not isinstance(value, (bool, np.bool_)):
                    raise ValueError(
                        f'AttitudeFilterSettings.{f.name} must be a bool, got {value!r}')
                continue
            if isinstance(value, (bool, np.bool_)) or not isinstance(
                    value, (int, float, np.integer, np.floating)):
                raise ValueError(
                    f'AttitudeFilterSettings.{f.name} must be a number, got {value!r}')
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(
                    f'AttitudeFilterSettings.{f.name} must be positive and finite, '
                    f'got {value!r}')


@dataclass(frozen=True)
class AttitudeEstimate:
    """Output of one :meth:`AttitudeFilter.step` (arrays are read-only).

    q: (4,) ``[x, y, z, w]`` body -> world (ENU) attitude.
    omega: (3,) bias-corrected body rate [rad/s].
    gyro_bias: (3,) estimated gyro bias [rad/s].
    orientation_cov: (3, 3) covariance of the attitude error about body x, y, z [rad^2].
    omega_cov: (3, 3) covariance of ``omega`` (gyro noise of one sample plus bias
        uncertainty) [(rad/s)^2].
    accel_used: the gravity update ran this step (False: gated out, or initialising step).
    mag_used: the magnetometer corrected (or, the first time, aligned) the heading this step.
    """

    q: Vector
    omega: Vector
    gyro_bias: Vector
    orientation_cov: Vector
    omega_cov: Vector
    accel_used: bool = False
    mag_used: bool = False


def _vector3(value: ArrayLike, name: str) -> Vec3:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,):
        raise ValueError(f'{name} must have shape (3,), got {v.shape}')
    x, y, z = v.tolist()
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f'{name} is not finite: {v!r}')
    return x, y, z


# The quaternion helpers of ``kinematics`` in Python floats, for the per-sample path; the
# reference test of the filter checks them (through the step) against ``kinematics``.

def _as_quat(q: Vector) -> Quat:
    x, y, z, w = q.tolist()
    return x, y, z, w


def _quat_normalize(x: float, y: float, z: float, w: float) -> Quat:
    """``kinematics.quat_normalize``: unit norm, w >= 0."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n == 0.0 or not math.isfinite(n):
        raise ValueError(f'cannot normalize quaternion {[x, y, z, w]!r}')
    if w < 0.0:
        n = -n
    return x / n, y / n, z / n, w / n


def _quat_from_rotvec(x: float, y: float, z: float) -> Quat:
    """``kinematics.quat_from_rotvec``: quaternion of the rotation vector [rad], exact."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return _quat_normalize(0.5 * x, 0.5 * y, 0.5 * z, 1.0)
    s = math.sin(0.5 * angle) / angle
    return s * x, s * y, s * z, math.cos(0.5 * angle)


def _quat_multiply(q1: Quat, q2: Quat) -> Quat:
    """``kinematics.quat_multiply``: Hamilton product q1 (x) q2."""
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)


def _rotmat(q: Quat) -> RotMat:
    """``kinematics.quat_to_rotmat``, row-major: R(q) (body -> world)."""
    x, y, z, w = q
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w),
            2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w),
            2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))


def _frozen(a: Vector) -> Vector:
    a.setflags(write=False)
    return a


class AttitudeFilter:
    """Multiplicative EKF for attitude and gyro bias (see the module docstring)."""

    def __init__(self, settings: AttitudeFilterSettings = AttitudeFilterSettings()) -> None:
        settings.validate()
        self._kf = KalmanFilter(dim_x=6, dim_z=4)
        self._q: Quat = (0.0, 0.0, 0.0, 1.0)
        self._b: Vec3 = (0.0, 0.0, 0.0)
        self._initialized = False
        self._heading_known = False
        self._accel_rejected = 0.0  # time the gravity innovation gate has failed in a row [s]
        # Per-step matrices, filled in place: F and G through flat views of their top rows
        # (one numpy call each), H and z as one 4-row buffer whose first three rows are the
        # gravity update and whose last row is the heading update.
        self._F = np.eye(6)
        self._G = np.eye(6)
        self._F_flat = self._F.reshape(36)
        self._G_flat = self._G.reshape(36)
        self._H = np.zeros((4, 6))
        self._H_flat = self._H.reshape(24)
        self._z = np.zeros((4, 1))
        self._z_flat = self._z.reshape(4)
        # What depends on the settings and dt only, rebuilt when either changes.
        self._Q = np.zeros((6, 6))
        self._omega_noise = np.zeros((3, 3))   # gyro noise of one sample in omega_cov
        self._noise_dt: float | None = None    # the dt that Q and _omega_noise are for
        self._R_gravity = self._R_heading = self._R_both = np.zeros((0, 0))
        self.settings = settings
        # filterpy's own F and Q are ours, filled in place: predict() reads them without the
        # checks it makes of matrices passed as arguments.
        self._kf.F = self._F
        self._kf.Q = self._Q
        self.reset()

    @property
    def settings(self) -> AttitudeFilterSettings:
        """Return the noise model and gates in use."""
        return self._settings

    @settings.setter
    def settings(self, settings: AttitudeFilterSettings) -> None:
        """Swap in new settings; Q and R use them from the next step, the state is kept."""
        settings.validate()
        self._settings = settings
        ra, rm = settings.accel_noise ** 2, settings.mag_noise ** 2
        self._R_gravity = np.diag([ra, ra, ra])
        self._R_heading = np.array([[rm]])
        self._R_both = np.diag([ra, ra, ra, rm])
        self._noise_dt = None

    def _use_dt(self, dt: float) -> None:
        """Build Q and the one-sample gyro noise of omega for ``dt`` unless already done."""
        if dt == self._noise_dt:
            return
        s = self._settings
        sg2, sb2 = s.gyro_noise ** 2, s.gyro_bias_walk ** 2
        Q = self._Q
        Q[:3, :3] = (sg2 * dt + sb2 * dt ** 3 / 3.0) * _I3
        Q[:3, 3:] = Q[3:, :3] = (-0.5 * sb2 * dt * dt) * _I3
        Q[3:, 3:] = (sb2 * dt) * _I3
        self._omega_noise = (sg2 / dt) * _I3
        self._noise_dt = dt

    @property
    def initialized(self) -> bool:
        """Whether the filter has an attitude (from its first sample on)."""
        return self._initialized

    def reset(self) -> None:
        """Forget the state; the next :meth:`step` (or :meth:`initialize`) starts over."""
        self._initialized = False
        self._heading_known = False
        self._accel_rejected = 0.0
        self._q = (0.0, 0.0, 0.0, 1.0)
        self._b = (0.0, 0.0, 0.0)
        self._kf.x = np.zeros((6, 1))
        self._kf.P = np.eye(6)

    @property
    def heading_known(self) -> bool:
        """Yaw is referenced to magnetic north (else to the heading at initialisation)."""
        return self._heading_known

    def initialize(self, accel: ArrayLike, mag: ArrayLike | None = None) -> None:
        """Attitude from one sample: roll and pitch from gravity, yaw from the magnetometer.

        accel: specific force [m/s^2] (body). mag: magnetic field (body, any unit) or None.
        Without a usable magnetometer (None, ``use_magnetometer`` False, or a field too
        vertical to give a heading) yaw starts at 0 with zero variance, i.e. the world frame is
        the initial heading, and is aligned to north by the first usable magnetometer sample.
        The gyro bias starts at zero with std ``initial_bias_std``.
        """
        s = self._settings
        ax, ay, az = _vector3(accel, 'accel')
        m = None if mag is None else _vector3(mag, 'mag')
        if math.sqrt(ax * ax + ay * ay + az * az) < _MIN_ACCEL_NORM:
            raise ValueError(f'accel {[ax, ay, az]!r} is too small to give the gravity '
                             'direction')
        # a = g [-sin(theta), sin(phi) cos(theta), cos(phi) cos(theta)] at rest.
        roll = math.atan2(ay, az)
        pitch = math.atan2(-ax, math.hypot(ay, az))
        # One sample of a possibly moving vehicle: tilt std from noise or the largest accepted
        # non-gravitational specific force, whichever is larger [rad].
        tilt_std = max(s.accel_noise, s.accel_gate) / s.gravity
        q = quat_normalize(quat_from_euler(roll, pitch, 0.0))
        self._q = _as_quat(q)
        self._b = (0.0, 0.0, 0.0)
        # Attitude covariance is diagonal in the world frame (tilt, tilt, heading); express it
        # about the body axes: dtheta_body = R' dtheta_world.
        R = quat_to_rotmat(q)
        P = np.zeros((6, 6))
        P[:3, :3] = R.T @ np.diag([tilt_std ** 2, tilt_std ** 2, 0.0]) @ R
        P[3:, 3:] = s.initial_bias_std ** 2 * _I3
        self._kf.x = np.zeros((6, 1))
        self._kf.P = P
        self._heading_known = False
        self._accel_rejected = 0.0
        self._initialized = True
        if s.use_magnetometer and m is not None:
            self._align_heading(m)

    def _align_heading(self, mag: Vec3) -> bool:
        """Rotate the estimate about world z so the magnetometer points north; True if done.

        Used instead of a Kalman update while the heading is unknown: a yaw error of up to pi
        is far outside the linearisation of the filter. The world-z rows of the attitude
        covariance are replaced by the heading variance of the magnetometer, which is
        ``mag_noise^2`` plus the tilt variance times tan(inclination)^2.
        """
        m = np.array(mag)
        m_norm = math.sqrt(float(m @ m))
        if m_norm <= _MIN_MAG_NORM:
            return False
        m_w = quat_to_rotmat(self._q) @ m
        horizontal = math.hypot(m_w[0], m_w[1])
        if horizontal <= _MIN_MAG_HORIZONTAL_FRACTION * m_norm:
            return False
        dpsi = float(ssa(0.5 * math.pi - math.atan2(m_w[1], m_w[0])))
        q = quat_normalize(quat_multiply(quat_from_rotvec([0.0, 0.0, dpsi]), self._q))
        self._q = _as_quat(q)
        T = np.zeros((6, 6))                                        # body -> world error axes
        T[:3, :3] = quat_to_rotmat(q)
        T[3:, 3:] = _I3
        Pw = T @ self._kf.P @ T.T
        tilt_var = max(Pw[0, 0], Pw[1, 1])
        Pw[2, :] = 0.0
        Pw[:, 2] = 0.0
        Pw[2, 2] = self._settings.mag_noise ** 2 + (m_w[2] / horizontal) ** 2 * tilt_var
        self._kf.P = T.T @ Pw @ T
        self._heading_known = True
        return True

    def step(self, gyro: ArrayLike, accel: ArrayLike, mag: ArrayLike | None,
             dt: float) -> AttitudeEstimate:
        """Advance the filter by one IMU sample.

        gyro: body rate [rad/s]. accel: specific force [m/s^2] (body). mag: magnetic field
        (body, any unit; only its direction is used) or None. dt: time since the previous
        sample [s], > 0. Raises ``ValueError`` on non-finite input or a bad ``dt``, leaving
        the state untouched. The first call only initialises from ``accel`` and ``mag``.
        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be positive and finite, got {dt!r}')
        wmx, wmy, wmz = _vector3(gyro, 'gyro')
        ax, ay, az = _vector3(accel, 'accel')
        m = None if mag is None else _vector3(mag, 'mag')
        s = self._settings
        kf = self._kf
        self._use_dt(dt)

        if not self._initialized:
            self.initialize((ax, ay, az), m)
            bx, by, bz = self._b
            return self._estimate((wmx - bx, wmy - by, wmz - bz), False, False)

        # --- predict -----------------------------------------------------------------------
        bx, by, bz = self._b
        px, py, pz = (wmx - bx) * dt, (wmy - by) * dt, (wmz - bz) * dt     # w dt
        dq = _quat_from_rotvec(px, py, pz)
        self._q = _quat_normalize(*_quat_multiply(self._q, dq))      # q (x) exp(w dt / 2)
        r = _rotmat(dq)
        hx, hy, hz = 0.5 * px, 0.5 * py, 0.5 * pz
        # F[:3] = [R(w dt)', -dt (I - S(w dt) / 2)]: R(w dt)' = exp(-S(w dt)).
        self._F_flat[:18] = [r[0], r[3], r[6], -dt, -dt * hz, dt * hy,
                             r[1], r[4], r[7], dt * hz, -dt, -dt * hx,
                             r[2], r[5], r[8], -dt * hy, dt * hx, -dt]
        kf.predict()                                                # P = FPF' + Q

        # --- update ------------------------------------------------------------------------
        R = _rotmat(self._q)
        g = s.gravity
        accel_used = abs(math.sqrt(ax * ax + ay * ay + az * az) - g) <= s.accel_gate
        if accel_used:
            gx, gy, gz = g * R[6], g * R[7], g * R[8]               # h = R' [0, 0, g]
            y = (ax - gx, ay - gy, az - gz)                         # y = z - h(x)
            if s.use_innovation_gate:
                accel_used = self._gravity_consistent((gx, gy, gz), y, dt)
        heading: float | None = None
        mag_used = False
        if s.use_magnetometer and m is not None:
            mx, my, mz = m
            m_norm = math.sqrt(mx * mx + my * my + mz * mz)
            if m_norm > _MIN_MAG_NORM:
                mwx = R[0] * mx + R[1] * my + R[2] * mz             # m_w = R m
                mwy = R[3] * mx + R[4] * my + R[5] * mz
                horizontal = math.hypot(mwx, mwy)
                if horizontal > _MIN_MAG_HORIZONTAL_FRACTION * m_norm:
                    mag_used = True
                    if self._heading_known:
                        heading = ssa(0.5 * math.pi - math.atan2(mwy, mwx))
        if accel_used or heading is not None:
            # Rows 0-2: gravity, H = [S(h), 0]; row 3: heading, H = [e_z' R, 0].
            H, z = self._H, self._z
            if accel_used:
                self._H_flat[:18] = [0.0, -gz, gy, 0.0, 0.0, 0.0,
                                     gz, 0.0, -gx, 0.0, 0.0, 0.0,
                                     -gy, gx, 0.0, 0.0, 0.0, 0.0]
                self._z_flat[:3] = y
            if heading is not None:
                self._H_flat[18:21] = R[6:]
                self._z_flat[3] = heading
            # filterpy's R set rather than passed: update() then skips its scalar check.
            if not accel_used:
                kf.R = self._R_heading
                kf.update(z[3:], H=H[3:])                           # K = PH'inv(HPH' + R)
            elif heading is None:
                kf.R = self._R_gravity
                kf.update(z[:3], H=H[:3])
            else:
                kf.R = self._R_both
                kf.update(z, H=H)
            # --- inject the error into the nominal state and reset it ----------------------
            dx, dy, dz, dbx, dby, dbz = kf.x.ravel().tolist()
            self._q = _quat_normalize(*_quat_multiply(self._q, _quat_from_rotvec(dx, dy, dz)))
            self._b = (bx + dbx, by + dby, bz + dbz)
            ex, ey, ez = 0.5 * dx, 0.5 * dy, 0.5 * dz
            self._G_flat[:18] = [1.0, ez, -ey, 0.0, 0.0, 0.0,       # G = I - S(dtheta / 2)
                                 -ez, 1.0, ex, 0.0, 0.0, 0.0,
                                 ey, -ex, 1.0, 0.0, 0.0, 0.0]
            G = self._G
            P = G @ kf.P @ G.T                                      # P = GPG'
            kf.P = 0.5 * (P + P.T)
            kf.x = np.zeros((6, 1))
        if mag_used and not self._heading_known and m is not None:  # mag_used: m is given
            mag_used = self._align_heading(m)                       # first heading: snap to it
        bx, by, bz = self._b
        return self._estimate((wmx - bx, wmy - by, wmz - bz), accel_used, mag_used)

    def _gravity_consistent(self, h: Vec3, y: Vec3, dt: float) -> bool:
        """Whether the gravity update may run: its tilt innovation passes the chi-square gate.

        The normalized innovation squared of the two components of ``y`` across ``h`` (the
        ones that correct the tilt) is ``y' S^-1 y - (y . h)^2 / (r g^2)`` with
        ``S = Hg P Hg' + r I``, ``Hg = S(h)``: ``h`` is an eigenvector of ``S`` with eigenvalue
        ``r``, so the along-``h`` term is taken out exactly. A sample that fails is skipped,
        unless the gate has failed for ``accel_gate_timeout`` in a row: then the estimate is
        more likely wrong than the vehicle still accelerating, and samples are used again
        until one passes.
        """
        s = self._settings
        ra = s.accel_noise ** 2
        Hg = skew(h)
        h_, y_ = np.array(h), np.array(y)
        S = Hg @ self._kf.P[:3, :3] @ Hg.T + ra * _I3
        nis = float(y_ @ np.linalg.solve(S, y_)) - float(y_ @ h_) ** 2 / (ra * s.gravity ** 2)
        if nis <= s.accel_innovation_gate:
            self._accel_rejected = 0.0
            return True
        if self._accel_rejected < s.accel_gate_timeout:
            self._accel_rejected += dt
            return False
        return True

    def _estimate(self, omega: Vec3, accel_used: bool, mag_used: bool) -> AttitudeEstimate:
        P = self._kf.P
        return AttitudeEstimate(
            q=_frozen(np.array(self._q)),
            omega=_frozen(np.array(omega)),
            gyro_bias=_frozen(np.array(self._b)),
            orientation_cov=_frozen(P[:3, :3].copy()),
            omega_cov=_frozen(P[3:, 3:] + self._omega_noise),
            accel_used=accel_used,
            mag_used=mag_used,
        )
