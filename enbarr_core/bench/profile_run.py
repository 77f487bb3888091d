"""``enbarr bench --profile NAME``: a whole vessel profile, run as a user runs it, measured.

``enbarr bringup --profile NAME`` runs as a child process tree (LOCALHOST, the bench's
ROS_DOMAIN_ID, with ``--output`` into a temporary bag directory). After ``--warmup`` seconds
(start-up and bringup's 3 s discovery wait), the CPU time of every process and thread of the
tree is read from ``/proc`` at the start and the end of a ``--seconds`` window; then bringup
is stopped with SIGINT (a recorder closes its bag) and one JSON line is printed:

- ``cpu_core_fraction``: CPU seconds of the whole tree per wall second (1.0 = one core busy),
  ``pi4_core_fraction_estimate`` = that x 6 (a Raspberry Pi 4 core runs CPython about six
  times slower, docs/benchmarks.md);
- ``threads``: the busiest threads as shares of a core, summed per thread name per process
  (``executor``: the main thread, which runs every node's timers and ROS subscriptions;
  ``<node>_loop``: a node's sources; ``recorder_writer``; ``dds.*``/``python``: middleware
  and other unnamed threads). The OS knows a Python thread's name only if it is told: every
  composed process installs ``enbarr_core.framework.threads.name_os_threads``
  (``compose.configure_process``). Names are cut to 15 characters by the kernel;
- ``processes``: the share of each process (its group) when there are several;
- ``vessel_cpu_core_fraction``: the tree without the threads of simulator and device emulator
  nodes (not on the vehicle), given only where those threads do their own work alone: not
  when a simulated device (``sim_imu``...) is fed on the simulator's thread, which then
  carries the whole control chain (``null`` then, and ``vessel_note`` says why). What stays
  mixed in: their timers and subscriptions (on the executor), the emulated device registers
  that a real driver reads (on its thread), DDS threads;
- ``rss_mb_start``/``rss_mb_end``: resident memory (VmRSS) summed over the tree just after
  the warm-up and at the end, and ``..._max``: of its biggest process;
- with ``--record``: the profile runs twice back to back, first without recording, then
  with; ``recorded_messages_per_second`` counts the bag's messages received in the window,
  ``cpu_us_per_recorded_message`` = (CPU with - CPU without) / messages recorded (all the
  recording costs: link taps, raw subscriptions, serializing, writing), and
  ``writer_cpu_us_per_recorded_message`` = the ``recorder_writer`` thread's CPU alone per
  message.

Figures depend on the machine and its load: run it alone, and compare runs made back to back.
"""

from __future__ import annotations

import os
from pathlib import Path
import random
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, NamedTuple

from enbarr_core.bench.chain import machine
from enbarr_core.framework.errors import EnbarrError

PI4_FACTOR = 6.0
TICKS = os.sysconf('SC_CLK_TCK')
PAGE_KB = os.sysconf('SC_PAGE_SIZE') / 1024.0
DEFAULT_SECONDS = 15.0
DEFAULT_WARMUP = 8.0
STOP_TIMEOUT = 40.0         # bringup's own grace is 10 s per batch of groups
START_TIMEOUT = 60.0        # after the warm-up, for every group to run
#: The line each process of bringup logs once its nodes run (run.run_group).
RUNNING = re.compile(r'\[enbarr\.bringup\]: .* running: ', re.MULTILINE)
TOP_THREADS = 8
STDERR_LINES = 8
EXECUTOR = 'executor'       # the label of a process's main thread


# -- /proc readers --------------------------------------------------------------------------

class ThreadTimes(NamedTuple):
    """CPU time [s] of one thread, and what it is called."""

    pid: int
    tid: int
    name: str
    cpu: float


def _stat_fields(path: Path) -> list[str]:
    """Return the fields of a ``stat`` file after the name (the name may hold spaces and ')')."""
    return path.read_text().rsplit(')', 1)[1].split()


def process_cpu(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid``, its exited threads included."""
    f = _stat_fields(Path(f'/proc/{pid}/stat'))
    return (int(f[11]) + int(f[12])) / TICKS


def thread_times(pid: int) -> list[ThreadTimes]:
    """CPU seconds of every live thread of ``pid``; the main thread is named ``executor``."""
    out = []
    for task in Path(f'/proc/{pid}/task').iterdir():
        try:
            f = _stat_fields(task / 'stat')
            name = (task / 'comm').read_text().rstrip('\n')
        except OSError:  # the thread ended meanwhile
            continue
        tid = int(task.name)
        out.append(ThreadTimes(pid, tid, EXECUTOR if tid == pid else name,
                               (int(f[11]) + int(f[12])) / TICKS))
    return out


def rss_mb(pid: int) -> float:
    """Resident size of ``pid`` [MB] (VmRSS; 0 for a zombie)."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) / 1024.0
    return 0.0


def process_tree(root: int) -> list[int]:
    """``root`` and its descendants, parents first."""
    children: dict[int, list[int]] = {}
    for d in Path('/proc').iterdir():
        if d.name.isdigit():
            try:
                ppid = int(_stat_fields(d / 'stat')[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [root]
    while todo:
        p = todo.pop(0)
        out.append(p)
        todo.extend(sorted(children.get(p, [])))
    return out


def process_label(pid: int, root: int) -> str:
    """Name a process of the tree: ``bringup``, ``group NAME`` or its command name."""
    try:
        argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
        comm = Path(f'/proc/{pid}/comm').read_text().strip()
    except OSError:
        return str(pid)
    if b'--group' in argv[:-1]:
        return f'group {argv[argv.index(b"--group") + 1].decode(errors="replace")}'
    return 'bringup' if pid == root else f'{comm} ({pid})'


class Snapshot(NamedTuple):
    """CPU times of a process tree at one instant."""

    wall: float                              # time.monotonic() [s]
    process: dict[int, float]                # pid -> CPU [s]
    thread: dict[int, ThreadTimes]           # tid -> its times
    rss: dict[int, float]                    # pid -> MB


def snapshot(root: int) -> Snapshot:
    """Read the CPU times and resident sizes of ``root``'s tree now."""
    process, thread, rss = {}, {}, {}
    for pid in process_tree(root):
        try:
            process[pid] = process_cpu(pid)
            rss[pid] = rss_mb(pid)
            thread.update({t.tid: t for t in thread_times(pid)})
        except (OSError, IndexError, ValueError):  # exited meanwhile
            process.pop(pid, None)
            rss.pop(pid, None)
    return Snapshot(time.monotonic(), process, thread, rss)


def cpu_between(a: Snapshot, b: Snapshot) -> tuple[float, dict[int, float],
                                                     dict[tuple[int, str], float]]:
    """CPU [s] used from ``a`` to ``b``: the tree's, per process, per (process, thread name).

    A process or thread born in between counts from zero; one that ended in between is lost
    (its time is not in ``b``), so per-thread sums may be less than the process's (the
    remainder is reported as ``threads_other``).
    """
    per_process = {p: b.process[p] - a.process.get(p, 0.0) for p in b.process}
    per_thread: dict[tuple[int, str], float] = {}
    for tid, t in b.thread.items():
        before = a.thread.get(tid)
        used = t.cpu - (before.cpu if before is not None and before.pid == t.pid else 0.0)
        key = (t.pid, t.name)
        per_thread[key] = per_thread.get(key, 0.0) + used
    return sum(per_process.values()), per_process, per_thread


# -- which threads are not on the vehicle -----------------------------------------------------

class Attribution(NamedTuple):
    """Simulator and emulator nodes of a profile, and whether their threads are their own."""

    nodes: tuple[tuple[str, str], ...]   # (node name, plugin name) not on the vehicle
    honest: bool
    note: str


def attribute(profile: Any) -> Attribution:
    """Which nodes of ``profile`` are not on the vehicle, and can their threads be told apart.

    A simulator (a plugin of ``enbarr_core.simulation``) or a device emulator (its class sets
    ``device_emulator``) is not on the vehicle. Its threads are its own only where no node of
    the vehicle runs on them: a simulated device (a plugin module ``*.sim``: ``sim_imu``,
    ``sim_mocap``, ``sim_thrusters``, ``sim_arduino``) takes the simulator's truth as a direct
    call on the simulator's thread and drives the chain from there (or calls the simulator on
    the chain's thread), so with one of them the split is refused.
    """
    from enbarr_core.framework import registry
    off, simulated = [], []
    for spec in profile.nodes:
        try:
            cls = registry.resolve(spec.plugin)
        except EnbarrError:
            continue
        module = cls.__module__.rsplit('.', 1)[-1]
        if cls.__module__.startswith('enbarr_core.simulation.') or getattr(
                cls, 'device_emulator', False):
            off.append((spec.name, spec.plugin))
        elif module == 'sim':
            simulated.append(spec.name)
    if not off:
        return Attribution((), False, 'no simulator or emulator nodes: all on the vehicle')
    if simulated:
        return Attribution(tuple(off), False,
                           f'simulated devices ({", ".join(simulated)}) are called on the '
                           "simulator's thread (sensors: the chain runs there) or call it on "
                           "the chain's (actuators): not separable")
    return Attribution(tuple(off), True,
                       'without the threads of simulator and emulator nodes; their timers '
                       'and subscriptions (executor) and the emulated registers a driver '
                       'reads (its thread) stay in')


def owned_by(thread: str, nodes: tuple[tuple[str, str], ...]) -> bool:
    """Whether the OS thread name ``thread`` is one of these nodes' own threads.

    A node's threads are named ``<node>_...`` (``<node>_loop``) or after its plugin
    (``qtm_emulator``); the kernel keeps 15 bytes of a name.
    """
    name = thread.encode()
    return any(name.startswith(f'{node}_'.encode()[:15]) or name == plugin.encode()[:15]
               for node, plugin in nodes)


# -- running bringup ------------------------------------------------------------------------

class Run(NamedTuple):
    """Figures of one bringup run."""

    wall: float
    cpu: float
    per_process: dict[str, float]            # label -> CPU [s]
    per_thread: dict[tuple[str, str], float]  # (process label, thread name) -> CPU [s]
    rss_start: dict[str, float]
    rss_end: dict[str, float]
    window_ns: tuple[int, int]               # time.time_ns() at the start and end
    exit_code: int | None
    warmup: float                            # from the start to the window [s]


def bench_domain() -> str:
    """Return the ROS_DOMAIN_ID to run in: the one set, else a random one (as ``./dev`` picks)."""
    return os.environ.get('ROS_DOMAIN_ID') or str(random.randint(1, 100))


def _last_lines(path: Path, n: int = STDERR_LINES) -> str:
    try:
        text = path.read_text(errors='replace')
    except OSError:
        return ''
    lines = [line for line in text.splitlines() if line.strip()][-n:]
    return ' | '.join(lines)


def _running(err_path: Path) -> int:
    """How many processes of the run have logged that their nodes run."""
    try:
        return len(RUNNING.findall(err_path.read_text(errors='replace')))
    except OSError:
        return 0


def run_once(profile: str, sets: list[str], warmup: float, seconds: float,
             bag: Path | None, workdir: Path, processes: int = 1,
             domain: str | None = None) -> Run:
    """Run ``enbarr bringup`` for the profile, measure the window, stop it with SIGINT.

    The window opens ``warmup`` seconds after the start, and not before each of the
    ``processes`` (one per group) has logged that its nodes run. ``domain``: the
    ROS_DOMAIN_ID to run in (default :func:`bench_domain`).
    """
    # The copy of enbarr that this bench runs (a source tree or the installed one).
    package_root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': domain or bench_domain(), 'PYTHONUNBUFFERED': '1',
           'PYTHONPATH': os.pathsep.join(p for p in (package_root,
                                                     os.environ.get('PYTHONPATH')) if p)}
    env.pop('ROS_LOCALHOST_ONLY', None)
    cmd = [sys.executable, '-m', 'enbarr_core.commands.main', 'bringup', '--profile', profile]
    for s in sets:
        cmd += ['--set', s]
    if bag is not None:
        cmd += ['--output', str(bag)]
    err_path = workdir / f'bringup-{time.monotonic_ns()}.err'
    launched = time.monotonic()
    with open(err_path, 'wb') as err:
        proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    try:
        def alive_for(s: float) -> None:
            end = time.monotonic() + s
            while time.monotonic() < end:
                if proc.poll() is not None:
                    raise EnbarrError(
                        f'bringup --profile {profile} exited early (code {proc.returncode}): '
                        f'{_last_lines(err_path) or "no output"}')
                time.sleep(min(0.1, max(0.0, end - time.monotonic())))

        alive_for(warmup)
        started = time.monotonic()
        while _running(err_path) < processes:   # a loaded machine starts slower
            if time.monotonic() - started > START_TIMEOUT:
                raise EnbarrError(
                    f'bringup --profile {profile}: {_running(err_path)} of {processes} '
                    f'process(es) running after {warmup + START_TIMEOUT:g} s: '
                    f'{_last_lines(err_path) or "no output"}')
            alive_for(0.2)
        t0_ns, a = time.time_ns(), snapshot(proc.pid)
        alive_for(seconds)
        b, t1_ns = snapshot(proc.pid), time.time_ns()
        labels = {p: process_label(p, proc.pid) for p in b.process}  # while they run
    except BaseException:
        _stop(proc)
        raise
    exit_code = _stop(proc)
    cpu, per_pid, per_thread = cpu_between(a, b)
    per_process: dict[str, float] = {}
    for pid, c in per_pid.items():
        per_process[labels[pid]] = per_process.get(labels[pid], 0.0) + c
    threads: dict[tuple[str, str], float] = {}
    for (pid, name), c in per_thread.items():
        key = (labels.get(pid, str(pid)), name)
        threads[key] = threads.get(key, 0.0) + c
    return Run(b.wall - a.wall, cpu, per_process, threads,
               {labels.get(p, str(p)): v for p, v in a.rss.items()},
               {labels.get(p, str(p)): v for p, v in b.rss.items()}, (t0_ns, t1_ns),
               exit_code, a.wall - launched)


def _stop(proc: subprocess.Popen[bytes]) -> int | None:
    """SIGINT bringup and wait for it (its recorder closes the bag); kill it past a limit."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            for pid in reversed(process_tree(proc.pid)):
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            proc.wait()
            return None
    return proc.returncode


def recorded_in(bag: Path, start_ns: int, end_ns: int) -> tuple[int, int]:
    """Messages of the bag in ``[start_ns, end_ns)`` of their log time, and in all."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    files = sorted(bag.rglob('*.mcap'))
    if not files:
        raise EnbarrError(f'{bag}: the recorded run left no MCAP file')
    inside = total = 0
    for f in files:
        with open(f, 'rb') as stream:
            try:
                for _, _, msg in make_reader(stream).iter_messages(log_time_order=False):
                    total += 1
                    inside += start_ns <= msg.log_time < end_ns
            except McapError as err:
                raise EnbarrError(f'{f}: not a readable MCAP file: {err}') from err
    return inside, total


# -- the command ----------------------------------------------------------------------------

def _share(cpu: float, wall: float) -> float:
    return round(cpu / wall, 4)


def figures(run: Run, attribution: Attribution) -> dict[str, Any]:
    """Return the JSON figures of one run."""
    share = run.cpu / run.wall
    top = sorted(run.per_thread.items(), key=lambda kv: -kv[1])
    several = len(run.per_process) > 1
    out: dict[str, Any] = {
        'warmup_s': round(run.warmup, 1),
        'seconds': round(run.wall, 2),
        'cpu_core_fraction': round(share, 4),
        'pi4_core_fraction_estimate': round(share * PI4_FACTOR, 3),
    }
    if attribution.honest:
        off = sum(c for (_, name), c in run.per_thread.items()
                  if owned_by(name, attribution.nodes))
        vessel = (run.cpu - off) / run.wall
        out['vessel_cpu_core_fraction'] = round(vessel, 4)
        out['vessel_pi4_core_fraction_estimate'] = round(vessel * PI4_FACTOR, 3)
    else:
        out['vessel_cpu_core_fraction'] = None
    out['vessel_note'] = attribution.note
    out['threads'] = [{'thread': name, **({'process': proc} if several else {}),
                       'core_fraction': _share(c, run.wall)}
                      for (proc, name), c in top[:TOP_THREADS]]
    out['threads_other'] = _share(run.cpu - sum(c for _, c in top[:TOP_THREADS]), run.wall)
    if several:
        out['processes'] = {p: _share(c, run.wall) for p, c in run.per_process.items()}
    for when, rss in (('start', run.rss_start), ('end', run.rss_end)):
        out[f'rss_mb_{when}'] = round(sum(rss.values()), 1)
        out[f'rss_mb_{when}_max'] = round(max(rss.values(), default=0.0), 1)
    out['bringup_exit'] = run.exit_code
    return out


def _processes(profile: Any, record: bool) -> int:
    """How many processes run the profile's nodes: one per group (the recorder's included)."""
    from enbarr_core.bringup.compose import add_recorder
    from enbarr_core.bringup.profile import with_record
    if record:
        profile = add_recorder(with_record(profile, 'bag', []))
    return len(profile.groups)


def writer_cpu(run: Run) -> float:
    """CPU [s] of the recorder's writer thread(s) in the window."""
    return sum(c for (_, name), c in run.per_thread.items() if name == 'recorder_writer')


def measure(profile: str, sets: list[str], warmup: float, seconds: float,
            record: bool) -> dict[str, Any]:
    """Measure ``profile`` (twice with ``record``); return the JSON line's dict."""
    from enbarr_core.bringup.profile import load_profile
    prof = load_profile(profile, sets)   # unknown profile, bad --set: one line
    attribution = attribute(prof)
    if record and prof.record is not None:
        raise EnbarrError(f'{prof.path}: the profile records already (its record section): '
                          'no run without a bag to compare with; drop --record')
    processes = _processes(prof, record=False)
    recorded = _processes(prof, record=True)
    result: dict[str, Any] = {'profile': prof.name, 'record': record, 'warmup': warmup}
    with tempfile.TemporaryDirectory(prefix='enbarr-bench-') as tmp:
        work = Path(tmp)
        if record:
            bare = run_once(profile, sets, warmup, seconds, None, work, processes)
            bag = work / 'bag'
            run = run_once(profile, sets, warmup, seconds, bag, work, recorded)
            inside, total = recorded_in(bag, *run.window_ns)
        else:
            run = run_once(profile, sets, warmup, seconds, None, work, processes)
        result.update(figures(run, attribution))
        if record:
            wall_s = (run.window_ns[1] - run.window_ns[0]) * 1e-9
            result['unrecorded'] = figures(bare, attribution)
            result['recorded_messages'] = inside
            result['recorded_messages_run'] = total
            result['recorded_messages_per_second'] = round(inside / wall_s, 1)
            if inside:
                extra = run.cpu / run.wall - bare.cpu / bare.wall   # core fraction
                result['cpu_us_per_recorded_message'] = round(
                    extra * wall_s / inside * 1e6, 2)
                result['writer_cpu_us_per_recorded_message'] = round(
                    writer_cpu(run) / inside * 1e6, 2)
            else:
                result['cpu_us_per_recorded_message'] = None
                result['writer_cpu_us_per_recorded_message'] = None
        shutil.rmtree(work / 'bag', ignore_errors=True)
    result['machine'] = machine()
    return result


# -- a profile against a baseline -------------------------------------------------------------

def other_domain(domain: str) -> str:
    """Return a second ROS_DOMAIN_ID beside ``domain`` (both valid for Fast DDS: 0..232)."""
    d = int(domain)
    return str(d - 1 if d > 100 else d + 1)


def thread_kind(name: str) -> str:
    """Return a thread's name without the numbers a run gives it (a DDS thread's port)."""
    return re.sub(r'(\.\d+)+$', '', name)


def difference(run: Run, base: Run) -> dict[str, float]:
    """Return the shares of a core by which ``run`` exceeds ``base``: whole, and per thread.

    Threads are grouped by :func:`thread_kind` (the two runs' DDS ports differ). Every group
    of either run is listed, one missing from a run counting as 0 there, and
    ``threads_other`` is the process time in no thread read (threads that ended; the process
    and its threads are read a clock tick apart), so the groups add up to the whole, to
    their rounding.
    """
    out = {'cpu_core_fraction': round(run.cpu / run.wall - base.cpu / base.wall, 4)}
    shares: dict[str, float] = {'threads_other': 0.0}
    for one, sign in ((run, 1.0), (base, -1.0)):
        for (_, name), c in one.per_thread.items():
            kind = thread_kind(name)
            shares[kind] = shares.get(kind, 0.0) + sign * c / one.wall
        in_threads = sum(one.per_thread.values())
        shares['threads_other'] += sign * (one.cpu - in_threads) / one.wall
    for kind in sorted(shares):
        out[kind] = round(shares[kind], 4)
    return out


def summarize_pairs(differences: list[float]) -> dict[str, Any]:
    """Return the mean, median, spread and Pi 4 estimate of the pairs' differences."""
    mean = statistics.fmean(differences)
    return {'pairs': len(differences), 'mean': round(mean, 4),
            'median': round(statistics.median(differences), 4),
            'min': round(min(differences), 4), 'max': round(max(differences), 4),
            'stdev': round(statistics.stdev(differences), 4) if len(differences) > 1 else None,
            'pi4_core_fraction_estimate': round(mean * PI4_FACTOR, 3)}


def compare(profile: str, baseline: str, sets: list[str], warmup: float, seconds: float,
            pairs: int) -> dict[str, Any]:
    """Measure ``profile`` against ``baseline`` in ``pairs`` pairs of runs; the JSON dict.

    The two runs of a pair go at the same time, each in its own ROS domain, so that what
    the machine does meanwhile (other work, a shared host's neighbours) weighs on both; on
    a machine with fewer than two cores they would take turns, and the pairs are refused.
    ``sets`` apply to both. The difference of each pair, and their mean and spread, are
    what ``profile`` costs beyond ``baseline``.
    """
    from enbarr_core.bringup.profile import load_profile
    if (os.cpu_count() or 1) < 2:
        raise EnbarrError('--against runs the two profiles at once: it needs two cores')
    profiles = [load_profile(p, sets) for p in (profile, baseline)]   # bad ones: one line
    processes = [_processes(p, record=False) for p in profiles]
    domains = [bench_domain()]
    domains.append(other_domain(domains[0]))
    result: dict[str, Any] = {'profile': profiles[0].name, 'against': profiles[1].name,
                              'warmup': warmup, 'seconds': seconds}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix='enbarr-bench-') as tmp:
        work = Path(tmp)
        for _ in range(pairs):
            runs: list[Run | None] = [None, None]
            errors: list[BaseException] = []

            def one(k: int) -> None:
                try:
                    runs[k] = run_once((profile, baseline)[k], sets, warmup, seconds, None,
                                       work, processes[k], domains[k])
                except BaseException as err:   # noqa: BLE001  # raised below, on this thread
                    errors.append(err)

            threads = [threading.Thread(target=one, args=(k,)) for k in (0, 1)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            if errors:
                raise errors[0]
            run, base = runs
            assert run is not None and base is not None
            rows.append({'profile': _share(run.cpu, run.wall),
                         'against': _share(base.cpu, base.wall),
                         'difference': difference(run, base)})
    result['runs'] = rows
    result['difference'] = summarize_pairs([r['difference']['cpu_core_fraction'] for r in rows])
    result['machine'] = machine()
    return result
