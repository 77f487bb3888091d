"""``enbarr bench --profile``: its /proc readers on this process, its thread attribution, its
count of recorded messages (unit), and the command itself (e2e: its errors, a short real run).

The readers are checked against a second source: CPU time against ``time.thread_time`` and
``time.process_time``, resident size against an allocation of known size; the OS thread name
against the kernel's own ``comm`` file.
"""

from __future__ import annotations

import json
import mmap
import os
from pathlib import Path
import re
import threading
import time

from mcap.writer import Writer
import pytest

from support.cli import enbarr, refused
from support.processes import split_profile

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import EnbarrError
from enbarr_core.framework.threads import name_os_threads, os_thread_name
from enbarr_core.bench import profile_run as bp

TICK = 1.0 / bp.TICKS


def _burn(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


@pytest.fixture
def named_threads():
    """``name_os_threads`` for the threads a test starts; the hook removed afterwards."""
    before = threading.getprofile()
    name_os_threads()
    yield
    threading.setprofile(before)


def _in_thread(name: str, work) -> object:
    """Run ``work()`` on a thread called ``name``; return what it returned."""
    out: list[object] = []
    t = threading.Thread(target=lambda: out.append(work()), name=name)
    t.start()
    t.join(30)
    return out[0]


def test_threads_carry_their_name_into_the_os(named_threads: None) -> None:
    def comm() -> str:
        return Path(f'/proc/self/task/{threading.get_native_id()}/comm').read_text().strip()

    assert _in_thread('recorder_writer', comm) == 'recorder_writer'
    assert _in_thread('thruster_converter_loop', comm) == 'thruster_conver'  # 15 bytes kept
    assert os_thread_name('thruster_converter_loop') == b'thruster_conver'


def test_thread_times_read_each_thread_by_name(named_threads: None) -> None:
    def work() -> tuple[list[bp.ThreadTimes], float]:
        _burn(0.3)
        return bp.thread_times(os.getpid()), time.thread_time()

    threads, own = _in_thread('bench_burner', work)
    mine = [t for t in threads if t.name == 'bench_burner']
    assert len(mine) == 1
    assert abs(mine[0].cpu - own) <= 2 * TICK + 0.01  # the kernel's ticks vs thread_time
    main = [t for t in threads if t.tid == os.getpid()]
    assert [t.name for t in main] == [bp.EXECUTOR]


def test_process_cpu_counts_every_thread() -> None:
    before, ours = bp.process_cpu(os.getpid()), time.process_time()
    _burn(0.3)
    used, ours = bp.process_cpu(os.getpid()) - before, time.process_time() - ours
    assert abs(used - ours) <= 2 * TICK + 0.01


def test_rss_follows_what_is_resident() -> None:
    with mmap.mmap(-1, 64 << 20) as block:   # mapped: not resident until written
        start = bp.rss_mb(os.getpid())
        block[::4096] = b'\1' * len(block[::4096])
        grown = bp.rss_mb(os.getpid()) - start
    assert 63.5 <= grown <= 65.0, grown
    with mmap.mmap(-1, 64 << 20):
        assert bp.rss_mb(os.getpid()) - start < grown - 50.0


def test_process_tree_and_snapshot_of_this_process() -> None:
    assert bp.process_tree(os.getpid())[0] == os.getpid()
    s = bp.snapshot(os.getpid())
    assert os.getpid() in s.process and s.rss[os.getpid()] > 10.0
    assert s.thread[os.getpid()].name == bp.EXECUTOR


def _snap(wall: float, process: dict[int, float], threads: list[tuple[int, int, str, float]],
          ) -> bp.Snapshot:
    return bp.Snapshot(wall, process, {t[1]: bp.ThreadTimes(*t) for t in threads},
                       dict.fromkeys(process, 1.0))


def test_cpu_between_sums_per_name_and_counts_new_threads_from_zero() -> None:
    a = _snap(0.0, {10: 5.0}, [(10, 10, 'executor', 3.0), (10, 11, 'dds', 1.0),
                               (10, 12, 'dds', 1.0), (10, 13, 'gone', 0.5)])
    b = _snap(2.0, {10: 7.0, 20: 0.4},
              [(10, 10, 'executor', 3.5), (10, 11, 'dds', 1.25), (10, 12, 'dds', 1.25),
               (10, 14, 'born', 0.3), (20, 20, 'executor', 0.4)])
    cpu, per_process, per_thread = bp.cpu_between(a, b)
    assert cpu == pytest.approx(2.4)
    assert per_process == pytest.approx({10: 2.0, 20: 0.4})
    assert per_thread == pytest.approx({(10, 'executor'): 0.5, (10, 'dds'): 0.5,
                                        (10, 'born'): 0.3, (20, 'executor'): 0.4})


def test_owned_by_matches_a_node_s_threads_and_no_other() -> None:
    nodes = (('lidar_emulator', 'rplidar_emulator'), ('simulator', 'vessel3dof_simulator'),
             ('imu_emulator', 'lsm9ds1_emulator'), ('long_device_emulator', 'pca9685_emulator'))
    # the kernel keeps 15 bytes: 'long_device_emulator_loop' is 'long_device_emu'
    for name in ('simulator_loop', 'rplidar_emulato', 'lidar_emulator_', 'imu_emulator_lo',
                 'long_device_emu', 'pca9685_emulato'):
        assert bp.owned_by(name, nodes), name
    for name in ('imu_loop', 'lidar_reader', 'executor', 'simulator', 'recorder_writer',
                 'lsm9ds1_emulat'):
        assert not bp.owned_by(name, nodes), name


def test_attribution_of_profiles() -> None:
    emulated = bp.attribute(load_profile('saucer_emulated'))
    assert emulated.honest
    assert {n for n, _ in emulated.nodes} == {
        'simulator', 'arduino_emulator', 'qtm_emulator', 'lidar_emulator', 'camera_emulator',
        'ds4_emulator'}
    simulated = bp.attribute(load_profile('saucer_sim'))
    assert not simulated.honest and 'mocap' in simulated.note
    assert [n for n, _ in simulated.nodes] == ['simulator']
    rov = bp.attribute(load_profile('enbarr_sim'))   # sim_gpio, sim_stepper: not fed by it
    assert not rov.honest and '(imu, thruster_control, depth, battery, hull)' in rov.note
    real = bp.attribute(load_profile('enbarr_rov'))
    assert real.nodes == () and not real.honest


def _bag(path: Path, log_times: list[int]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'wb') as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema('std_msgs/msg/Empty', 'ros2msg', b'')
        channel = w.register_channel('/x', 'cdr', schema)
        for t in log_times:
            w.add_message(channel, log_time=t, data=b'\0\1\0\0', publish_time=t)
        w.finish()


def test_recorded_in_counts_the_window_over_every_file(tmp_path: Path) -> None:
    _bag(tmp_path / 'bag' / 'a_0.mcap', [5, 10, 11, 19])
    _bag(tmp_path / 'bag' / 'a_1.mcap', [20, 25, 30])
    assert bp.recorded_in(tmp_path / 'bag', 10, 25) == (4, 7)   # [10, 25)


def test_recorded_in_refuses_a_bag_it_cannot_read(tmp_path: Path) -> None:
    with pytest.raises(EnbarrError, match='no MCAP file'):
        bp.recorded_in(tmp_path, 0, 1)
    (tmp_path / 'x.mcap').write_bytes(b'not mcap at all')
    with pytest.raises(EnbarrError, match=r'x\.mcap: not a readable MCAP file'):
        bp.recorded_in(tmp_path, 0, 1)


def _run(cpu: float, threads: dict[tuple[str, str], float], wall: float = 10.0) -> bp.Run:
    return bp.Run(wall, cpu, {}, threads, {}, {}, (0, 1), 0, 8.0)


def test_difference_is_whole_and_per_thread_shares() -> None:
    run = _run(1.6, {('bringup', 'executor'): 0.5, ('bringup', 'simulator_loop'): 1.1})
    base = _run(1.2, {('bringup', 'executor'): 0.2995, ('bringup', 'simulator_loop'): 0.9,
                      ('bringup', 'python'): 0.0005}, wall=8.0)
    d = bp.difference(run, base)
    assert d['cpu_core_fraction'] == pytest.approx(0.16 - 0.15)
    assert d['executor'] == pytest.approx(0.05 - 0.2995 / 8.0, abs=1e-4)
    assert d['simulator_loop'] == pytest.approx(0.11 - 0.1125)
    assert d['python'] == pytest.approx(-0.0005 / 8.0, abs=1e-4)   # every thread, small too
    assert d['threads_other'] == 0.0                   # the threads hold all the time here
    assert set(d) == {'cpu_core_fraction', 'executor', 'simulator_loop', 'python',
                      'threads_other'}


def test_difference_groups_a_runs_numbered_threads_and_adds_up() -> None:
    # The two runs are in two ROS domains: their DDS threads carry different ports.
    run = _run(2.0, {('bringup', 'dds.udp.7000'): 0.2, ('bringup', 'dds.udp.7001'): 0.1,
                     ('bringup', 'dds.asyn.0.0'): 0.05, ('bringup', 'executor'): 1.0})
    base = _run(1.5, {('bringup', 'dds.udp.7250'): 0.25, ('bringup', 'dds.udp.7251'): 0.1,
                      ('bringup', 'dds.asyn.0.0'): 0.05, ('bringup', 'executor'): 0.8})
    d = bp.difference(run, base)
    assert set(d) == {'cpu_core_fraction', 'dds.udp', 'dds.asyn', 'executor', 'threads_other'}
    assert d['dds.udp'] == pytest.approx(-0.005) and d['dds.asyn'] == 0.0
    assert d['threads_other'] == pytest.approx((0.65 - 0.3) / 10.0)   # ended threads' time
    assert sum(v for k, v in d.items() if k != 'cpu_core_fraction') == pytest.approx(
        d['cpu_core_fraction'])
    assert bp.thread_kind('dds.shm.wdog') == 'dds.shm.wdog'
    assert bp.thread_kind('simulator_loop') == 'simulator_loop'


def test_pairs_summary_and_domains() -> None:
    s = bp.summarize_pairs([0.02, 0.03, 0.016, 0.022])
    assert s['pairs'] == 4 and s['mean'] == pytest.approx(0.022)
    assert s['median'] == pytest.approx(0.021) and (s['min'], s['max']) == (0.016, 0.03)
    assert s['pi4_core_fraction_estimate'] == pytest.approx(0.132)
    assert s['stdev'] == pytest.approx(0.00589, abs=1e-5)
    assert bp.summarize_pairs([0.01])['stdev'] is None
    for d in ('0', '7', '100', '101', '232'):
        other = bp.other_domain(d)
        assert other != d and 0 <= int(other) <= 232


# -- the command (e2e: processes) -------------------------------------------------------------

@pytest.mark.e2e
@pytest.mark.parametrize('args, says', [
    (['--profile', 'no_such_profile'], "profile 'no_such_profile' not found"),
    (['--profile', 'saucer_sim', '--seconds', '0'], '--seconds must be a positive finite'),
    (['--profile', 'saucer_sim', '--warmup', 'inf'], '--warmup must be a positive finite'),
    (['--profile', 'saucer_sim', '--rate', '50'], '--rate is for --chain'),
    (['--chain', 'rov', '--record'], '--record is for --profile'),
    (['--chain', 'rov', '--idle'], '--idle is for --profile'),
    (['--profile', 'saucer_sim', '--idle', '--record'], '--record does not go with --idle'),
    (['--profile', 'saucer_sim', '--idle', '--seconds', '-1'], '--seconds must be a positive'),
    (['--profile', 'saucer_sim', '--set', 'nobody.rate=5'], "no node 'nobody'"),
    (['--chain', 'rov', '--against', 'saucer_sim'], '--against and --pairs are for --profile'),
    (['--profile', 'saucer_sim', '--idle', '--pairs', '2'], '--against and --pairs are for'),
    (['--profile', 'saucer_sim', '--pairs', '2'], '--pairs is for --against'),
    (['--profile', 'saucer_sim', '--against', 'saucer_sim', '--pairs', '0'],
     '--pairs must be 1..50'),
    (['--profile', 'saucer_sim', '--against', 'saucer_sim', '--record'],
     '--record does not go with --against'),
    (['--profile', 'saucer_sim', '--against', 'no_such_base'], "'no_such_base' not found"),
    (['--profile', 'saucer_sim', '--warmup', '30', '--set', 'simulator.rate=-5'],
     r'bringup --profile saucer_sim exited early \(code 2\): enbarr bringup: error: .*rate'),
])
def test_bench_profile_refuses_with_one_line(args: list[str], says: str) -> None:
    line = refused(enbarr('bench', *args, timeout=120), 'bench')
    assert re.search(says, line), line


@pytest.mark.e2e
def test_bench_profile_runs_a_recorded_profile() -> None:
    result = enbarr('bench', '--profile', 'saucer_sim', '--record', '--warmup', '5',
                    '--seconds', '2', timeout=240)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, result.stdout
    r = json.loads(lines[0])
    for run in (r, r['unrecorded']):
        assert 0.0 < run['cpu_core_fraction'] < os.cpu_count()
        assert run['pi4_core_fraction_estimate'] == pytest.approx(
            6 * run['cpu_core_fraction'], abs=0.01)
        for when in ('start', 'end'):
            assert 20.0 < run[f'rss_mb_{when}_max'] <= run[f'rss_mb_{when}']
        names = {t['thread'] for t in run['threads']}
        assert 'executor' in names and 'simulator_loop' in names, names
        assert run['vessel_cpu_core_fraction'] is None   # simulated devices: not separable
        assert run['bringup_exit'] == 0
        assert run['warmup_s'] >= 5.0
    assert 'recorder_writer' in {t['thread'] for t in r['threads']}
    assert 0 < r['recorded_messages'] <= r['recorded_messages_run']
    assert r['recorded_messages_per_second'] > 50.0   # mocap 50 Hz alone, and more
    assert r['writer_cpu_us_per_recorded_message'] > 0.0
    assert isinstance(r['cpu_us_per_recorded_message'], float)
    assert r['machine']


@pytest.mark.e2e
@pytest.mark.alone   # two vessels at once, and its second domain is the next one: no worker beside
def test_bench_against_a_baseline_runs_pairs_at_once() -> None:
    base = Path(__file__).resolve().parents[2] / 'params/bench/saucer_ca_sim_baseline.yaml'
    result = enbarr('bench', '--profile', 'saucer_ca_sim', '--against', str(base),
                    '--pairs', '1', '--warmup', '5', '--seconds', '2', timeout=240)
    assert result.returncode == 0, result.stderr
    r = json.loads(result.stdout)
    assert (r['profile'], r['against']) == ('saucer_ca_sim', 'saucer_ca_sim_baseline')
    (run,) = r['runs']
    assert 0.0 < run['against'] and 0.0 < run['profile']
    d = run['difference']
    assert d['cpu_core_fraction'] == pytest.approx(run['profile'] - run['against'], abs=2e-4)
    # Every thread, the perception's (executor) and the simulator's included; they add up to
    # the whole. (What share each has is not pinned: two seconds of a run are too few.)
    threads = {k: v for k, v in d.items() if k != 'cpu_core_fraction'}
    assert {'executor', 'simulator_loop'} <= threads.keys(), d
    assert sum(threads.values()) == pytest.approx(d['cpu_core_fraction'],
                                                  abs=5e-5 * (len(threads) + 1)), d
    assert r['difference']['pairs'] == 1
    assert r['difference']['mean'] == d['cpu_core_fraction']


SPLIT_PROFILE = split_profile()


@pytest.mark.e2e
def test_bench_profile_splits_by_process(tmp_path: Path) -> None:
    profile = tmp_path / 'split.yaml'
    profile.write_text(SPLIT_PROFILE)
    result = enbarr('bench', '--profile', str(profile), '--warmup', '6', '--seconds', '2',
                    timeout=240)
    assert result.returncode == 0, result.stderr
    r = json.loads(result.stdout)
    groups = sorted(p for p in r['processes'] if p.startswith('group '))
    assert 'bringup' in r['processes'] and 'group control' in groups and len(groups) == 2
    assert sum(r['processes'].values()) == pytest.approx(r['cpu_core_fraction'], abs=0.002)
    placed = {(t['process'], t['thread']) for t in r['threads']}
    other = next(g for g in groups if g != 'group control')
    assert (other, 'simulator_loop') in placed, placed   # named in a supervised child too


@pytest.mark.e2e
def test_bench_idle_measures_the_composed_profile_with_nothing_flowing() -> None:
    result = enbarr('bench', '--profile', 'saucer_sim', '--idle', '--seconds', '1', timeout=120)
    assert result.returncode == 0, result.stderr
    (line,) = result.stdout.strip().splitlines()
    r = json.loads(line)
    assert r['profile'] == 'saucer_sim' and r['idle'] is True and r['nodes'] >= 8
    assert 0.0 < r['cpu_core_fraction'] < os.cpu_count()
    assert r['pi4_core_fraction_estimate'] == pytest.approx(6 * r['cpu_core_fraction'], abs=1e-3)
