"""A simulated scenario run headless, faster than real time (``enbarr scenario NAME``).

A scenario is a vessel profile (``params/scenarios/NAME.yaml``) with a ``scenario`` section::

    scenario:
      duration: 60.0          # simulated seconds
      kind: station_keeping   # or: path, or run (only the common figures; a test judges it)
      settle_time: 20.0       # s after automatic began: the evaluation window starts here
                              # (station_keeping only, required there)
      settle_band: [0.05, 2.0] # m, deg: settled once the errors stay inside (default)
      targets:                 # required: what the run must achieve (tools.targets)
        position_error_rms_m: {max: 0.01}
        settled_in_time: true

The nodes are built exactly as ``bringup`` builds them, in one process, but time is
simulated: every node's ROS clock is set to the simulated time, and the runner steps the
simulator itself (instead of its real-time loop), then lets the executor run whatever timers
and callbacks became due. A simulated camera's frames are rendered in step too
(``stepped_renderers``), not on its wall-clock thread. Nothing waits for the wall clock (but
the start, until the recorder has the latched topics' messages: ``wait_for_latched``), so a
scenario runs as fast as the machine computes it; stamps, timers, watchdogs and recorded
times are all simulated time.

The run is recorded (rosbag2/MCAP) into the output directory: the topics the metrics and the
plot read (``metrics.METRIC_TOPICS``, ``metrics.PLOT_TOPICS``; with the collision avoidance
``avoidance_metrics.AVOIDANCE_TOPICS``, with a simulated camera and a detector
``vision_metrics.VISION_TOPICS``, with the ROV's failsafes
``failsafe_metrics.FAILSAFE_TOPICS``), plus the topics the scenario lists in its ``record``
section (its ``path`` is replaced by the output directory), or every topic with
``--record-all`` (several times slower: the recorder serializes each message of every 100 Hz
topic). The metrics are computed from that bag (their definitions:
:mod:`enbarr_core.tools.metrics`), judged against the scenario's targets
(:mod:`enbarr_core.tools.targets`) and printed as one JSON line: ``scenario``, ``verdict``
(``pass`` or ``fail``), ``failed``, the figures, ``targets`` (each with its bound, value and
``pass``), ``simulated_s``, ``wall_s``, ``real_time_factor``, ``cpu_s``, ``bag`` and ``plot``.
A run with ``--duration`` or ``--set`` is judged against the same targets. The PNG
(``metrics.plot_run``) carries the verdict too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
import math
from pathlib import Path
import time
from typing import Any

from enbarr_core.framework.checks import MAX_SECONDS
from enbarr_core.framework.errors import EnbarrError, ProfileError
from enbarr_core.tools.targets import judge, parse_targets, Target

T0_NS = 1_000_000_000  # simulated time starts at 1 s (0 is 'unset' in many stamps)
#: Wall time [s] a scenario waits at start for the recorder's latched topics.
LATCHED_WAIT_S = 0.5
SCENARIO_KEYS = ('duration', 'kind', 'settle_time', 'settle_band', 'targets')
SCENARIO_KINDS = ('station_keeping', 'path', 'run')  # run: modes and saturation only


@dataclass(frozen=True)
class ScenarioSpec:
    """The ``scenario`` section of a scenario profile."""

    duration: float                   # simulated seconds
    kind: str                         # station_keeping, path or run
    settle_band: tuple[float, float]  # [m, deg]
    settle_time: float | None = None  # [s] after automatic began (station_keeping only)
    targets: tuple[Target, ...] = ()  # what the run must achieve (``tools.targets``)


def scenario_spec(profile: Any) -> ScenarioSpec:
    """Read and check the profile's ``scenario`` section."""
    raw = profile.scenario
    if not raw:
        raise ProfileError('not a scenario: it has no "scenario" section', path=profile.path)
    unknown = sorted(set(raw) - set(SCENARIO_KEYS))
    if unknown:
        raise ProfileError(f'unknown key {unknown[0]!r}; expected: {", ".join(SCENARIO_KEYS)}',
                           path=profile.path, key='scenario')
    duration = _number(raw.get('duration'), profile, 'duration', 'simulated seconds > 0')
    if not 0 < duration <= MAX_SECONDS:
        raise ProfileError(f'must be > 0 and at most {MAX_SECONDS:.0f} (simulated seconds), '
                           f'got {duration}', path=profile.path, key='scenario.duration')
    kind = raw.get('kind', 'station_keeping')
    if kind not in SCENARIO_KINDS:
        raise ProfileError(f'must be one of {", ".join(SCENARIO_KINDS)}, got {kind!r}',
                           path=profile.path, key='scenario.kind')
    band = raw.get('settle_band', (0.05, 2.0))
    if not isinstance(band, (list, tuple)) or len(band) != 2:
        raise ProfileError(f'expected two numbers [m, deg], got {band!r}',
                           path=profile.path, key='scenario.settle_band')
    band_m = _number(band[0], profile, 'settle_band', 'two numbers > 0 [m, deg]')
    band_deg = _number(band[1], profile, 'settle_band', 'two numbers > 0 [m, deg]')
    if not (band_m > 0 and band_deg > 0):
        raise ProfileError(f'expected two numbers > 0 [m, deg], got {list(band)}',
                           path=profile.path, key='scenario.settle_band')
    settle_time = None
    if kind == 'station_keeping':
        if 'settle_time' not in raw:
            raise ProfileError('required for a station_keeping scenario: the seconds after '
                               'automatic mode begins when the evaluation window starts',
                               path=profile.path, key='scenario.settle_time')
        settle_time = _number(raw['settle_time'], profile, 'settle_time', 'seconds >= 0')
        if not 0.0 <= settle_time < duration:
            raise ProfileError(f'must be >= 0 and below the duration ({duration} s), got '
                               f'{settle_time}', path=profile.path, key='scenario.settle_time')
    elif 'settle_time' in raw:
        raise ProfileError('only for a station_keeping scenario', path=profile.path,
                           key='scenario.settle_time')
    from enbarr_core.tools.metrics import figures_of
    targets = parse_targets(raw.get('targets'), kind, figures_of(kind), profile.path)
    return ScenarioSpec(duration, kind, (band_m, band_deg), settle_time, targets)


def _number(value: Any, profile: Any, key: str, expected: str) -> float:
    """``value`` as a finite float, or a ProfileError naming ``scenario.key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ProfileError(f'expected {expected}, got {value!r}', path=profile.path,
                           key=f'scenario.{key}')
    return float(value)


def with_duration(spec: ScenarioSpec, duration: float) -> ScenarioSpec:
    """``spec`` run for ``duration`` [s] (``--duration``); it must outlast the settle time."""
    if not duration > 0:
        raise EnbarrError(f'--duration must be positive, got {duration}')
    if spec.settle_time is not None and not duration > spec.settle_time:
        raise EnbarrError(f'--duration {duration} s leaves no evaluation window: the '
                          f"scenario's settle_time is {spec.settle_time} s after automatic "
                          'began')
    return replace(spec, duration=duration)


def known_scenarios() -> list[str]:
    """Names of the scenarios in the profile search path (``scenarios/*.yaml``), sorted."""
    from enbarr_core.bringup.profile import search_dirs
    return sorted({f.stem for d in search_dirs() for f in (d / 'scenarios').glob('*.yaml')})


def resolve(name: str) -> str:
    """Find a scenario: a bare name means ``scenarios/NAME`` among the installed profiles."""
    from enbarr_core.bringup.profile import search_dirs
    if '/' in name or name.endswith('.yaml'):
        return name
    for d in search_dirs():
        candidate = d / 'scenarios' / f'{name}.yaml'
        if candidate.is_file():
            return str(candidate)
    raise ProfileError(f'no scenario {name!r}; scenarios: {", ".join(known_scenarios())}')


def record_topics(profile: Any, plot: bool = True, record_all: bool = False) -> tuple[str, ...]:
    """Return the topics a scenario records, sorted (empty: every topic, ``--record-all``)."""
    from enbarr_core.tools.avoidance_metrics import AVOIDANCE_TOPICS, avoids
    from enbarr_core.tools.failsafe_metrics import FAILSAFE_TOPICS, has_failsafes
    from enbarr_core.tools.metrics import METRIC_TOPICS, PLOT_TOPICS
    from enbarr_core.tools.rov_plot import is_rov, ROV_PLOT_TOPICS
    from enbarr_core.tools.vision_metrics import sees, VISION_TOPICS
    if record_all:
        return ()
    listed = profile.record.topics if profile.record is not None else ()
    avoiding = AVOIDANCE_TOPICS if avoids(profile) else ()
    seeing = VISION_TOPICS if sees(profile) else ()
    failsafes = FAILSAFE_TOPICS if has_failsafes(profile) else ()
    plotted = (ROV_PLOT_TOPICS if is_rov(profile) else PLOT_TOPICS) if plot else ()
    return tuple(sorted({*METRIC_TOPICS, *plotted, *avoiding, *seeing, *failsafes, *listed}))


def run(name: str, output: str | None = None, overrides: list[str] | tuple[str, ...] = (),
        plot: bool = True, duration: float | None = None,
        record_all: bool = False) -> dict[str, Any]:
    """Run scenario ``name`` on simulated time, record it and return its metrics."""
    from enbarr_core.bringup.compose import add_recorder, composed
    from enbarr_core.bringup.profile import apply_environment, load_profile, with_record

    profile = load_profile(resolve(name), overrides)
    spec = scenario_spec(profile)
    if duration is not None:
        spec = with_duration(spec, duration)
    out = Path(output or f'runs/scenario-{profile.name}-{time.strftime("%Y%m%d-%H%M%S")}')
    if out.exists() and any(out.iterdir()):
        raise EnbarrError(f'{out}: exists and is not empty')
    out.mkdir(parents=True, exist_ok=True)
    bag = out / 'bag'
    topics = record_topics(profile, plot, record_all)
    # The scenario's record section only lists topics: its path is replaced by ``bag``.
    profile = add_recorder(with_record(replace(profile, record=None), str(bag), topics))
    apply_environment(profile)
    wall0, cpu0 = time.monotonic(), time.process_time()
    # bringup's own executor (EventsExecutor); the world's time 0 is the scenario's start
    with composed(profile, world_epoch_ns=T0_NS) as c:
        sim = next((n for n in c.nodes if n.get_name() == 'simulator'), None)
        if sim is None or not hasattr(sim, 'step'):
            raise ProfileError('a scenario needs a node named simulator', path=profile.path)
        set_time = simulated_time([n.get_clock() for n in c.nodes])
        now = T0_NS
        set_time(now)
        c.start(skip=[sim])  # the simulator is stepped here, not by its real-time loop
        renderers = stepped_renderers(c.nodes)  # and the simulated cameras' frames
        run_due = _run_due(c.executor)
        run_due()
        wait_for_latched(c.nodes, run_due)
        dt_ns = sim.period_ns
        end = now + int(spec.duration * 1e9)
        while now < end:
            now += dt_ns
            set_time(now)
            sim.step()
            run_due()  # everything due at this instant: timers, ROS messages, and theirs
            for r in renderers:
                if r.render_pending():  # a frame due at this instant, and what reads it
                    run_due()
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    from enbarr_core.recording.bag import read_bag
    from enbarr_core.tools.metrics import compute_metrics, plot_run
    msgs = read_bag(bag)  # once, for the metrics and the plot
    figures = compute_metrics(bag, spec, profile, msgs)
    verdict = judge(figures, spec.targets)
    result = {'scenario': profile.name, 'verdict': verdict['verdict'],
              'failed': verdict['failed'], **figures, 'targets': verdict['targets'],
              'simulated_s': spec.duration, 'wall_s': round(wall, 2),
              'real_time_factor': round(spec.duration / wall, 1), 'cpu_s': round(cpu, 2),
              'bag': str(bag)}
    if plot:
        result['plot'] = str(plot_run(bag, spec, profile, out / f'{profile.name}.png', msgs,
                                      verdict))
    return result


def simulated_time(clocks: list[Any]) -> Callable[[int], None]:
    """Put ``clocks`` (the nodes' ROS clocks) on simulated time; return the call that sets it.

    This is what a node's ``use_sim_time`` does with ``/clock``, through the same public rclpy
    API (a ``TimeSource`` with ROS time active, the clocks attached, each time fed to its
    ``clock_callback``), but the time source belongs to the runner and subscribes to nothing:
    each step costs no message per node, and no ``/clock`` from another process in the domain
    can move a scenario's time.
    """
    from rclpy.time_source import TimeSource
    from rosgraph_msgs.msg import Clock

    source = TimeSource()  # no node: no /clock subscription
    source.ros_time_is_active = True
    for clock in clocks:
        source.attach_clock(clock)
    msg = Clock()

    def set_time(t_ns: int) -> None:
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 1_000_000_000)
        source.clock_callback(msg)
    return set_time


def stepped_renderers(nodes: list[Any]) -> list[Any]:
    """Take the nodes that render on their own wall-clock thread (``sim_camera``) off it.

    Each is asked to leave its frames to the caller (``render_in_caller``); the run renders
    every due frame in step (``render_pending``), so that no frame is skipped because
    simulated time ran ahead of the renderer and a run repeats whatever the machine.
    """
    return [n for n in nodes if callable(getattr(n, 'render_in_caller', None))
            and n.render_in_caller()]


def wait_for_latched(nodes: list[Any], run_due: Callable[[], None],
                     timeout: float = LATCHED_WAIT_S) -> list[str]:
    """Before simulated time moves: let the recorder receive every latched topic's message.

    A latched message published at start (the controller's ``mode``) reaches the recorder,
    which subscribed after it, some milliseconds of wall time later (the middleware's
    late-joiner repair). Simulated time does not wait for that: at 30 times real time the next
    mode had replaced it before it came, and the bag started without the initial mode
    (2026-11-27). Waits ``timeout`` [s] of wall time at most (a latched topic whose publisher
    published nothing yet never arrives); returns the topics still pending.
    """
    from enbarr_core.bringup.compose import RECORDER_NODE
    recorder = next((n for n in nodes if n.get_name() == RECORDER_NODE), None)
    if recorder is None:
        return []
    deadline = time.monotonic() + timeout
    while recorder.latched_pending() and time.monotonic() < deadline:
        time.sleep(0.001)
        run_due()
    return recorder.latched_pending()


def _run_due(executor: Any) -> Callable[[], None]:
    """Return a call that runs every callback due now on ``executor`` (an ``EventsExecutor``).

    rclpy's ``EventsExecutor`` (7.1.x) queues an event when a message arrives (the middleware's
    listener, called in the publisher's thread for an in-process subscriber), when a clock of
    a timer is set (its jump callback) and when a timer it dispatched must be rescheduled.
    ``spin_until_future_complete`` with a zero timeout runs that queue until it is empty,
    events queued by the callbacks included, and never waits: with a future that never
    completes, it is "run everything due at this instant".
    """
    from rclpy.task import Future
    never = Future()
    return lambda: executor.spin_until_future_complete(never, timeout_sec=0.0)
