"""``enbarr bench --recording``: what recording costs per message.

Composes a source node and a ``RecorderNode`` in one process as bringup does, publishes
``--messages`` realistic messages of each hot fast-topic type on the link bus, lets the
recorder write them all and close its bag, and takes the process CPU time (every thread:
the tap on the publishing thread, the queue, serializing and writing on the writer thread)
minus the same publishing without a recorder, per message from the difference between a
run and one four times as long (what a run costs once is left out). Prints one JSON line: CPU
per recorded message by type and for the mix of both chains (``us_per_message``), the part of
it on the publishing thread (``tap_us_per_message``), the recorder's
throughput when the publisher does not wait (``messages_per_second``), the cost of the
pieces measured alone (``pieces_us``) and the Pi 4 estimate (x6).
"""

from __future__ import annotations

import os
from pathlib import Path
import statistics
import tempfile
import time
import timeit
from typing import Any

#: A Raspberry Pi 4 core runs CPython about this much slower (docs/benchmarks.md).
PI4_FACTOR = 6
DEFAULT_MESSAGES = 8000     # per type in the long run
DEFAULT_REPEAT = 3          # runs per case; the median is kept
MIN_MESSAGES = 100


def _messages() -> dict[str, tuple[Any, Any]]:
    """Topic spec -> a realistic message, for the fast topics of both chains."""
    from geometry_msgs.msg import Transform, Twist
    import numpy as np
    from trajectory_msgs.msg import MultiDOFJointTrajectoryPoint

    from enbarr_interfaces import topics as t

    def fill(msg: Any, frame: str = t.BODY_FRAME) -> Any:
        if hasattr(msg, 'header'):
            msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 123_456_789
            msg.header.frame_id = frame
        return msg

    rng = np.random.default_rng(1)
    imu = fill(t.IMU.msg_type(), t.IMU_FRAME)
    imu.orientation.w = 1.0
    imu.angular_velocity.z = 0.01
    imu.linear_acceleration.z = 9.81
    imu.orientation_covariance = rng.random(9)
    imu.angular_velocity_covariance = rng.random(9)
    imu.linear_acceleration_covariance = rng.random(9)
    odom = fill(t.SIM_ODOMETRY.msg_type(), t.WORLD_FRAME)
    odom.child_frame_id = t.BODY_FRAME
    odom.pose.pose.position.x = 1.5
    odom.pose.covariance = rng.random(36)
    odom.twist.covariance = rng.random(36)
    wrench = fill(t.FORCE_COMMAND.msg_type())
    wrench.wrench.force.x, wrench.wrench.torque.z = 12.0, -0.5
    thrusters = fill(t.THRUSTER_COMMANDS.msg_type())
    thrusters.name = [f'thruster_{k}' for k in range(8)]
    thrusters.effort = list(rng.uniform(-1, 1, 8))
    mag = fill(t.IMU_MAG.msg_type(), t.IMU_FRAME)
    mag.magnetic_field.x = 2e-5
    pose = fill(t.MOCAP_POSE.msg_type(), t.WORLD_FRAME)
    pose.pose.orientation.w = 1.0
    ref = fill(t.GUIDANCE_REFERENCE.msg_type(), t.WORLD_FRAME)
    ref.joint_names = [t.BODY_FRAME]
    ref.points = [MultiDOFJointTrajectoryPoint(transforms=[Transform()], velocities=[Twist()],
                                               accelerations=[Twist()])]
    azimuths = fill(t.AZIMUTH_COMMANDS.msg_type())
    azimuths.name = ['port', 'starboard', 'bow']
    azimuths.effort = [1.0, 2.0, 3.0]
    azimuths.position = [0.1, 0.2, 0.3]
    duty = t.PWM_DUTY.msg_type()
    duty.data = [7.5] * 6
    return {
        'sensor_msgs/Imu': (t.IMU, imu),
        'nav_msgs/Odometry': (t.SIM_ODOMETRY, odom),
        'geometry_msgs/WrenchStamped': (t.FORCE_COMMAND, wrench),
        'sensor_msgs/JointState': (t.THRUSTER_COMMANDS, thrusters),
        'sensor_msgs/MagneticField': (t.IMU_MAG, mag),
        'geometry_msgs/PoseStamped': (t.MOCAP_POSE, pose),
        'trajectory_msgs/MultiDOFJointTrajectory': (t.GUIDANCE_REFERENCE, ref),
        'sensor_msgs/JointState (azimuths)': (t.AZIMUTH_COMMANDS, azimuths),
        'std_msgs/Float64MultiArray': (t.PWM_DUTY, duty),
    }


#: Messages per sample of the two chains (bringup enbarr_sim / saucer_sim, everything on).
ROV_MIX = ['sensor_msgs/Imu'] * 3 + ['sensor_msgs/MagneticField', 'nav_msgs/Odometry',
                                     'geometry_msgs/WrenchStamped'] + [
    'sensor_msgs/JointState'] * 3
SAUCER_MIX = ['geometry_msgs/PoseStamped', 'nav_msgs/Odometry', 'geometry_msgs/WrenchStamped',
              'trajectory_msgs/MultiDOFJointTrajectory', 'sensor_msgs/JointState (azimuths)',
              'geometry_msgs/WrenchStamped', 'std_msgs/Float64MultiArray']


def _run(context: Any, specs_msgs: list[tuple[Any, Any]], n: int, record: bool,
         where: Path) -> tuple[float, float, float, int]:
    """Publish ``n`` rounds of ``specs_msgs``.

    Returns (process CPU s, publishing thread CPU s, wall s, messages written).
    """
    from rclpy.parameter import Parameter

    from enbarr_core.framework.node import EnbarrNode
    from enbarr_core.recording.recorder_node import RecorderNode
    from enbarr_interfaces.links import LinkBus

    source = EnbarrNode(f'bench_source_{time.monotonic_ns()}', context=context)
    pubs = []
    seen = set()
    for spec, msg in specs_msgs:
        if spec.name not in seen:
            seen.add(spec.name)
            pubs.append(source.create_topic_publisher(spec))
    by_name = {p.spec.name: p for p in pubs}
    plan = [(by_name[spec.name], msg) for spec, msg in specs_msgs]
    rec = None
    if record:
        rec = RecorderNode(context=context, parameter_overrides=[
            Parameter('path', value=str(where)),
            Parameter('max_queued', value=10_000_000)])
    LinkBus.of(context).connect()
    if rec is not None:
        rec.start()
    cpu0, wall0, th0 = time.process_time(), time.perf_counter(), time.thread_time()
    for _ in range(n):
        for pub, msg in plan:
            pub.publish(msg)
    thread = time.thread_time() - th0
    written = 0
    if rec is not None:
        rec.close()
        written = rec.written
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    if rec is not None:
        rec.destroy_node()
    source.destroy_node()
    return cpu, thread, wall, written


def _pieces(cases: dict[str, tuple[Any, Any]]) -> dict[str, Any]:
    """Time the remaining per-message pieces, each alone [us]."""
    from rclpy.serialization import serialize_message

    from enbarr_core.recording import bag as bag_mod
    out: dict[str, Any] = {}
    try:
        from enbarr_core.recording import cdr
    except ImportError:
        cdr = None
    enc: dict[str, float] = {}
    ser: dict[str, float] = {}
    for name, (_, msg) in cases.items():
        ser[name] = min(timeit.repeat(lambda m=msg: serialize_message(m), number=2000,
                                      repeat=3)) / 2000 * 1e6
        if cdr is not None and (e := cdr.encoder(type(msg))) is not None:
            enc[name] = min(timeit.repeat(lambda m=msg, e=e: e(m), number=2000,
                                          repeat=3)) / 2000 * 1e6
    out['serialize_message'] = {k: round(v, 2) for k, v in ser.items()}
    if enc:
        out['cdr_encoder'] = {k: round(v, 2) for k, v in enc.items()}
    # Writing one Imu into the bag (in memory; flushes amortized).
    _, imu = cases['sensor_msgs/Imu']
    data = serialize_message(imu)
    with tempfile.TemporaryDirectory() as tmp:
        writer_cls = getattr(bag_mod, 'BagWriter', None) or bag_mod.SegmentedBagWriter
        writer = writer_cls(Path(tmp) / 'w')
        k = [0]

        def one() -> None:
            k[0] += 1
            writer.write('/imu/data', 'sensor_msgs/msg/Imu', k[0], data)
        writer.write('/imu/data', 'sensor_msgs/msg/Imu', 0, data)
        out['bag_write_imu'] = round(min(timeit.repeat(one, number=5000, repeat=3))
                                     / 5000 * 1e6, 2)
        writer.close()
    import queue
    q: Any = queue.SimpleQueue()
    item = (('x', 'y', None), 1, imu)
    out['queue_put_get'] = round(min(timeit.repeat(lambda: (q.put(item), q.get()),
                                                   number=20000, repeat=3)) / 20000 * 1e6, 2)
    return out


def measure(messages: int = DEFAULT_MESSAGES, repeat: int = DEFAULT_REPEAT) -> dict[str, Any]:
    """Run the benchmark: ``messages`` per type in the long run, ``repeat`` runs per case."""
    from enbarr_core.framework.errors import EnbarrError
    if messages < MIN_MESSAGES or repeat < 1:
        raise EnbarrError(f'--messages must be >= {MIN_MESSAGES} and --repeat >= 1, got '
                          f'{messages} and {repeat}')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.context import Context

    cases = _messages()
    context = Context()
    rclpy.init(context=context)
    result: dict[str, Any] = {'messages': messages, 'repeat': repeat,
                              'us_per_message': {}, 'tap_us_per_message': {},
                              'messages_per_second': {}}
    try:
        groups = {name: [case] for name, case in cases.items()}
        groups['mix: ROV chain sample'] = [cases[k] for k in ROV_MIX]
        groups['mix: Saucer chain sample'] = [cases[k] for k in SAUCER_MIX]
        with tempfile.TemporaryDirectory() as tmp:
            for gi, (name, group) in enumerate(groups.items()):
                # Two lengths: the difference is the cost per message, without what a run
                # costs once (first message of a topic, final flush, thread start and stop).
                short = max(1, messages // (4 * len(group)))
                long = 4 * short
                extra = (long - short) * len(group)
                per, tap, rates = [], [], []
                for r in range(repeat):
                    got = {}
                    for rounds in (short, long):
                        base, base_th, _, _ = _run(context, group, rounds, False,
                                                   Path(tmp) / 'none')
                        cpu, th, wall, written = _run(context, group, rounds, True,
                                                      Path(tmp) / f'bag{gi}_{r}_{rounds}')
                        if written != rounds * len(group):
                            raise EnbarrError(f'{name}: {written} of {rounds * len(group)} '
                                              'messages recorded')
                        got[rounds] = (cpu - base, th - base_th, wall)
                    per.append((got[long][0] - got[short][0]) / extra * 1e6)
                    tap.append((got[long][1] - got[short][1]) / extra * 1e6)
                    rates.append(long * len(group) / got[long][2])
                result['us_per_message'][name] = round(statistics.median(per), 1)
                result['tap_us_per_message'][name] = round(statistics.median(tap), 1)
                result['messages_per_second'][name] = round(statistics.median(rates))
        result['pieces_us'] = _pieces(cases)
    finally:
        rclpy.try_shutdown(context=context)
    mixes = [v for k, v in result['us_per_message'].items() if k.startswith('mix')]
    result['pi4_estimate_us_per_message'] = round(max(mixes) * PI4_FACTOR, 1)
    return result
