"""``enbarr bench --chain``: the sensor -> actuator chain of a vessel, measured.

``--chain rov`` (default): simulator -> sim IMU -> attitude filter -> velocity control ->
thruster converter -> sim thrusters (profile ``enbarr_sim``). ``--chain saucer``: simulator
-> sim motion capture -> DP observer -> guidance -> DP control (automatic mode) -> azimuth
allocation -> PWM mapping -> sim Arduino (profile ``saucer_sim``). The nodes are composed as
``bringup`` composes them, in this process, at ``--rate`` for ``--seconds``; one JSON line:

- ``rate_hz``: achieved chain rate (sensor samples whose command reached the actuator, /s);
- ``latency_ms_p50/p99/max``: sensor sample stamp -> actuator command applied;
- ``cpu_s_per_cycle`` and ``cpu_core_fraction``: process CPU time (all threads, including
  the executor and DDS) per cycle and per wall second;
- ``pure_s_per_cycle``: the same algorithms called in a plain loop without ROS, and
  ``ros_overhead_ratio`` = cpu_s_per_cycle / pure_s_per_cycle;
- ``pure_paced_s_per_cycle`` and ``ros_overhead_ratio_paced``: the same loop run one cycle per
  period at ``--rate`` (for 3 s) instead of back to back. At 50 Hz the chain runs on cold
  caches and the same code costs about twice as much per cycle as in a hot loop; this ratio
  compares the chain with its algorithms under the same pacing (the plain ratio stays the
  one the targets in ``docs/benchmarks.md`` are stated in);
- saucer only, ``scenario_real_time_factor``: simulated seconds per wall second of the
  headless station-keeping scenario (recording included).

``--profile NAME`` measures a whole profile under ``bringup`` instead (``profile_run``);
``--profile NAME --idle`` its fixed cost (``run_idle``, here): the nodes composed in this
process and spun, no source started (what runs: the supervision tick with its watchdogs and
reports, the timers of core nodes, parameter services; a source's timer does not), as
``cpu_core_fraction``.

Figures depend on the machine and its load: run it alone. ``docs/benchmarks.md`` has ours.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import os
import platform
import tempfile
import time
from typing import Any, Iterator

import numpy as np


@dataclass(frozen=True)
class Chain:
    """A control chain to measure: its profile, the nodes it needs, and its actuator."""

    profile: str
    nodes: tuple[str, ...]
    sink: str  # the node holding the LatencyLog (last one that has the sensor stamp)


CHAINS = {
    'rov': Chain('enbarr_sim', ('simulator', 'imu', 'filtering', 'control_loop',
                                'thruster_converter', 'thruster_control'), 'thruster_control'),
    'saucer': Chain('saucer_sim', ('simulator', 'mocap', 'observer', 'guidance', 'dp_control',
                                   'allocation', 'pwm', 'arduino', 'joystick'), 'pwm'),
}


def measure(chain_name: str, rate: float, seconds: float) -> dict[str, Any]:
    """Measure ``CHAINS[chain_name]`` at ``rate`` [Hz] for ``seconds``; the JSON line's dict."""
    from enbarr_core.framework.errors import EnbarrError, ProfileError
    chain = CHAINS[chain_name]
    result: dict[str, Any] = {'chain': chain_name, 'rate_hz_requested': rate}
    try:
        result.update(run_ros(chain, rate, seconds))
    except ProfileError as err:
        if not (err.key or '').endswith('.rate'):
            raise
        raise EnbarrError(f'--rate {rate:g}: not a rate the {chain_name} chain runs at: '
                          f'{err.__cause__ or err}') from err
    pure_loop = pure_rov if chain_name == 'rov' else pure_saucer
    pure = hot(pure_loop(rate))
    paced = paced_cycles(pure_loop(rate), rate)
    result['pure_s_per_cycle'] = round(pure, 6)
    result['ros_overhead_ratio'] = round(result['cpu_s_per_cycle'] / pure, 2)
    result['pure_paced_s_per_cycle'] = round(paced, 6)
    result['ros_overhead_ratio_paced'] = round(result['cpu_s_per_cycle'] / paced, 2)
    if chain_name == 'saucer':
        from enbarr_core.tools.scenario import run as run_scenario
        with tempfile.TemporaryDirectory() as tmp:
            r = run_scenario('station_keeping', os.path.join(tmp, 'out'), plot=False,
                             duration=30.0)
        result['scenario_real_time_factor'] = r['real_time_factor']
    result['machine'] = machine()
    return result


def machine() -> str:
    """Describe this machine for a benchmark's JSON line."""
    return f'{platform.machine()} {os.cpu_count()} cpu, Python {platform.python_version()}'


#: Spin before the idle window [s]: discovery's first exchanges, the first reports.
IDLE_WARMUP = 3.0


def run_idle(profile: str, sets: list[str], seconds: float) -> dict[str, Any]:
    """Measure the fixed cost of ``profile``: its nodes composed and spun, no source started."""
    from enbarr_core.bringup.compose import composed
    from enbarr_core.bringup.profile import apply_environment, load_profile

    prof = replace(load_profile(profile, sets), record=None)
    apply_environment(prof)
    with composed(prof) as c:
        def spin_for(s: float) -> None:
            end = time.monotonic() + s
            while time.monotonic() < end:
                c.executor.spin_once(timeout_sec=0.1)

        spin_for(IDLE_WARMUP)
        cpu0, wall0 = time.process_time(), time.monotonic()
        spin_for(seconds)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        nodes = len(c.nodes)
    share = cpu / wall
    return {'profile': prof.name, 'idle': True, 'nodes': nodes,
            'cpu_core_fraction': round(share, 4),
            'pi4_core_fraction_estimate': round(share * 6.0, 3),
            'machine': machine()}


def _overrides(chain: Chain, rate: float) -> list[str]:
    if chain.sink == 'pwm':
        return [f'simulator.rate={rate}', f'mocap.rate={rate}',
                "joystick.script=['0.0 sticks 0.0 0.0 0.0', '0.5 press triangle']"]
    return [f'simulator.rate={rate}']


def _chain_profile(chain: Chain, rate: float) -> Any:
    from enbarr_core.bringup.profile import load_profile
    prof = load_profile(chain.profile, _overrides(chain, rate))
    return replace(prof, nodes=tuple(n for n in prof.nodes if n.name in chain.nodes),
                   record=None)


def run_ros(chain: Chain, rate: float, seconds: float) -> dict[str, Any]:
    """Run ``chain`` composed in this process at ``rate`` [Hz]; return its figures."""
    from enbarr_core.bringup.compose import composed
    from enbarr_core.bringup.profile import apply_environment

    prof = _chain_profile(chain, rate)
    apply_environment(prof)
    with composed(prof) as c:
        c.start()
        sim, sink = c.node('simulator'), c.node(chain.sink)

        def spin_for(s: float) -> None:
            end = time.monotonic() + s
            while time.monotonic() < end:
                c.executor.spin_once(timeout_sec=0.1)

        spin_for(2.0)
        n0 = sink.latency.count
        cpu0, wall0 = time.process_time(), time.monotonic()
        spin_for(seconds)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        cycles = sink.latency.count - n0
    if not cycles:
        from enbarr_core.framework.errors import EnbarrError
        raise EnbarrError(f'no command reached {chain.sink}: the chain did not run')
    lat_ms = sink.latency.last(cycles) * 1e-6
    return {
        'rate_hz': round(cycles / wall, 1),
        'cycles': cycles,
        'late_ticks': sim.rate_loops[0].overruns,
        'time_skips': sim.time_skips,
        'latency_ms_p50': round(float(np.percentile(lat_ms, 50)), 3),
        'latency_ms_p99': round(float(np.percentile(lat_ms, 99)), 3),
        'latency_ms_max': round(float(lat_ms.max()), 3),
        'cpu_s_per_cycle': round(cpu / cycles, 6),
        'cpu_core_fraction': round(cpu / wall, 3),
    }


def _common(chain: str, rate: float) -> dict[str, Any]:
    prof = _chain_profile(CHAINS[chain], rate)
    return dict(prof.parameters), prof


def hot(loop: Iterator[None], cycles: int = 2000) -> float:
    """CPU seconds per cycle of ``loop`` (one cycle per ``next``) run back to back."""
    t0 = time.process_time()
    for _ in range(cycles):
        next(loop)
    return (time.process_time() - t0) / cycles


def paced_cycles(loop: Iterator[None], rate: float, seconds: float = 3.0) -> float:
    """CPU seconds per cycle of ``loop`` run one cycle per period of ``rate`` [Hz]."""
    period = 1.0 / rate
    cycles = max(20, round(seconds * rate))
    cpu = 0.0
    deadline = time.monotonic()
    for _ in range(cycles):
        t0 = time.process_time()
        next(loop)
        cpu += time.process_time() - t0
        deadline += period
        time.sleep(max(0.0, deadline - time.monotonic()))
    return cpu / cycles


def pure_rov(rate: float) -> Iterator[None]:
    """Run the ROV chain's algorithms, one cycle per ``next``."""
    from enbarr_core.allocation.fixed import allocation_matrix, Thruster, ThrustAllocator
    from enbarr_core.estimation.attitude_filter import AttitudeFilter
    from enbarr_core.framework.kinematics import quat_to_rotmat
    from enbarr_core.models.rigid_body import RigidBodyModel, RigidBodyParams, RigidBodyState
    from enbarr_core.control.velocity_control import VelocityController, VelocityReference
    from enbarr_core.control.velocity_control_node import SPECS, VelocityControlNodeSettings

    common, prof = _common('rov', rate)
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
    values = {s.name: s.default for s in SPECS}
    values.update({k: v for k, v in {**common, **prof.node('control_loop').parameters}.items()
                   if k in values})
    controller = VelocityController(VelocityControlNodeSettings.from_params(values).controller)
    reference = VelocityReference(values['reference_time_constant'], values['max_accel'])
    filt = AttitudeFilter()
    rng = np.random.default_rng(1)
    dt = 1.0 / rate
    state = RigidBodyState.at_rest((0.0, 0.0, -0.5))
    thrust = np.zeros(len(thrusters))
    goal = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.2])
    m_world = np.array([0.0, 1.8e-5, -4.8e-5])
    nan3 = np.full(3, np.nan)
    while True:
        tau = B @ thrust
        state = model.step(state, tau, dt)
        nu_dot = model.nu_dot(state.q, state.nu, tau)
        f = model.specific_force(state, nu_dot)
        gyro = state.nu[3:] + rng.normal(0.0, 0.002, 3)
        accel = f + rng.normal(0.0, 0.03, 3)
        mag = quat_to_rotmat(state.q).T @ m_world + rng.normal(0.0, 5e-7, 3)
        est = filt.step(gyro, accel, mag, dt)
        nu_ref, nu_ref_dot = reference.step(goal, dt)
        out = controller.step(nu_ref, np.concatenate((nan3, est.omega)), dt,
                              nu_d_dot=nu_ref_dot)
        thrust = allocator.allocate(out.tau).thrust
        yield


def pure_saucer(rate: float) -> Iterator[None]:
    """Run the Saucer chain's algorithms, one cycle per ``next``."""
    from enbarr_core.allocation.azimuth import AzimuthAllocator, PwmCalibration
    from enbarr_core.control import dp_control_node
    from enbarr_core.control.dp_control import DpController
    from enbarr_core.estimation import dp_observer_node
    from enbarr_core.estimation.dp_observer import PassiveObserver
    from enbarr_core.guidance.guidance import HoldPose
    from enbarr_core.models.vessel3dof import AzimuthActuators, AzimuthSpec, Vessel3Dof
    from enbarr_core.models.vessel3dof_params import vessel_from_params

    common, prof = _common('saucer', rate)

    def settings(node: str, module: Any, cls: Any) -> Any:
        # What the node would run with: its declared defaults, the profile's values.
        values = {s.name: s.default for s in module.SPECS}
        given = {**common, **prof.node(node).parameters}
        return cls.from_params({**values, **{k: v for k, v in given.items() if k in values}})

    specs = [AzimuthSpec(n, tuple(common[f'azimuths.{n}.position']),
                         common[f'azimuths.{n}.max_forward'],
                         common[f'azimuths.{n}.max_reverse'],
                         common[f'azimuths.{n}.angle_min'], common[f'azimuths.{n}.angle_max'],
                         common[f'azimuths.{n}.time_constant'],
                         common[f'azimuths.{n}.max_angle_rate'])
             for n in common['azimuth_names']]
    pwm = PwmCalibration.from_mapping({k.removeprefix('pwm.'): v for k, v in common.items()
                                       if k.startswith('pwm.')})
    vessel, actuators = Vessel3Dof(vessel_from_params(common)), AzimuthActuators(specs)
    allocator = AzimuthAllocator(specs)
    observer = PassiveObserver(settings('observer', dp_observer_node,
                                        dp_observer_node.DpObserverNodeSettings).observer)
    controller = DpController(settings('dp_control', dp_control_node,
                                       dp_control_node.DpControlNodeSettings).control)
    guidance = HoldPose((0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    dt = 1.0 / rate
    eta, nu = np.zeros(3), np.zeros(3)
    observer.initialize(eta)
    angle = np.zeros(len(specs))
    tau_delivered = np.zeros(3)
    while True:
        eta, nu = vessel.step(eta, nu, actuators.tau(), dt, current=(0.05, 0.0))
        y = eta + rng.normal(0.0, (0.002, 0.002, 0.005))
        est = observer.step(y, tau_delivered, dt)
        ref = guidance.reference(est.eta_hat, dt)
        tau = controller.step(est.eta_hat, est.nu_hat, est.b_hat, ref, dt).tau
        r = allocator.allocate(tau, previous_angle=angle)
        angle, tau_delivered = r.angle, r.tau_delivered
        duty = [(pwm.thrust_to_duty(f), pwm.angle_to_duty(a)) for f, a in zip(r.thrust, angle)]
        actuators.step([pwm.duty_to_thrust(d[0]) for d in duty],
                       [pwm.duty_to_angle(d[1]) for d in duty], dt)
        yield
