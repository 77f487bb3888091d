"""The ``enbarr`` command line, run as a user runs it: a separate process.

Every error a user can cause ends as one line ``enbarr bringup: error: ...`` on stderr and
exit code 2, never a traceback. ``--check`` builds every node (in its own rclpy context), so
parameter names, values, types and the thruster geometry are all checked here.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from enbarr_core.bringup.profile import resolve_profile
from support.cli import enbarr, refused

# where the bare name resolves (the source tree here, share/enbarr/params when installed)
SIM = str(resolve_profile('enbarr_sim'))

pytestmark = pytest.mark.e2e  # the command line, in processes


def write(path: Path, text: str) -> str:
    path.write_text(textwrap.dedent(text).lstrip('\n'), encoding='utf-8')
    return str(path)


def test_check_enbarr_sim_ok(tmp_path: Path) -> None:
    r = enbarr('bringup', '--profile', 'enbarr_sim', '--check', cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f'{SIM}: ok (17 nodes in 1 group(s))'
    assert 'Traceback' not in r.stderr


def test_check_with_set_override(tmp_path: Path) -> None:
    r = enbarr('bringup', '--profile', SIM, '--check', '--set',
               'control_loop.kp=[1,2,3,4,5,6]', '--set', 'imu.gyro_noise=0.01', cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.rstrip().endswith(': ok (17 nodes in 1 group(s))')


def test_bad_profile_file_one_line_error(tmp_path: Path) -> None:
    path = write(tmp_path / 'bad.yaml', """
        include: [enbarr_sim]
        nodes:
          imu: {plugin: sim_imu, rate: 100.0}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert line == (f'enbarr bringup: error: {path}: nodes.imu.rate: unknown key; expected one '
                    'of: plugin, namespace, remappings, parameters, group, enabled')


def test_invalid_yaml_one_line_error(tmp_path: Path) -> None:
    path = write(tmp_path / 'broken.yaml', 'nodes:\n  imu: [plugin: sim_imu\n')
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert line.startswith(f'enbarr bringup: error: {path}: line ')
    assert 'invalid YAML' in line


def test_bad_set_value_one_line_error(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'enbarr_sim', '--check', '--set',
                          'control_loop.kp=[1, 2', cwd=tmp_path))
    assert line.startswith("enbarr bringup: error: --set 'control_loop.kp=[1, 2': value is "
                           'not valid YAML')


def test_unknown_parameter_name_suggests_close_match(tmp_path: Path) -> None:
    path = write(tmp_path / 'typo.yaml', """
        include: [enbarr_sim]
        nodes:
          control_loop:
            parameters: {kpp: [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert line.startswith(
        f"enbarr bringup: error: {path}: nodes.control_loop.parameters.kpp: node "
        "'control_loop' (velocity_control) has no parameter 'kpp' (did you mean 'kp'?); "
        'it has: ')
    assert 'level_gain' in line and 'vehicle.mass' in line


def test_unknown_parameter_in_included_file_names_that_file(tmp_path: Path) -> None:
    """Origin tracking: the typo is in the included file, the error names it."""
    base = write(tmp_path / 'base.yaml', """
        include: [enbarr_sim]
        nodes:
          imu:
            parameters: {gyro_bais: [0.0, 0.0, 0.0]}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        nodes:
          imu:
            parameters: {gyro_noise: 0.01}
        """)
    line = refused(enbarr('bringup', '--profile', child, '--check', cwd=tmp_path))
    assert line.startswith(
        f"enbarr bringup: error: {base}: nodes.imu.parameters.gyro_bais: node 'imu' (sim_imu) "
        "has no parameter 'gyro_bais' (did you mean 'gyro_bias'?)")


def test_unknown_common_parameter(tmp_path: Path) -> None:
    path = write(tmp_path / 'common.yaml', """
        include: [enbarr_sim]
        parameters:
          vehicle: {masss: 12.0}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert line == (f'enbarr bringup: error: {path}: parameters.vehicle.masss: no node '
                    "declares the common parameter 'vehicle.masss'")


@pytest.mark.parametrize('node,param,value,expected', [
    # Before: rclpy's words, 'Invalid parameter value (-1.0) for parameter. Reason: ...'.
    ('control_loop', 'level_gain', '-1.0', 'level_gain = -1.0 is outside [0.0, 100.0]'),
    ('imu', 'gyro_noise', '-1', 'gyro_noise = -1.0 is outside [0.0, 1.0]'),
    ('control_loop', 'kp', '[1.0, 1.0, -1.0, 1.0, 1.0, 1.0]',
     'kp[2] = -1.0 is outside [0.0, 10000.0]'),
])
def test_out_of_range_value(tmp_path: Path, node: str, param: str, value: str,
                            expected: str) -> None:
    path = write(tmp_path / 'range.yaml', f"""
        include: [enbarr_sim]
        nodes:
          {node}:
            parameters: {{{param}: {value}}}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    # The file and key that set the value, not the file that named the plugin.
    assert line.startswith(f'enbarr bringup: error: {path}: nodes.{node}.parameters.{param}: '
                           f'node {node!r}: parameter ')
    assert expected in line and 'Invalid parameter value' not in line


def test_wrong_type_names_expected_type(tmp_path: Path) -> None:
    path = write(tmp_path / 'type.yaml', """
        include: [enbarr_sim]
        nodes:
          control_loop:
            parameters: {level_gain: fast}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert line == (f'enbarr bringup: error: {path}: nodes.control_loop.parameters.level_gain: '
                    "node 'control_loop': parameter 'level_gain': expected a float, got "
                    "'fast'")


def test_wrong_type_via_set(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'enbarr_sim', '--check', '--set',
                          'control_loop.kp=[a, b, c, d, e, f]', cwd=tmp_path))
    assert "--set: nodes.control_loop.parameters.kp: node 'control_loop': parameter 'kp': " \
        "expected a list of floats, got ['a', 'b', 'c', 'd', 'e', 'f']" in line


def test_thruster_layout_that_cannot_yaw(tmp_path: Path) -> None:
    """Every horizontal thruster moved to the centre: surge and sway remain, yaw is gone."""
    path = write(tmp_path / 'noyaw.yaml', """
        include: [enbarr_sim]
        parameters:
          thrusters:
            front_right: {position: [0.0, 0.0, 0.0]}
            front_left: {position: [0.0, 0.0, 0.0]}
            rear_right: {position: [0.0, 0.0, 0.0]}
            rear_left: {position: [0.0, 0.0, 0.0]}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert f"{path}: parameters.thrusters.front_right.position: node 'thruster_converter': " \
        'thruster layout' in line  # the user's file, not core.yaml that named the plugin
    assert 'cannot produce yaw' in line
    assert 'sway' not in line.split('cannot produce')[1].split('(')[0]


def test_negative_duration(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'enbarr_sim', '--duration', '-1',
                          cwd=tmp_path))
    assert line == ('enbarr bringup: error: --duration must be a positive finite number of '
                    'seconds, got -1.0')


def test_profile_not_found_lists_installed(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'enbarr_simm', '--check', cwd=tmp_path))
    assert "profile 'enbarr_simm' not found (did you mean 'enbarr_sim'?)" in line
    installed = line.split('installed profiles: ')[1].split(', ')
    assert 'enbarr_sim' in installed and 'core' not in installed


def test_a_fragment_is_refused(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'core', '--check', cwd=tmp_path))
    assert line == (f'enbarr bringup: error: {Path(SIM).parent / "core.yaml"}: a fragment, only '
                    'for include: [core] in a vessel profile; run one that includes it (enbarr '
                    'list profiles)')


@pytest.fixture(scope='module')
def listed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The output of ``enbarr list`` and of ``list WHAT`` for each section, run once."""
    cwd = tmp_path_factory.mktemp('list')
    out = {}
    for what in ('', 'nodes', 'profiles', 'scenarios', 'commands'):
        r = enbarr('list', *([what] if what else []), cwd=cwd)
        assert r.returncode == 0, r.stderr
        assert r.stderr == ''
        out[what] = r.stdout
    return out


def rows(text: str) -> dict[str, str]:
    """The ``  name  text`` rows of a listing, by name."""
    return {line.split()[0]: line.split(None, 1)[1] if len(line.split()) > 1 else ''
            for line in text.splitlines() if line.startswith('  ')}


def sections(text: str) -> dict[str, list[str]]:
    """The names listed under each section heading (a line that does not start with spaces)."""
    out: dict[str, list[str]] = {}
    heading = ''
    for line in text.splitlines():
        if line and not line.startswith(' '):
            heading = line.split(' (')[0]
            out[heading] = []
        elif line.strip():
            out[heading].append(line.split()[0])
    return out


def test_list_nodes_names_every_builtin(listed: dict[str, str]) -> None:
    names = list(rows(listed['nodes']))
    for name in ('attitude_filter', 'command_receiver', 'velocity_control',
                 'thruster_converter', 'rov_simulator', 'scripted_commands', 'recorder',
                 'sim_imu', 'sim_thrusters', 'sim_stepper', 'sim_gpio'):
        assert name in names


def test_list_nodes_is_sorted(listed: dict[str, str]) -> None:
    names = list(rows(listed['nodes']))
    assert names == sorted(names)


def test_list_nodes_shows_target_and_origin(listed: dict[str, str]) -> None:
    assert rows(listed['nodes'])['sim_imu'] == 'enbarr_plugins.imu.sim:SimImuNode  (builtin)'


def test_list_profiles_separates_fragments_and_describes_each(listed: dict[str, str]) -> None:
    # Before: one list of file paths, fragments (core, saucer_core) among runnable profiles.
    found = sections(listed['profiles'])
    assert list(found) == ['Profiles', 'Fragments']
    assert {'enbarr_sim', 'saucer_sim', 'skiff_sim', 'enbarr_rov'} <= set(found['Profiles'])
    assert found['Fragments'] == ['core', 'saucer_ca_core', 'saucer_core', 'skiff_core']
    described = rows(listed['profiles'])
    assert described['enbarr_sim'] == ('Enbarr ROV, everything simulated, scripted surface '
                                       'commands.')
    assert described['core'] == 'Core nodes of an Enbarr ROV (no plugins).'
    assert all(described.values())


def test_list_scenarios_names_every_shipped_scenario(listed: dict[str, str]) -> None:
    shipped = sorted(p.stem for p in (Path(__file__).parents[2] / 'params' / 'scenarios')
                     .glob('*.yaml'))
    described = rows(listed['scenarios'])
    assert sorted(described) == shipped and all(described.values())


def test_list_commands_names_every_command(listed: dict[str, str]) -> None:
    commands = rows(listed['commands'])
    assert list(commands) == ['bringup', 'list', 'scenario', 'chaos', 'bench', 'check-device',
                              'bag', 'calibrate', 'param']
    assert commands['bringup'] == 'run a vessel profile  (builtin)'


def test_list_alone_lists_every_section(listed: dict[str, str]) -> None:
    # Before: 'the following arguments are required: what'.
    assert list(sections(listed[''])) == ['Profiles', 'Fragments', 'Scenarios', 'Nodes',
                                          'Commands']
    assert listed[''] == '\n\n'.join(listed[w].rstrip('\n') for w in (
        'profiles', 'scenarios', 'nodes', 'commands')) + '\n'


def test_list_help_explains_each_section(tmp_path: Path) -> None:
    r = enbarr('list', '--help', cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    for what in ('profiles', 'scenarios', 'nodes', 'commands', 'include-only'):
        assert what in r.stdout


@pytest.fixture(scope='module')
def bringup_help(tmp_path_factory: pytest.TempPathFactory) -> str:
    r = enbarr('bringup', '--help', cwd=tmp_path_factory.mktemp('help'))
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_bringup_help_lists_the_options(bringup_help: str) -> None:
    for option in ('--profile', '--duration', '--output', '--record-topic', '--set', '--check',
                   '--only-group', '--skip-group'):
        assert option in bringup_help


def test_bringup_help_hides_internal_and_old_options(bringup_help: str) -> None:
    assert '--group' not in bringup_help  # internal: the supervisor's children
    assert '--record ' not in bringup_help and '--record DIR' not in bringup_help  # old


def test_scenario_help_lists_every_shipped_scenario(tmp_path: Path) -> None:
    r = enbarr('scenario', '--help', cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    text = ' '.join(r.stdout.split())  # the description is wrapped
    shipped = sorted(p.stem for p in (Path(__file__).parents[2] / 'params' / 'scenarios')
                     .glob('*.yaml'))
    assert 'skiff_station_keeping' in shipped
    assert (f'Scenarios (params/scenarios/; enbarr list scenarios describes them): '
            f'{", ".join(shipped)}.') in text


def test_bringup_requires_profile(tmp_path: Path) -> None:
    r = enbarr('bringup', '--check', cwd=tmp_path)
    assert r.returncode == 2
    assert 'the following arguments are required: --profile' in r.stderr


def test_out_of_range_vector_element_names_the_index(tmp_path: Path) -> None:
    """Vector parameters without a natural bound still get one: a CG 1 km away is a typo."""
    path = write(tmp_path / 'cg.yaml', """
        include: [enbarr_sim]
        nodes:
          simulator:
            parameters: {vehicle: {r_g: [0.0, 0.0, -1000.0]}}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert f'{path}: nodes.simulator.parameters.vehicle.r_g: ' in line
    assert 'vehicle.r_g[2] = -1000.0 is outside [-100.0, 100.0]' in line


# -- an error names where the faulty values came from -----------------------------------------
CENTRED_AZIMUTHS = """
    include: [saucer_sim]
    parameters:
      azimuths:
        az_bow: {position: [0.0, 0.0]}
        az_port_aft: {position: [0.0, 0.0]}
        az_stbd_aft: {position: [0.0, 0.0]}
    """


def test_cross_check_error_names_the_users_file(tmp_path: Path) -> None:
    # A layout that cannot yaw is refused (exit 2, one line, no traceback), naming the user's
    # file. Before the fix: 'saucer_core.yaml: parameters.azimuth_names: ... cannot produce yaw',
    # the included file, which the user never touched.
    path = write(tmp_path / 'centred.yaml', CENTRED_AZIMUTHS)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert 'cannot produce yaw' in line and 'azimuth' in line
    assert f'{path}: parameters.azimuths.az_bow.position' in line, line


def test_cross_check_error_names_set(tmp_path: Path) -> None:
    sets = [a for n in ('az_bow', 'az_port_aft', 'az_stbd_aft')
            for a in ('--set', f'allocation.azimuths.{n}.position=[0.0, 0.0]')]
    line = refused(enbarr('bringup', '--profile', 'saucer_sim', '--check', *sets,
                          cwd=tmp_path))
    assert 'cannot produce yaw' in line
    assert '--set: nodes.allocation.parameters.azimuths.az_bow.position' in line, line


def test_error_about_a_member_field_names_the_users_file(tmp_path: Path) -> None:
    # The allocation checks 'angle_min < angle_max' of one azimuth (parameter 'angle_max').
    path = write(tmp_path / 'angles.yaml', """
        include: [saucer_sim]
        parameters:
          azimuths:
            az_bow: {angle_min: 1.0, angle_max: 0.5}
        """)
    line = refused(enbarr('bringup', '--profile', path, '--check', cwd=tmp_path))
    assert f'{path}: parameters.azimuths.az_bow.angle_' in line, line


def test_skip_group_checks_the_vessels_part_of_a_split_profile(tmp_path: Path) -> None:
    r = enbarr('bringup', '--profile', 'saucer_fusion_split_sim', '--skip-group', 'operator',
               '--check', cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].endswith(': ok (13 nodes in 1 group(s))')


def test_only_group_checks_the_operators_part_of_a_split_profile(tmp_path: Path) -> None:
    r = enbarr('bringup', '--profile', 'saucer_fusion_split_sim', '--only-group', 'operator',
               '--check', cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].endswith(': ok (2 nodes in 1 group(s))')


def test_an_unknown_group_is_one_line_naming_the_groups(tmp_path: Path) -> None:
    line = refused(enbarr('bringup', '--profile', 'saucer_fusion_split_sim', '--skip-group',
                          'topside', '--check', cwd=tmp_path))
    assert line.endswith("--skip-group 'topside': no such group; the groups of the profile "
                         'are main, operator')


def test_only_and_skip_group_together_are_refused(tmp_path: Path) -> None:
    r = enbarr('bringup', '--profile', 'enbarr_sim', '--only-group', 'main', '--skip-group',
               'main', cwd=tmp_path)
    assert r.returncode == 2 and 'not allowed with argument' in r.stderr
