"""``enbarr bench``: the IMU -> filter -> control -> allocation -> thruster chain, measured.

Runs the chain of a profile (default ``enbarr_sim``: simulator -> sim IMU -> attitude filter
-> velocity control -> thruster converter -> sim thrusters) in this process, composed exactly
as ``bringup`` composes it, at ``--rate`` for ``--seconds``, and prints one JSON line:

- ``rate_hz``: achieved chain rate (IMU samples through the chain per second);
- ``latency_ms_p50/p99/max``: IMU sample stamp -> thruster command applied;
- ``cpu_s_per_cycle`` and ``cpu_core_fraction``: process CPU time (all threads, including
  the executor and DDS) per cycle and per wall second;
- ``pure_s_per_cycle``: the same algorithms called in a plain loop without ROS, and
  ``ros_overhead_ratio`` = cpu_s_per_cycle / pure_s_per_cycle.

Figures depend on the machine and its load: run it alone. ``docs/benchmarks.md`` has ours.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import os
import platform
import time
from typing import Any

import numpy as np

CHAIN = ('simulator', 'imu', 'filtering', 'control_loop', 'thruster_converter',
         'thruster_control')


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--rate', type=float, default=400.0, help='chain rate in Hz (default 400)')
    p.add_argument('--seconds', type=float, default=10.0,
                   help='measured duration after a 1 s warm-up (default 10)')
    p.add_argument('--profile', default='enbarr_sim',
                   help='profile whose chain nodes to run (default enbarr_sim)')


def main(args: argparse.Namespace) -> int:
    from .errors import EnbarrError
    if not (args.rate > 0 and args.seconds > 0):
        raise EnbarrError('--rate and --seconds must be positive')
    result = {'rate_hz_requested': args.rate, **run_ros(args), **run_pure(args)}
    result['ros_overhead_ratio'] = round(result['cpu_s_per_cycle'] /
                                         result['pure_s_per_cycle'], 2)
    result['machine'] = f'{platform.machine()} {os.cpu_count()} cpu, Python ' \
                        f'{platform.python_version()}'
    print(json.dumps(result))
    return 0


def _chain_profile(args: argparse.Namespace) -> Any:
    from .profile import load_profile
    prof = load_profile(args.profile, [f'simulator.rate={args.rate}'])
    nodes = tuple(n for n in prof.nodes if n.name in CHAIN)
    return replace(prof, nodes=nodes, record=None)


def run_ros(args: argparse.Namespace) -> dict[str, Any]:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from enbarr_interfaces.links import LinkBus

    from .bringup import build_nodes, configure_process, shutdown_nodes
    from .profile import apply_environment

    prof = _chain_profile(args)
    apply_environment(prof)
    configure_process()
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    try:
        nodes = build_nodes(prof, context)
        by_name = {n.get_name(): n for n in nodes}
        for n in nodes:
            executor.add_node(n)
        LinkBus.of(context).connect()
        for n in nodes:
            n.start()
        sim, thr = by_name['simulator'], by_name['thruster_control']

        def spin_for(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)

        spin_for(1.0)
        steps0, lat0 = sim.samples, thr.latency_count
        cpu0, wall0 = time.process_time(), time.monotonic()
        spin_for(args.seconds)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        steps, lat_n = sim.samples - steps0, thr.latency_count - lat0
        ring = thr.latency_ns
        n = min(lat_n, len(ring))
        idx = (np.arange(thr.latency_count - n, thr.latency_count)) % len(ring)
        lat_ms = ring[idx] * 1e-6
        return {
            'rate_hz': round(steps / wall, 1),
            'cycles': steps,
            'commands': lat_n,
            'late_ticks': sim._loops[0].overruns,
            'time_skips': sim.time_skips,
            'latency_ms_p50': round(float(np.percentile(lat_ms, 50)), 3),
            'latency_ms_p99': round(float(np.percentile(lat_ms, 99)), 3),
            'latency_ms_max': round(float(lat_ms.max()), 3),
            'cpu_s_per_cycle': round(cpu / max(steps, 1), 6),
            'cpu_core_fraction': round(cpu / wall, 3),
        }
    finally:
        shutdown_nodes(nodes)
        executor.shutdown()
        rclpy.try_shutdown(context=context)


def run_pure(args: argparse.Namespace, cycles: int = 2000) -> dict[str, Any]:
    """The same computation per cycle as the ROS chain, as plain function calls."""
    from .algorithms.allocation import allocation_matrix, Thruster, ThrustAllocator
    from .algorithms.attitude_filter import AttitudeFilter
    from .algorithms.kinematics import quat_to_rotmat
    from .algorithms.rigid_body import RigidBodyModel, RigidBodyParams, RigidBodyState
    from .algorithms.velocity_control import VelocityController
    from .nodes.velocity_control import build_settings, SPECS

    prof = _chain_profile(args)
    common = dict(prof.parameters)
    sim = {**common, **prof.node('simulator').parameters}
    fields = ('mass', 'inertia', 'r_g', 'r_b', 'buoyancy', 'added_mass', 'd_lin', 'd_quad')
    model = RigidBodyModel(RigidBodyParams.from_mapping(
        {f: sim[f'vehicle.{f}'] for f in fields}))
    thrusters = [Thruster(n, tuple(common[f'thrusters.{n}.position']),
                          tuple(common[f'thrusters.{n}.direction']),
                          common[f'thrusters.{n}.max_forward'],
                          common[f'thrusters.{n}.max_reverse'])
                 for n in common['thruster_names']]
    B = allocation_matrix(thrusters)
    allocator = ThrustAllocator(thrusters)
    ctrl_values = {s.name: s.default for s in SPECS}
    ctrl_values.update({k: v for k, v in {**common, **prof.node('control_loop').parameters}
                        .items() if k in ctrl_values})
    controller = VelocityController(build_settings(ctrl_values)[0])
    filt = AttitudeFilter()
    rng = np.random.default_rng(1)
    dt = 1.0 / args.rate
    state = RigidBodyState.at_rest((0.0, 0.0, -0.5))
    thrust = np.zeros(len(thrusters))
    goal = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.2])
    m_world = np.array([0.0, 1.8e-5, -4.8e-5])
    nan3 = np.full(3, np.nan)
    t0 = time.process_time()
    for _ in range(cycles):
        tau = B @ thrust
        state = model.step(state, tau, dt)
        nu_dot = model.nu_dot(state.q, state.nu, tau)
        f = model.specific_force(state, nu_dot)
        gyro = state.nu[3:] + rng.normal(0.0, 0.002, 3)
        accel = f + rng.normal(0.0, 0.03, 3)
        mag = quat_to_rotmat(state.q).T @ m_world + rng.normal(0.0, 5e-7, 3)
        est = filt.step(gyro, accel, mag, dt)
        out = controller.step(goal, np.concatenate((nan3, est.omega)), dt)
        thrust = allocator.allocate(out.tau).thrust
    per = (time.process_time() - t0) / cycles
    return {'pure_s_per_cycle': round(per, 6)}
