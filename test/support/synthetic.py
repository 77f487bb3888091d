"""Synthetic runs for the metrics: small bags written with the project's own bag writer
(``enbarr_core.recording.bag.BagWriter``) from hand-made messages, serialized with
the rosbags Jazzy typestore (pure Python: no rclpy, so the metrics tests stay in the unit
tier).

A run is the truth ``sim/odometry`` (pose eta = [x, y, psi] at times t), the reference on
``guidance/reference`` at the first sample and whenever it changes (the metrics compare each
sample with the reference in force: a hold pose is one message), ``/mode`` messages (the
latched 'manual' at the first sample, as the recorder takes it, then the given ones) and,
optionally, what the controller asked (``force_command``) and what the allocation delivered.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from rosbags.typesys import get_typestore, Stores

from enbarr_core.bringup.profile import NodeSpec
from enbarr_core.recording.bag import BagWriter

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def _time(t_s: float) -> Any:
    ns = int(round(t_s * 1e9))
    return T['builtin_interfaces/msg/Time'](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _header(t_s: float, frame: str) -> Any:
    return T['std_msgs/msg/Header'](stamp=_time(t_s), frame_id=frame)


def _quat(psi: float) -> Any:
    return T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=math.sin(psi / 2),
                                             w=math.cos(psi / 2))


def _vec(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
    return T['geometry_msgs/msg/Vector3'](x=float(x), y=float(y), z=float(z))


def _twist(nu: Sequence[float] = (0.0, 0.0, 0.0)) -> Any:
    return T['geometry_msgs/msg/Twist'](linear=_vec(nu[0], nu[1]), angular=_vec(0.0, 0.0, nu[2]))


def odometry(t_s: float, eta: Sequence[float]) -> Any:
    x, y, psi = (float(v) for v in eta)
    pose = T['geometry_msgs/msg/Pose'](position=T['geometry_msgs/msg/Point'](x=x, y=y, z=0.0),
                                       orientation=_quat(psi))
    return T['nav_msgs/msg/Odometry'](
        header=_header(t_s, 'odom'), child_frame_id='base_link',
        pose=T['geometry_msgs/msg/PoseWithCovariance'](pose=pose, covariance=np.zeros(36)),
        twist=T['geometry_msgs/msg/TwistWithCovariance'](twist=_twist(),
                                                          covariance=np.zeros(36)))


def reference(t_s: float, eta_d: Sequence[float],
              nu_d: Sequence[float] = (0.0, 0.0, 0.0)) -> Any:
    x, y, psi = (float(v) for v in eta_d)
    point = T['trajectory_msgs/msg/MultiDOFJointTrajectoryPoint'](
        transforms=[T['geometry_msgs/msg/Transform'](translation=_vec(x, y), rotation=_quat(psi))],
        velocities=[_twist(nu_d)], accelerations=[_twist()],
        time_from_start=T['builtin_interfaces/msg/Duration'](sec=0, nanosec=0))
    return T['trajectory_msgs/msg/MultiDOFJointTrajectory'](
        header=_header(t_s, 'odom'), joint_names=['base_link'], points=[point])


def wrench(t_s: float, xyn: Sequence[float]) -> Any:
    x, y, n = (float(v) for v in xyn)
    return T['geometry_msgs/msg/WrenchStamped'](
        header=_header(t_s, 'base_link'),
        wrench=T['geometry_msgs/msg/Wrench'](force=_vec(x, y), torque=_vec(0.0, 0.0, n)))


def joint_state(t_s: float, names: Sequence[str], thrust: Sequence[float],
                angle: Sequence[float]) -> Any:
    return T['sensor_msgs/msg/JointState'](
        header=_header(t_s, 'base_link'), name=list(names),
        position=np.asarray(angle, dtype=float), velocity=np.zeros(0),
        effort=np.asarray(thrust, dtype=float))


def write_run(bag: Path, t: np.ndarray, eta: np.ndarray, eta_d: Sequence[float] | np.ndarray,
              modes: Sequence[tuple[float, str]] = (), asked: np.ndarray | None = None,
              delivered: np.ndarray | None = None, nu_d: Sequence[float] = (0.0, 0.0, 0.0),
              bias: np.ndarray | None = None,
              azimuths: tuple[Sequence[str], np.ndarray, np.ndarray] | None = None) -> Path:
    """Write a synthetic run into ``bag`` (a new directory) and return it.

    ``t`` (n,) [s], ``eta`` (n, 3) truth poses; ``eta_d`` one hold pose (3,) or one per sample
    (n, 3), written when it changes, with the reference velocity ``nu_d`` (3,) (body);
    ``modes`` (time [s], mode); ``asked`` / ``delivered`` (n, 3) forces [X, Y, N] at the
    sample times; ``bias`` (n, 3) the observer's ``observer/bias``; ``azimuths`` (names,
    thrust (n, k) [N], angle (n, k) [rad]) on ``azimuth_commands``. Every message is
    recorded at its own stamp.
    """
    eta_d = np.broadcast_to(np.asarray(eta_d, dtype=float), (len(t), 3))
    out: list[tuple[int, str, str, Any]] = []
    for i, ti in enumerate(t):
        ns = int(round(ti * 1e9))
        out.append((ns, '/sim/odometry', 'nav_msgs/msg/Odometry', odometry(ti, eta[i])))
        if i == 0 or not np.array_equal(eta_d[i], eta_d[i - 1], equal_nan=True):
            out.append((ns, '/guidance/reference',
                        'trajectory_msgs/msg/MultiDOFJointTrajectory',
                        reference(ti, eta_d[i], nu_d)))
        if bias is not None:
            out.append((ns, '/observer/bias', 'geometry_msgs/msg/WrenchStamped',
                        wrench(ti, bias[i])))
        if azimuths is not None:
            names, thrust, angle = azimuths
            out.append((ns, '/azimuth_commands', 'sensor_msgs/msg/JointState',
                        joint_state(ti, names, thrust[i], angle[i])))
        for topic, forces in (('/force_command', asked), ('/allocation/delivered', delivered)):
            if forces is not None:
                out.append((ns, topic, 'geometry_msgs/msg/WrenchStamped', wrench(ti, forces[i])))
    # The recorder takes the latched mode first, as the run starts: manual.
    for tm, mode in ((t[0], 'manual'), *modes):
        out.append((int(round(tm * 1e9)), '/mode', 'std_msgs/msg/String',
                    T['std_msgs/msg/String'](data=mode)))
    writer = BagWriter(bag, flush_seconds=3600.0)
    for ns, topic, msgtype, msg in sorted(out, key=lambda m: m[0]):
        # exact: rosbags' CDR ends where the message does (no cut to find by decoding it)
        assert writer.write(topic, msgtype, ns, bytes(TS.serialize_cdr(msg, msgtype)),
                            exact=True)
    writer.close()
    return bag


def profile(waypoints: Sequence[float] = (), dropout_windows: Sequence[float] = (),
            simulator: dict[str, Any] | None = None, parameters: dict[str, Any] | None = None,
            speed: float = 0.2) -> Any:
    """The parts of a profile the metrics and the plot read: the guidance path and speed,
    the mocap dropouts, the simulator's parameters (a ``vessel3dof_simulator`` node when
    given) and the common ``parameters``."""
    nodes = [NodeSpec('guidance', 'guidance',
                      parameters={'path.waypoints': list(waypoints) or [0.0],
                                  'path.speed': speed}),
             NodeSpec('mocap', 'sim_mocap',
                      parameters={'dropout_windows': list(dropout_windows) or [0.0]})]
    if simulator is not None:
        nodes.append(NodeSpec('simulator', 'vessel3dof_simulator', parameters=simulator))
    return SimpleNamespace(name='synthetic', nodes=tuple(nodes), parameters=parameters or {})
