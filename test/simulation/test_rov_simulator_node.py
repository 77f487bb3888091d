"""Node tests: rov simulator node (with the simulated IMU measuring it)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, JointState, MagneticField
from support.nodes import TIMEOUT, add, probe
from support.rov import G, overrides, sim_parameters
from support.saucer import SimClock

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.kinematics import quat_from_euler, quat_to_euler
from enbarr_core.models.rigid_body import RigidBodyState
from enbarr_core.simulation.rov_simulator_node import RovSimulatorNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.imu.sim import SimImuNode

BIAS = [0.01, -0.02, 0.03]


class Run:
    """The simulator stepped by hand 400 times, the simulated IMU listening; by stamp."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.sim = sim = add(executor, RovSimulatorNode(
            node_name='simulator', context=context,
            parameter_overrides=overrides(sim_parameters('simulator'))))
        self.imu = add(executor, SimImuNode(node_name='imu', context=context,
                                            parameter_overrides=[
                                                Parameter('gyro_bias', value=BIAS),
                                                Parameter('gyro_noise', value=0.002)]))
        p = probe(context, executor, 'listener')
        self.truth: dict[int, Imu] = {}
        self.raw: dict[int, Imu] = {}
        self.mags: dict[int, MagneticField] = {}
        for spec, into in ((topics.SIM_IMU, self.truth), (topics.IMU_RAW, self.raw),
                           (topics.IMU_MAG, self.mags)):
            p.create_topic_subscription(
                spec, lambda m, d=into: d.__setitem__(convert.stamp_to_ns(m.header.stamp), m))
        LinkBus.of(context).connect()
        self.started = sim.rate_loops[0].running
        deadline = time.monotonic() + TIMEOUT
        while sim.samples < 400 and time.monotonic() < deadline:
            sim.step()
            time.sleep(0.001)
        self.stamps = sorted(self.truth)

    def errors(self, field: str) -> np.ndarray:
        return np.array([convert.vector3_to_array(getattr(self.raw[s], field))
                         - convert.vector3_to_array(getattr(self.truth[s], field))
                         for s in self.stamps])


@pytest.fixture
def run(context, executor) -> Run:
    return Run(context, executor)


def test_not_started_until_bringup_starts_it(run):
    assert not run.started  # never started: driven by hand


def test_every_step_is_one_truth_and_one_imu_sample(run):
    assert run.sim.samples >= 400
    assert len(run.truth) == len(run.raw) == len(run.mags) == run.sim.samples
    assert run.stamps == sorted(run.raw) == sorted(run.mags)
    assert np.all(np.diff(run.stamps) > 0)


def test_truth_at_rest_is_level_with_gravity_up(run):
    f = np.array([convert.vector3_to_array(m.linear_acceleration) for m in run.truth.values()])
    assert f == pytest.approx(np.tile([0.0, 0.0, G], (len(f), 1)), abs=1e-2)
    for m in run.truth.values():
        roll, pitch, yaw = quat_to_euler(convert.quaternion_to_array(m.orientation))
        assert abs(roll) < 1e-3 and abs(pitch) < 1e-3 and abs(yaw) < 1e-3


def test_gyro_has_the_bias_and_noise_asked(run):
    gyro_err = run.errors('angular_velocity')
    n = len(run.stamps)
    assert gyro_err.mean(axis=0) == pytest.approx(BIAS, abs=5 * 0.002 / math.sqrt(n))
    assert gyro_err.std(axis=0) == pytest.approx([0.002] * 3, rel=0.25)


def test_accelerometer_has_the_default_noise_and_no_bias(run):
    accel_err = run.errors('linear_acceleration')
    n = len(run.stamps)
    assert accel_err.mean(axis=0) == pytest.approx(np.zeros(3), abs=5 * 0.03 / math.sqrt(n))
    assert accel_err.std(axis=0) == pytest.approx([0.03] * 3, rel=0.25)


def test_raw_imu_carries_no_orientation(run):
    assert run.raw[run.stamps[0]].orientation_covariance[0] == -1.0


def test_magnetometer_measures_the_earth_field(run):
    m = np.array([convert.vector3_to_array(run.mags[s].magnetic_field) for s in run.stamps])
    assert m.mean(axis=0) == pytest.approx([0.0, 1.8e-5, -4.8e-5], abs=2e-7)


def test_initial_position_needs_three_values(context):
    with pytest.raises(ConfigurationError, match=r'initial.position: expected 3 values, got 2'):
        RovSimulatorNode(context=context, parameter_overrides=overrides(
            {**sim_parameters('simulator'), 'initial.position': [0.0, 1.0]}))


def test_vehicle_errors_name_the_parameter(context):
    with pytest.raises(ConfigurationError, match=r'vehicle.d_lin\b'):
        RovSimulatorNode(context=context, parameter_overrides=overrides(
            {**sim_parameters('simulator'), 'vehicle.d_lin': [1.0, 2.0]}))


@pytest.mark.parametrize('missing', [
    'vehicle.mass', 'vehicle.inertia', 'vehicle.added_mass', 'vehicle.d_lin', 'vehicle.d_quad',
    'vehicle.r_g', 'vehicle.r_b', 'vehicle.buoyancy'])
def test_the_vehicle_comes_from_the_profile_only(context, missing):
    """Vessel data has no default in the code: without it the simulator refuses to start,
    naming the parameter (bringup turns this into a ProfileError naming the file)."""
    given = {k: v for k, v in sim_parameters('simulator').items() if k != missing}
    with pytest.raises(ConfigurationError, match=(
            f"node 'simulator': parameter '{missing}' is not set; the profile must give it")):
        RovSimulatorNode(node_name='simulator', context=context,
                         parameter_overrides=overrides(given))


def test_sim_imu_bias_needs_three_values(context):
    with pytest.raises(ConfigurationError, match=r'gyro_bias: expected 3 values, got 2'):
        SimImuNode(context=context, parameter_overrides=[
            Parameter('gyro_bias', value=[0.0, 0.1])])


# -- away from rest: the published odometry against closed forms -----------------------------
#
# The simulator is stepped on a simulated clock (1/rate per step) from a moving start, with no
# thrust, and sim/odometry is compared with solutions written here from the equations of
# motion, with scipy's Rotation for the attitude (independent of the package's kinematics).
# Budget of every comparison: RK4 at dt = 2.5 ms on motions no faster than 1 rad/s and time
# constants of 4 s has a global error of order (1 rad/s dt)^4 t ~ 1e-10; 1e-8 is that with
# room for float64 rounding of 800 steps.

RATE = 400.0
TOL = 1e-8


class Coast:
    """The simulator started at ``p0``, ``rpy0`` with body velocity ``nu0``, coasting 2 s."""

    def __init__(self, context: Any, executor: Any, vehicle: dict[str, Any], p0: list[float],
                 rpy0: list[float], nu0: list[float], seconds: float = 2.0) -> None:
        params = {**sim_parameters('simulator'), 'rate': RATE, 'odometry_rate': 50.0,
                  'initial.position': p0, 'initial.rpy': rpy0,
                  **{f'vehicle.{k}': v for k, v in vehicle.items()}}
        self.sim = sim = add(executor, RovSimulatorNode(
            node_name='simulator', context=context, parameter_overrides=overrides(params)))
        sim.state = RigidBodyState(sim.state.p, sim.state.q, np.array(nu0, dtype=float))
        clock = SimClock(sim)
        self.t0_ns = clock.ns
        p = probe(context, executor, 'listener')
        self.odom: list[Odometry] = []
        p.create_topic_subscription(topics.SIM_ODOMETRY, self.odom.append)
        LinkBus.of(context).connect()
        for _ in range(round(seconds * RATE)):
            clock.advance(1.0 / RATE)
            sim.step()
        assert sim.steps == round(seconds * RATE) and len(self.odom) == round(seconds * 50.0)

    def samples(self):
        """(t [s since start], position, rotation, body linear velocity, body rate) per msg."""
        for m in self.odom:
            assert m.header.frame_id == topics.WORLD_FRAME
            assert m.child_frame_id == topics.BODY_FRAME
            yield ((convert.stamp_to_ns(m.header.stamp) - self.t0_ns) * 1e-9,
                   convert.vector3_to_array(m.pose.pose.position),
                   Rotation.from_quat(convert.quaternion_to_array(m.pose.pose.orientation)),
                   convert.vector3_to_array(m.twist.twist.linear),
                   convert.vector3_to_array(m.twist.twist.angular))


MASS, G_SIM = 11.5, 9.81
BALANCED = {'r_g': [0.0, 0.0, 0.0], 'r_b': [0.0, 0.0, 0.0], 'buoyancy': MASS * G_SIM}


def test_isotropic_vehicle_coasts_in_a_straight_line_while_it_tumbles(context, executor):
    """Equal total inertia on every linear axis and on every rotational axis, linear damping,
    CG = CB = CO, neutral: in the world frame the linear velocity decays along a fixed line,
    w(t) = R0 v0 exp(-t / tau_v), whatever the rotation (the Coriolis term omega x v only
    turns the body-frame velocity); the body rate decays about a fixed axis,
    omega(t) = omega0 exp(-t / tau_w), so R(t) = R0 Rot(omega0 / |omega0|, theta(t)).
    Heading starts at 3.0 rad and turns through +-pi."""
    m_v, d_v = MASS + 5.5, 4.0          # total inertia [kg], damping [N s/m] on x, y, z
    m_w, d_w = 0.16 + 0.12, 0.07        # [kg m^2], [N m s/rad] about x, y, z
    p0, rpy0 = [1.0, -2.0, -1.5], [0.1, -0.2, 3.0]
    v0, w0 = np.array([0.4, -0.2, 0.1]), np.array([0.3, -0.4, 0.9])
    run = Coast(context, executor, {
        **BALANCED, 'inertia': [0.16] * 3, 'added_mass': [5.5] * 3 + [0.12] * 3,
        'd_lin': [d_v] * 3 + [d_w] * 3, 'd_quad': [0.0] * 6}, p0, rpy0, [*v0, *w0])
    tau_v, tau_w = m_v / d_v, m_w / d_w
    R0 = Rotation.from_euler('ZYX', rpy0[::-1])
    world_v0 = R0.apply(v0)
    turned = 0.0
    for t, p, rot, v_body, w_body in run.samples():
        w_world = world_v0 * math.exp(-t / tau_v)
        np.testing.assert_allclose(p, np.array(p0) + world_v0 * tau_v * (1 - math.exp(-t / tau_v)),
                                   rtol=0.0, atol=TOL)
        theta = np.linalg.norm(w0) * tau_w * (1.0 - math.exp(-t / tau_w))
        expected = R0 * Rotation.from_rotvec(w0 / np.linalg.norm(w0) * theta)
        assert (expected.inv() * rot).magnitude() < TOL
        np.testing.assert_allclose(v_body, expected.inv().apply(w_world), rtol=0.0, atol=TOL)
        np.testing.assert_allclose(w_body, w0 * math.exp(-t / tau_w), rtol=0.0, atol=TOL)
        turned = theta
    assert turned > 1.5                   # it really turned (and the heading crossed pi)


@pytest.mark.parametrize('u0', [0.8, -0.6])
def test_profile_vehicle_surge_coast_follows_the_quadratic_damping_solution(context, executor,
                                                                            u0):
    """The profile's vehicle (CG moved to the CO, neutral), coasting in pure surge, ahead and
    astern, at heading -2.8 rad: m u_dot = -d u - q u |u| has
    |u(t)| = a |u0| e / (a + b |u0| (1 - e)), e = exp(-a t), a = d / m, b = q / m, and the
    distance travelled ln(1 + b |u0| (1 - e) / a) / b, along the heading in the world (ENU:
    yaw measured from east, counter-clockwise)."""
    m = MASS + 5.5                        # mass + added mass in surge (profile)
    a, b = 4.03 / m, 18.18 / m            # profile d_lin[0], d_quad[0]
    psi0, speed, sign = -2.8, abs(u0), math.copysign(1.0, u0)
    p0 = [3.0, 4.0, -2.0]
    run = Coast(context, executor, BALANCED, p0, [0.0, 0.0, psi0], [u0, 0, 0, 0, 0, 0])
    heading = np.array([math.cos(psi0), math.sin(psi0), 0.0])
    for t, p, rot, v_body, w_body in run.samples():
        e = math.exp(-a * t)
        u = sign * a * speed * e / (a + b * speed * (1.0 - e))
        s = sign * math.log(1.0 + b * speed * (1.0 - e) / a) / b
        np.testing.assert_allclose(v_body, [u, 0.0, 0.0], rtol=0.0, atol=TOL)
        np.testing.assert_allclose(w_body, 0.0, rtol=0.0, atol=TOL)
        np.testing.assert_allclose(p, np.array(p0) + s * heading, rtol=0.0, atol=TOL)
        assert rot.as_euler('ZYX')[0] == pytest.approx(psi0, abs=TOL)
    assert abs(u) < 0.6 * speed           # it really slowed down (2 s, quadratic drag)


# -- the free surface -------------------------------------------------------------------------
#
# Pinned to the sources, not read from the code: the BlueROV2 is 254 mm high (Blue Robotics'
# technical details), a T200's propeller 76 mm across (its data sheet), and the profile's
# thrusters give 51.5 N forward (5.25 kgf at 16 V, the profile's header).

HULL, PROPELLER, THRUST = 0.254, 0.076, 51.5
VERTICAL = ('vert_front_right', 'vert_front_left', 'vert_rear_right', 'vert_rear_left')


def surface_sim(context: Any, executor: Any, p0: list[float],
                rpy0: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> RovSimulatorNode:
    """The profile's ROV at ``p0`` with every vertical thruster at full upward thrust."""
    params = {**sim_parameters('simulator'), 'rate': RATE, 'initial.position': p0,
              'initial.rpy': list(rpy0)}
    assert params['vehicle.height'] == HULL
    sim = add(executor, RovSimulatorNode(node_name='simulator', context=context,
                                         parameter_overrides=overrides(params)))
    msg = JointState()
    msg.name = list(VERTICAL)
    msg.effort = [THRUST] * 4
    sim._on_thrust(msg)
    return sim


def test_thrusters_lose_their_thrust_in_the_last_propeller_diameter(context, executor):
    sim = surface_sim(context, executor, [0.0, 0.0, -1.0])
    for z, share in ((-1.0, 1.0), (-PROPELLER, 1.0), (-PROPELLER / 2, 0.5), (0.0, 0.0),
                     (0.05, 0.0)):
        sim.state = RigidBodyState.at_rest(p=(0.0, 0.0, z))
        assert sim.tau[2] == pytest.approx(4 * THRUST * share)
        assert sim.tau[3] == pytest.approx(0.0, abs=1e-9)  # level: no roll moment
    # Rolled 20 deg to port-side-down (about +x, FLU): the left thrusters (y = +0.218 m)
    # sit higher, 0.218 sin 20 deg = 7.5 cm above the CO.
    sim.state = RigidBodyState(np.array([0.0, 0.0, -0.05]), quat_from_euler(
        math.radians(20.0), 0.0, 0.0), np.zeros(6))
    rot = Rotation.from_euler('x', 20.0, degrees=True)
    for name, depth in zip(sim._index, sim.thruster_depths()):
        r = sim_parameters()[f'thrusters.{name}.position']
        assert depth == pytest.approx(0.05 - rot.apply(r)[2])
    # The right (lower) side keeps its thrust, the left (0.025 m above the surface) none:
    # a moment that rights the roll.
    assert sim.tau[3] < -1.0


def test_full_upward_thrust_holds_the_rov_at_the_surface(context, executor):
    """206 N up against the neutral hull: it climbs at 2.29 m/s (d_lin w + d_quad w|w| =
    206 N), breaches, falls back and settles where the thrust left and the buoyancy left
    balance the weight. Without the free surface it would be 45 m up after the 20 s."""
    sim = surface_sim(context, executor, [0.0, 0.0, -1.0])
    clock = SimClock(sim)
    heights = []
    for _ in range(round(20.0 * RATE)):
        clock.advance(1.0 / RATE)
        sim.step()
        heights.append(float(sim.state.p[2]))
    # Level, thrusters at the CO's height z: 4 T min(1, -z / d) + B (1/2 - z / h) = W, B = W.
    z_eq = -0.5 / (4 * THRUST / (MASS * G_SIM * PROPELLER) + 1.0 / HULL)   # -1.79 cm
    # A jump, not a flight: below the height its kinetic energy at 2.29 m/s would reach,
    # (m + Z_wdot) w^2 / (2 m g) = 0.61 m (0.31 m here: the model keeps the water's damping).
    assert HULL / 2 < max(heights) < 0.61
    last = heights[-round(2.0 * RATE):]
    assert max(last) < 0.0 and np.mean(last) == pytest.approx(z_eq, abs=0.005)


# -- thrust_timeout against the measured thrust period (valid but harmful) -------------------

def test_a_thrust_timeout_shorter_than_two_thrust_periods_is_refused_live(context, executor):
    """A thrust_timeout under the period of sim/thrust drops tau to zero between every two
    thrust messages (the simulated ESC stutters). Refused live with the measured period."""
    from sensor_msgs.msg import JointState
    sim = add(executor, RovSimulatorNode(
        node_name='simulator', context=context,
        parameter_overrides=overrides(sim_parameters('simulator'))))
    clock = SimClock(sim, t0_ns=1_000 * 1_000_000_000)
    pub = probe(context, executor, 'thrusters').create_topic_publisher(topics.SIM_THRUST)
    LinkBus.of(context).connect()
    names = [t.name for t in sim.thrusters]
    for _ in range(12):  # 20 Hz
        clock.advance(0.05)
        pub.publish(JointState(name=names, effort=[1.0] * len(names)))
    result = sim.set_parameters([Parameter('thrust_timeout', value=0.08)])[0]
    assert not result.successful
    assert 'thrust_timeout' in result.reason and 'period' in result.reason, result.reason
    assert sim.set_parameters([Parameter('thrust_timeout', value=0.1)])[0].successful


def test_the_status_line_gives_the_compass_heading(context, monkeypatch) -> None:
    """Yaw 30 deg counter-clockwise from east (ENU) is 060 on a compass; a person reads that."""
    sim = RovSimulatorNode(node_name='simulator', context=context,
                           parameter_overrides=overrides(sim_parameters('simulator')))
    try:
        q = Rotation.from_euler('z', 30.0, degrees=True).as_quat()
        sim.state = RigidBodyState(np.zeros(3), q, np.zeros(6))
        said: list[str] = []
        monkeypatch.setattr(sim.get_logger(), 'info', lambda m, **kw: said.append(m))
        sim._status()
        [line] = said
        assert 'heading 060 deg (compass)' in line
    finally:
        sim.destroy_node()
