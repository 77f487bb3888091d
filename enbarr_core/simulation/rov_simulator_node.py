"""Simulated 6-DOF ROV: the vehicle the simulated IMU measures and the thrusters push.

Integrates ``RigidBodyModel`` (Fossen 2021) at ``rate`` on its own loop thread. Each step:
tau = B f from the latest ``sim/thrust`` (zero when it is older than ``thrust_timeout`` on the
node's clock, as an ESC whose signal stops), one model step in the water ``current`` (a
constant velocity in the world frame; the damping and added mass act on the velocity relative
to it), then the truth at the IMU on ``sim/imu`` (which drives the whole IMU -> thruster
chain synchronously through the link bus) and, decimated, ``sim/odometry`` (velocity over
ground, as a DVL locked on the bottom measures it).

The free surface (``vehicle.height`` > 0, ``models.rigid_body``): the water ends at z = 0 of
odom. The buoyancy falls as the hull emerges, and a thruster gives thrust only in the water:
its thrust scales from full at one propeller diameter (``PROPELLER_DIAMETER``) below the
surface to none at the surface and above, so that a vehicle at full upward thrust porpoises at
the surface instead of flying out of it. ``vehicle.height`` 0 is deep water, as before.

The thrust's age is measured on the node's ROS clock, the clock the simulated time of
``enbarr scenario`` overrides, so a scenario run does not depend on the machine's speed.
``sim/thrust`` carries no stamp the simulator uses (its arrival on that clock is what counts),
so the time policy has nothing to gate here; but ``thrust_timeout`` must cover two measured
periods of ``sim/thrust`` (else tau drops to zero between messages): a live change below that
is refused with the measured period.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import threading
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Imu, JointState

from enbarr_interfaces.fastmsg import new
from enbarr_interfaces import convert, topics

from enbarr_core.allocation.fixed import allocation_matrix
from enbarr_core.framework.frames import format_heading
from enbarr_core.framework.kinematics import quat_from_euler, quat_to_euler, quat_to_rotmat
from enbarr_core.models.rigid_body import RigidBodyModel, RigidBodyParams, RigidBodyState
from enbarr_core.models.rigid_body_params import RESTORING_SPECS, VEHICLE_SPECS
from enbarr_core.framework.checks import floats
from enbarr_core.framework.health import IntervalMeter, too_short_for_rate
from enbarr_core.framework.node import EnbarrNode, sim_steps
from enbarr_core.framework.params import ParamSpec
from enbarr_core.allocation.layout_params import declare_thrusters

# Model steps integrated in one late tick before time is skipped. A step costs far less than
# the tick's own ROS work, so a loaded machine is better served by integrating the whole span
# (the vehicle then lives the time the controller and the thrusters lived) than by skipping
# it: with 10 (25 ms) a run beside two CPU hogs lost seconds of simulated time and the
# vehicle fell behind its feed-forward (docs/benchmarks.md). 100 steps (0.25 s) skip only
# real stalls.
MAX_CATCH_UP = 100
#: A thruster loses its thrust over this depth below the free surface [m]: the propeller
#: diameter of a Blue Robotics T200 (76 mm), the thruster of the BlueROV2 class.
PROPELLER_DIAMETER = 0.076

SPECS = [
    ParamSpec('rate', 400.0, 'Integration and IMU truth rate', 'Hz', 1.0, 2000.0,
              read_only=True),
    ParamSpec('odometry_rate', 50.0, 'Rate of sim/odometry (decimated from rate)', 'Hz', 0.1,
              2000.0, read_only=True),
    ParamSpec('thrust_timeout', 0.25, 'Thrust older than this is dropped to zero (ESC '
              'watchdog)', 's', 0.001, 10.0),
    *VEHICLE_SPECS, *RESTORING_SPECS,  # vessel data from the profile, required
    ParamSpec('status_period', 2.0, 'Period of the status line in the log (0: none)', 's',
              0.0, 3600.0, read_only=True),
    ParamSpec('current', [0.0, 0.0, 0.0], 'Water current in odom (east, north, up): constant, '
              'damping and added mass act on the velocity relative to it', 'm/s', -5.0, 5.0),
    ParamSpec('initial.position', [0.0, 0.0, -1.0], 'Start position in odom (ENU)', 'm', -1e6,
              1e6),
    ParamSpec('initial.rpy', [0.0, 0.0, 0.0], 'Start roll, pitch, yaw', 'rad', -math.pi,
              math.pi),
]

VEHICLE_FIELDS = ('mass', 'inertia', 'r_g', 'r_b', 'buoyancy', 'added_mass', 'd_lin', 'd_quad',
                  'height')


def in_water(depths: np.ndarray, band: float = PROPELLER_DIAMETER) -> np.ndarray:
    """Share of each thruster's thrust [0..1] at ``depths`` [m] below the surface (< 0: above).

    Full from ``band`` below the surface down, none at the surface and above, linear between.
    """
    return np.clip(depths / band, 0.0, 1.0)


@dataclass(frozen=True)
class RovSimulatorSettings:
    """Settings of ``RovSimulatorNode`` (see ``SPECS``)."""

    rate: float                  # integration and IMU truth rate [Hz]
    odometry_rate: float         # rate of sim/odometry [Hz]
    thrust_timeout: float        # thrust older than this counts as zero [s]
    vehicle: RigidBodyParams     # the simulated vehicle (Fossen 2021)
    status_period: float         # period of the log status line, 0: none [s]
    current: tuple[float, ...]   # water velocity in odom (ENU) [m/s]
    initial_position: tuple[float, ...]  # start position in odom (ENU) [m]
    initial_rpy: tuple[float, ...]       # start roll, pitch, yaw [rad]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> RovSimulatorSettings:
        """Build from the declared parameters' values; ``ValueError`` names the field."""
        try:
            vehicle = RigidBodyParams.from_mapping({f: v[f'vehicle.{f}'] for f in VEHICLE_FIELDS})
        except ValueError as err:  # the message starts with the field: name the parameter
            raise ValueError(f'vehicle.{err}') from err
        return cls(
            rate=v['rate'], odometry_rate=v['odometry_rate'],
            thrust_timeout=v['thrust_timeout'], vehicle=vehicle,
            status_period=v['status_period'],
            current=floats('current', v['current'], 3),
            initial_position=floats('initial.position', v['initial.position'], 3),
            initial_rpy=floats('initial.rpy', v['initial.rpy'], 3))


class RovSimulatorNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'simulator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._lock = threading.Lock()
        self.thrusters = declare_thrusters(self)
        self._B = allocation_matrix(self.thrusters)
        self._thruster_r = np.array([t.position for t in self.thrusters])  # (n, 3) body [m]
        self._index = {t.name: i for i, t in enumerate(self.thrusters)}
        self._model: RigidBodyModel | None = None
        self.thrust_period = IntervalMeter()  # arrivals of sim/thrust on the node's clock
        self.settings: RovSimulatorSettings
        self.bind_settings(SPECS, self._build, self._apply)
        v = self.settings
        self.state = RigidBodyState(np.array(v.initial_position),
                                    quat_from_euler(*v.initial_rpy), np.zeros(6))
        self.time_ns = 0
        self._thrust = np.zeros(len(self.thrusters))
        self._thrust_ns: int | None = None  # clock time of the last sim/thrust [ns]
        self.steps = 0        # model steps
        self.samples = 0      # truth samples published (fewer than steps when late)
        self.time_skips = 0
        self._imu_pub = self.create_topic_publisher(topics.SIM_IMU)
        self._odom_pub = self.create_topic_publisher(topics.SIM_ODOMETRY)
        self.create_topic_subscription(topics.SIM_THRUST, self._on_thrust)
        self._dt_ns = round(1e9 / v.rate)
        self.period_ns = self._dt_ns  # one model step [ns] (what enbarr scenario steps by)
        self._odom_every = max(1, round(v.rate / v.odometry_rate))
        self.create_rate_loop(v.rate, self.step)
        if v.status_period > 0.0:
            self.create_timer(v.status_period, self._status)

    def _build(self, v: Mapping[str, Any]) -> RovSimulatorSettings:
        settings = RovSimulatorSettings.from_params(v)
        problem = too_short_for_rate('thrust_timeout', settings.thrust_timeout,
                                     topics.SIM_THRUST.name, self.thrust_period.period,
                                     'the thrust would drop to zero between messages')
        if problem:
            raise ValueError(problem)
        return settings

    def _apply(self, settings: RovSimulatorSettings) -> None:
        with self._lock:
            self.settings = settings
            self._model = RigidBodyModel(settings.vehicle)
            self._current = settings.current if any(settings.current) else None
            self._thrust_timeout_ns = int(settings.thrust_timeout * 1e9)

    def _on_thrust(self, msg: JointState) -> None:
        thrust = np.zeros(len(self.thrusters))
        for name, f in zip(msg.name, msg.effort):
            i = self._index.get(name)
            if i is not None and math.isfinite(f):  # a float: math's test (numpy's costs more)
                thrust[i] = f
        self._thrust = thrust
        self._thrust_ns = self.now_ns()
        self.thrust_period.add(self._thrust_ns)

    @property
    def tau(self) -> np.ndarray:
        """Generalized force of the thrusters now [N, N m] (zero when their signal is stale).

        With the free surface, each thruster's thrust times its share in the water
        (``in_water``) at the present state.
        """
        last = self._thrust_ns
        if last is None or self.now_ns() - last > self._thrust_timeout_ns:
            return np.zeros(6)
        if self.settings.vehicle.height <= 0.0:
            return self._B @ self._thrust
        return self._B @ (self._thrust * in_water(self.thruster_depths()))

    def thruster_depths(self) -> np.ndarray:
        """Depth of each thruster below the free surface [m] (negative: above it)."""
        s = self.state
        k_world_z = quat_to_rotmat(s.q)[2]  # the world z row of R: z of R r for each r
        return -(s.p[2] + self._thruster_r @ k_world_z)

    def step(self) -> None:
        """Advance the vehicle to the clock's present and publish the truth at the IMU.

        Normally one step of about 1/rate; a late tick integrates the whole span in steps of
        about 1/rate (up to ``MAX_CATCH_UP``, beyond that time is skipped and counted in
        ``time_skips``). The truth is stamped with the time it is true at.
        """
        now = self.now_ns()
        if self.time_ns == 0:
            self.time_ns = now - self._dt_ns
        n, dt, skipped = sim_steps(self.time_ns, now, self._dt_ns, MAX_CATCH_UP)
        if n == 0:
            return
        self.time_skips += skipped
        tau = self.tau
        with self._lock:
            model, current = self._model, self._current
            state = self.state
            for _ in range(n):
                state = model.step(state, tau, dt, current=current)
            nu_dot = model.nu_dot(state.q, state.nu, tau, current=current, p=state.p)
            self.state = state
        self.time_ns = now
        self.steps += n
        imu = new(Imu)
        imu.header.frame_id = topics.IMU_FRAME
        convert.ns_to_stamp(self.time_ns, imu.header.stamp)
        convert.set_quaternion(imu.orientation, state.q)
        convert.set_vector3(imu.angular_velocity, state.nu[3:])
        convert.set_vector3(imu.linear_acceleration, model.specific_force(state, nu_dot))
        self.samples += 1
        self._imu_pub.publish(imu)
        if self.samples % self._odom_every == 0:
            self._odom_pub.publish(self.odometry(self.time_ns))

    def _status(self) -> None:
        s = self.state
        roll, pitch, yaw = quat_to_euler(s.q)
        u, v, w, _, _, r = s.nu
        # A person reads a compass heading (0 = north, clockwise); r stays the body's (FLU).
        self.get_logger().info(
            f'depth {-s.p[2]:5.2f} m  u {u:+.2f} v {v:+.2f} w {w:+.2f} m/s  '
            f'r {math.degrees(r):+5.1f} deg/s (+ port)  {format_heading(yaw)}  '
            f'roll {math.degrees(roll):+4.1f} pitch {math.degrees(pitch):+4.1f} deg  '
            f'thrust {np.abs(self._thrust).sum():5.1f} N')

    def odometry(self, now_ns: int) -> Odometry:
        """Return the true state as ``nav_msgs/Odometry`` stamped ``now_ns``."""
        s = self.state
        msg = new(Odometry)
        convert.ns_to_stamp(now_ns, msg.header.stamp)
        msg.header.frame_id = topics.WORLD_FRAME
        msg.child_frame_id = topics.BODY_FRAME
        p = msg.pose.pose.position
        p.x, p.y, p.z = (float(x) for x in s.p)
        convert.set_quaternion(msg.pose.pose.orientation, s.q)
        convert.set_twist(msg.twist.twist, s.nu)
        return msg
