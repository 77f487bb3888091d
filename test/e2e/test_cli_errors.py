"""Hostile command lines of ``bringup``, ``scenario`` and ``bench``.

Every one must end in one clear line ``enbarr COMMAND: error: ...`` and exit code 2, never a
traceback. One test per class of failure found by trying them; the comment says what each
did before the fix.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from support.cli import enbarr, refused


@pytest.fixture
def a_file(tmp_path: Path) -> Path:
    f = tmp_path / 'a_file'
    f.write_text('x')
    return f


@pytest.mark.parametrize('command', [
    ['bringup', '--profile', 'enbarr_sim'],
    ['scenario', 'station_keeping'],
])
@pytest.mark.parametrize('value', ['inf', '-inf', 'nan', '-1', '0'])
def test_duration_must_be_positive_and_finite(tmp_path: Path, command: list[str],
                                              value: str) -> None:
    # Before: bringup --duration inf ran forever; scenario --duration inf: OverflowError.
    line = refused(enbarr(*command, f'--duration={value}', cwd=tmp_path), command[0])
    assert '--duration' in line and 'finite' in line, line


@pytest.mark.parametrize('where', ['file', 'under_file', 'proc'])
def test_scenario_output_that_cannot_be_a_directory(tmp_path: Path, a_file: Path,
                                                    where: str) -> None:
    # Before: NotADirectoryError / FileNotFoundError tracebacks.
    out = {'file': a_file, 'under_file': a_file / 'sub', 'proc': Path('/proc/enbarr/x')}[where]
    line = refused(enbarr('scenario', 'station_keeping', '--output', str(out), '--no-plot',
                          cwd=tmp_path), 'scenario')
    assert '--output' in line and str(out) in line, line


@pytest.mark.parametrize('where', ['file', 'under_file', 'proc'])
def test_bringup_output_that_cannot_be_a_directory(tmp_path: Path, a_file: Path,
                                                   where: str) -> None:
    # Before: the message blamed 'enbarr_sim.yaml: parameters.thruster_names'.
    out = {'file': a_file, 'under_file': a_file / 'sub', 'proc': Path('/proc/enbarr/x')}[where]
    line = refused(enbarr('bringup', '--profile', 'enbarr_sim', '--duration', '1',
                          '--output', str(out), cwd=tmp_path))
    assert 'error: --output: ' in line and str(out) in line, line
    assert 'thruster_names' not in line


def test_bad_record_topic_is_refused(tmp_path: Path) -> None:
    # Before: accepted; the run recorded nothing of it and exited 0.
    line = refused(enbarr('bringup', '--profile', 'enbarr_sim', '--duration', '1',
                          '--output', str(tmp_path / 'bag'), '--record-topic', 'bad topic!',
                          cwd=tmp_path))
    assert '--record-topic' in line and "'bad topic!'" in line, line
    assert not (tmp_path / 'bag').exists()


def test_old_record_spelling_works_with_one_notice(tmp_path: Path, a_file: Path) -> None:
    # --record DIR is --output DIR now: the same run (here refused the same way), one notice.
    r = enbarr('bringup', '--profile', 'enbarr_sim', '--duration', '1', '--record',
               str(a_file), cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 2, r.stderr
    assert lines[0] == 'enbarr bringup: warning: --record is deprecated; use --output'
    assert lines[1].startswith('enbarr bringup: error: --output: ') and str(a_file) in lines[1]


@pytest.mark.parametrize('command', [
    ['bringup', '--profile', 'enbarr_sim'],
    ['scenario', 'box_path'],
    ['chaos', '--profile', 'enbarr_sim'],
])
def test_a_duration_too_long_to_wait_is_refused(tmp_path: Path, command: list[str]) -> None:
    # Before: scenario --duration 1e308 ended in an OverflowError traceback.
    line = refused(enbarr(*command, '--duration', '1e308', cwd=tmp_path), command[0])
    assert '--duration must be at most' in line and 'got 1e+308' in line, line


def test_a_scenario_duration_too_long_in_the_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / 'long.yaml'
    path.write_text('include: [box_path.yaml]\nscenario: {duration: 1e308}\n')
    (tmp_path / 'box_path.yaml').write_text(
        (Path(__file__).parents[2] / 'params' / 'scenarios' / 'box_path.yaml').read_text()
        .replace('../saucer_sim.yaml', 'saucer_sim'))
    line = refused(enbarr('scenario', str(path), cwd=tmp_path), 'scenario')
    assert 'scenario.duration: must be > 0 and at most' in line, line


def test_check_device_timeout_too_long_is_refused(tmp_path: Path) -> None:
    line = refused(enbarr('check-device', 'pca9685', '--bus', 'emulated', '--timeout',
                          '1e308', cwd=tmp_path), 'check-device')
    assert '--timeout must be at most 3600 s' in line, line


@pytest.mark.parametrize('value', ['inf', 'nan', '1e9'])
def test_bench_rate_out_of_reach(tmp_path: Path, value: str) -> None:
    # Before: 'inf' and '1e9' were blamed on an internal '--set: nodes.simulator...'.
    line = refused(enbarr('bench', '--rate', value, '--seconds', '1', cwd=tmp_path), 'bench')
    assert '--rate' in line and '--set' not in line, line


def test_bench_seconds_must_be_finite(tmp_path: Path) -> None:
    line = refused(enbarr('bench', '--seconds', 'inf', cwd=tmp_path), 'bench')
    assert '--seconds' in line


@pytest.mark.parametrize('command', [['bringup', '--check', '--profile'], ['scenario']])
def test_a_directory_or_missing_file_as_profile(tmp_path: Path, command: list[str]) -> None:
    (tmp_path / 'dir.yaml').mkdir()
    for ref in (str(tmp_path / 'dir.yaml'), str(tmp_path / 'missing.yaml')):
        line = refused(enbarr(*command, ref, cwd=tmp_path), command[0])
        assert 'not found' in line and ref.rsplit('/', 1)[-1] in line, line


def test_scenario_of_a_vessel_profile_is_refused(tmp_path: Path) -> None:
    line = refused(enbarr('scenario', 'enbarr_sim', cwd=tmp_path), 'scenario')
    assert "no scenario 'enbarr_sim'" in line


def test_hostile_profile_gives_one_short_line(tmp_path: Path) -> None:
    # Deep nesting was a RecursionError traceback; a long value was echoed in full.
    for name, text in (('deep', 'parameters: ' + '[' * 5000 + ']' * 5000 + '\n'),
                       ('long', 'nodes: {imu: {plugin: "' + 'x' * 100_000 + '"}}\n')):
        path = tmp_path / f'{name}.yaml'
        path.write_text(text)
        for command in (['bringup', '--check', '--profile'], ['scenario']):
            line = refused(enbarr(*command, str(path), cwd=tmp_path), command[0])
            assert len(line) < 600, line[:300]


def test_not_utf8_and_binary_profiles(tmp_path: Path) -> None:
    path = tmp_path / 'binary.yaml'
    path.write_bytes(bytes(range(256)) * 4)
    line = refused(enbarr('bringup', '--check', '--profile', str(path), cwd=tmp_path))
    assert 'not UTF-8' in line and len(line) < 600


# -- profile values that used to reach ROS unchecked --------------------------------------------
@pytest.mark.parametrize('section, says', [
    # Before: passed, then the supervisor's sleep(nan) raised ValueError at the first restart.
    ('groups: {main: {restart_delay: .nan}}', 'groups.main.restart_delay: expected a number '
     'with 0 <= value <= 3600, got nan'),
    # Before: a Fast-DDS error spew (99999) or a traceback (abc), exit code 1.
    ('environment: {ROS_DOMAIN_ID: 99999}', 'environment.ROS_DOMAIN_ID: expected an integer '
     'from 0 to 232'),
    ('environment: {ROS_DOMAIN_ID: abc}', "environment.ROS_DOMAIN_ID: expected an integer "
     "from 0 to 232 (Fast-DDS maps the domain to UDP ports; higher ones do not fit), got "
     "'abc'"),
    # Before: RCLInvalidROSArgsError with a traceback.
    ("nodes: {imu: {remappings: {imu/data_raw: 'imu//x'}}}", "nodes.imu.remappings: "
     "'imu//x' is not a valid topic name to remap: topic name must not contain repeated '/'"),
    ("nodes: {imu: {remappings: {imu/data_raw: 'imu/{x}'}}}", "nodes.imu.remappings: "
     "'imu/{x}' is not a valid topic name to remap: unknown substitution: {x}"),
    ('nodes: {dp_contrl: {parameters: {kp: [1.0, 1.0, 1.0]}}}', "nodes.dp_contrl: no plugin "
     "(did you mean the node 'dp_control'?)"),
])
def test_profile_mistakes_are_one_line_before_ros_starts(tmp_path: Path, section: str,
                                                         says: str) -> None:
    base = 'saucer_sim' if 'dp_contrl' in section else 'enbarr_sim'
    path = tmp_path / 'p.yaml'
    path.write_text(f'include: [{base}]\n{section}\n')
    line = refused(enbarr('bringup', '--profile', str(path), '--check', cwd=tmp_path))
    assert line.startswith(f'enbarr bringup: error: {path}: {says}'), line


def test_a_set_value_with_an_exponent_is_a_number(tmp_path: Path) -> None:
    # Before: '1e1' was the string '1e1' (YAML 1.1) and refused as not a float.
    r = enbarr('bringup', '--profile', 'enbarr_sim', '--check', '--set',
               'control_loop.level_gain=1e1', cwd=tmp_path)
    assert r.returncode == 0, r.stderr
