"""Vessel profiles (enbarr_core.bringup.profile): loading, includes, overrides and error messages.

Pure: no ROS is started; profiles are written into ``tmp_path``. Every error message is
checked for the file, the key path and what was expected.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from enbarr_core.bringup import profile as profiles
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError

# where the bare name resolves (the source tree here, share/enbarr/params when installed)
SIM = str(profiles.resolve_profile('enbarr_sim'))
CORE = str(Path(SIM).parent / 'core.yaml')


def write(path: Path, text: str) -> str:
    path.write_text(textwrap.dedent(text).lstrip('\n'), encoding='utf-8')
    return str(path)


def load_error(ref: str, overrides: tuple[str, ...] = ()) -> ProfileError:
    with pytest.raises(ProfileError) as info:
        load_profile(ref, overrides)
    return info.value


# -- the shipped simulation profile -----------------------------------------------------------
@pytest.fixture(scope='module')
def sim() -> profiles.Profile:
    return load_profile('enbarr_sim')  # bare name: found among the installed profiles


def test_enbarr_sim_is_found_by_name_with_core_included(sim: profiles.Profile) -> None:
    assert sim.name == 'enbarr_sim'
    assert sim.path == SIM
    assert sim.files == (CORE, SIM)  # includes first, then the file itself


def test_enbarr_sim_nodes_and_plugins(sim: profiles.Profile) -> None:
    assert sim.node_names() == [
        'command_receiver', 'filtering', 'control_loop', 'thruster_converter', 'frames',
        'simulator', 'imu', 'thruster_control', 'thruster_monitor', 'manipulator', 'lights',
        'depth', 'leak', 'battery', 'hull', 'failsafe', 'surface']
    plugins = {n.name: n.plugin for n in sim.nodes}
    assert plugins == {
        'command_receiver': 'command_receiver', 'filtering': 'attitude_filter',
        'control_loop': 'velocity_control', 'thruster_converter': 'thruster_converter',
        'frames': 'frame_publisher', 'simulator': 'rov_simulator', 'imu': 'sim_imu',
        'thruster_control': 'sim_thrusters', 'thruster_monitor': 'thruster_monitor',
        'manipulator': 'sim_stepper', 'lights': 'sim_gpio', 'depth': 'sim_depth',
        'leak': 'sim_leak', 'battery': 'sim_battery', 'hull': 'sim_hull', 'failsafe': 'failsafe',
        'surface': 'scripted_commands'}


def test_each_node_remembers_the_file_that_named_its_plugin(sim: profiles.Profile) -> None:
    assert sim.node('control_loop').origin == CORE
    assert sim.node('imu').origin == SIM


def test_common_parameters_are_flattened_to_dotted_names(sim: profiles.Profile) -> None:
    p = sim.parameters
    assert p['thrusters.front_right.position'] == [0.156, -0.111, 0.0]
    assert p['thrusters.vert_rear_left.direction'] == [0.0, 0.0, 1.0]
    assert p['thrusters.rear_left.max_reverse'] == 40.2
    assert p['vehicle.mass'] == 11.5
    assert p['vehicle.d_quad'] == [18.18, 21.66, 36.99, 1.55, 1.55, 1.55]
    assert p['thruster_names'][0] == 'front_right' and len(p['thruster_names']) == 8
    assert not any(isinstance(v, dict) for v in p.values())


def test_node_parameters_are_flattened_and_survive_the_include(sim: profiles.Profile) -> None:
    simulator = sim.node('simulator').parameters
    assert simulator['vehicle.r_g'] == [0.0, 0.0, -0.02]
    assert simulator['initial.position'] == [0.0, 0.0, -0.5]
    assert simulator['rate'] == 400.0
    assert sim.node('command_receiver').parameters['timeout'] == 0.5
    assert sim.node('lights').parameters == {'pin': 12}
    assert len(sim.node('surface').parameters['script']) == 10


def test_enbarr_sim_environment_groups_and_record(sim: profiles.Profile) -> None:
    assert sim.environment == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    assert list(sim.groups) == ['main'] and sim.group_names() == ['main']
    assert sim.record is None


def test_apply_environment_overrides_only_the_profile_keys() -> None:
    prof = load_profile(SIM)
    env: dict[str, str] = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'OTHER': 'x'}
    profiles.apply_environment(prof, env)
    assert env == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'OTHER': 'x'}


def test_a_null_environment_value_drops_the_included_profiles(tmp_path: Path) -> None:
    base = write(tmp_path / 'base.yaml', f"""
        include: [{SIM}]
        environment: {{ROS_DOMAIN_ID: 42, ROS_AUTOMATIC_DISCOVERY_RANGE: SUBNET}}
        """)
    sim = write(tmp_path / 'sim.yaml', f"""
        include: [{base}]
        environment: {{ROS_DOMAIN_ID: ~, ROS_AUTOMATIC_DISCOVERY_RANGE: LOCALHOST}}
        """)
    assert load_profile(base).environment['ROS_DOMAIN_ID'] == '42'
    prof = load_profile(sim)
    assert prof.environment == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    env = {'ROS_DOMAIN_ID': '7'}
    profiles.apply_environment(prof, env)
    assert env['ROS_DOMAIN_ID'] == '7'  # the shell's


def test_the_rov_and_its_topside_share_one_domain_and_the_emulation_keeps_its_own() -> None:
    vessel, topside = load_profile('enbarr_rov'), load_profile('enbarr_rov_topside')
    # the tether's domain, docs/deployment.md
    assert vessel.environment['ROS_DOMAIN_ID'] == topside.environment['ROS_DOMAIN_ID'] == '42'
    assert vessel.environment['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    assert topside.environment['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    for name in ('enbarr_rov_emulated', 'enbarr_sim', 'enbarr_teleop'):
        assert 'ROS_DOMAIN_ID' not in load_profile(name).environment, name


def test_with_record_switches_recording_on_in_a_copy() -> None:
    prof = load_profile(SIM)
    rec = profiles.with_record(prof, 'bags/x', ['/imu/data'])
    assert rec.record is not None
    assert (rec.record.path, rec.record.topics, rec.record.flush_seconds,
            rec.record.split_size, rec.record.split_seconds) == (
        'bags/x', ('/imu/data',), 1.0, 0.0, 0.0)
    assert prof.record is None  # the original is unchanged


def test_with_record_takes_the_split_options() -> None:
    rec = profiles.with_record(load_profile(SIM), 'bags/x', [], 50.0, 600.0)
    assert rec.record is not None
    assert (rec.record.split_size, rec.record.split_seconds) == (50.0, 600.0)
    with pytest.raises(ProfileError, match=r'--record-split-size must be a number from 0 '
                                           r'\(no split\) to 1000000, got -1.0'):
        profiles.with_record(load_profile(SIM), 'bags/x', [], -1.0)


# -- includes and overrides -------------------------------------------------------------------
@pytest.fixture
def included(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
             ) -> tuple[str, str, profiles.Profile]:
    """``child.yaml`` including ``base.yaml``: overrides a parameter, swaps a plugin and
    disables a node. Returns (base path, child path, the loaded child).
    """
    vessel = tmp_path / 'vessel'
    vessel.mkdir()
    base = write(vessel / 'base.yaml', """
        profile: base
        parameters:
          vehicle: {mass: 10.0, inertia: [0.1, 0.1, 0.1]}
        nodes:
          imu:
            plugin: sim_imu
            parameters: {gyro_noise: 0.01, gyro_bias: [0.1, 0.2, 0.3]}
          control_loop:
            plugin: velocity_control
            parameters: {level_gain: 2.0, max_gap: 0.5}
          lights:
            plugin: sim_gpio
            parameters: {pin: 12}
        """)
    child = write(vessel / 'child.yaml', """
        profile: child
        include: base.yaml          # a single string, relative to this file
        parameters:
          vehicle: {mass: 12.5}
        nodes:
          imu: {plugin: sim_stepper}
          control_loop:
            parameters: {level_gain: 3.0}
          lights: {enabled: false}
        """)
    monkeypatch.chdir(tmp_path)  # not the profile's directory: includes are file-relative
    return base, child, load_profile(child)


def test_include_is_file_relative_and_comes_first(included) -> None:
    base, child, prof = included
    assert prof.name == 'child'
    assert prof.files == (base, child)


def test_disabled_node_is_dropped(included) -> None:
    _, _, prof = included
    assert prof.node_names() == ['imu', 'control_loop']  # lights dropped


def test_plugin_swap_keeps_the_node_parameters(included) -> None:
    _, child, prof = included
    imu = prof.node('imu')
    assert imu.plugin == 'sim_stepper'  # swapped in one line ...
    assert imu.parameters == {'gyro_noise': 0.01, 'gyro_bias': [0.1, 0.2, 0.3]}  # ... rest kept
    assert imu.origin == child


def test_node_parameters_merge_key_by_key(included) -> None:
    base, _, prof = included
    control = prof.node('control_loop')
    assert control.parameters == {'level_gain': 3.0, 'max_gap': 0.5}
    assert control.origin == base


def test_common_parameters_merge_key_by_key(included) -> None:
    _, _, prof = included
    assert prof.parameters == {'vehicle.mass': 12.5, 'vehicle.inertia': [0.1, 0.1, 0.1]}


def test_where_names_the_file_that_set_each_key(included) -> None:
    base, child, prof = included
    assert prof.where('nodes.control_loop.parameters.level_gain') == child
    assert prof.where('nodes.control_loop.parameters.max_gap') == base
    assert prof.where('nodes.imu.parameters.gyro_bias') == base
    assert prof.where('parameters.vehicle.mass') == child
    assert prof.where('parameters.vehicle.inertia') == base


def test_included_profile_is_unchanged_by_being_included(included) -> None:
    base, _, _ = included
    assert load_profile(base).node_names() == ['imu', 'control_loop', 'lights']


@pytest.fixture
def grandchild(tmp_path: Path) -> tuple[str, profiles.Profile]:
    """A vessel profile including the shipped simulation by its bare name, which itself
    includes core.yaml; the grandchild overrides a core parameter.
    """
    child = write(tmp_path / 'mine.yaml', """
        include: [enbarr_sim]
        nodes:
          command_receiver:
            parameters: {timeout: 0.25}
          surface: {enabled: false}
        """)
    return child, load_profile(child)


def test_include_chain_of_installed_profiles(grandchild) -> None:
    child, prof = grandchild
    assert prof.files == (CORE, SIM, child)
    assert prof.name == 'enbarr_sim'  # not overridden: the included name stays
    assert 'surface' not in prof.node_names() and len(prof.nodes) == 16


def test_grandchild_overrides_a_core_parameter(grandchild) -> None:
    child, prof = grandchild
    assert prof.node('command_receiver').parameters == {
        'max_linear': 1.0, 'max_angular': 1.0, 'timeout': 0.25, 'max_age': 0.5}
    assert prof.where('nodes.command_receiver.parameters.timeout') == child
    assert prof.where('nodes.command_receiver.parameters.max_age') == CORE
    assert prof.where('parameters.thrusters.front_right.position') == SIM


SETS = ['control_loop.kp=[1,2,3,4,5,6]', 'imu.gyro_noise=0.5',
        'control_loop.ki=[1, 2.5, 3, 4, 5, 6]', 'lights.pin=7']


def test_set_override_applies() -> None:
    prof = load_profile(SIM, SETS)
    assert prof.node('control_loop').parameters['kp'] == [1, 2, 3, 4, 5, 6]
    assert prof.node('imu').parameters == {'gyro_noise': 0.5}
    assert prof.node('lights').parameters == {'pin': 7}


def test_set_mixed_numbers_become_floats() -> None:
    ki = load_profile(SIM, SETS).node('control_loop').parameters['ki']
    assert ki == [1.0, 2.5, 3.0, 4.0, 5.0, 6.0]
    assert all(isinstance(v, float) for v in ki)


def test_set_origin_is_reported_as_set() -> None:
    assert load_profile(SIM, SETS).where('nodes.control_loop.parameters.kp') == '--set'


def test_set_leaves_the_file_untouched() -> None:
    before = load_profile(SIM).node('control_loop').parameters['kp']
    load_profile(SIM, SETS)
    assert load_profile(SIM).node('control_loop').parameters['kp'] == before != [1, 2, 3, 4, 5, 6]


# -- errors: each names the file, the key path and what was expected ---------------------------
def test_invalid_yaml_names_line_and_column(tmp_path: Path) -> None:
    path = write(tmp_path / 'bad.yaml', """
        nodes:
          imu: {plugin: sim_imu
          other: 1
        """)
    err = load_error(path)
    assert str(err).startswith(f'{path}: line 3, column 8: invalid YAML: ')
    assert err.path == path


def test_not_utf8_is_a_profile_error(tmp_path: Path) -> None:
    path = tmp_path / 'latin1.yaml'
    path.write_bytes(b'nodes:\n  imu: {plugin: sim_imu}  # caf\xe9\n')
    err = load_error(str(path))
    assert str(err).startswith(f'{path}: not UTF-8 text')


def test_top_level_must_be_a_mapping(tmp_path: Path) -> None:
    path = write(tmp_path / 'list.yaml', '- imu\n- control\n')
    err = load_error(path)
    assert str(err) == f'{path}: expected a mapping at the top level, got a list'


def test_unknown_top_key_lists_allowed_keys(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodez:
          imu: {plugin: sim_imu}
        """)
    err = load_error(path)
    assert str(err) == (f"{path}: nodez: unknown key (did you mean 'nodes'?); expected one of: "
                        'profile, description, fragment, include, environment, parameters, '
                        'nodes, groups, record, scenario, frames, world')
    assert (err.path, err.key) == (path, 'nodez')


def test_unknown_node_key_lists_allowed_keys(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, params: {rate: 100.0}}
        """)
    err = load_error(path)
    assert str(err) == (f"{path}: nodes.imu.params: unknown key (did you mean 'parameters'?); "
                        'expected one of: plugin, namespace, remappings, parameters, group, '
                        'enabled')


def test_missing_plugin_lists_known_names(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {namespace: sensors}
        """)
    err = load_error(path)
    assert str(err).startswith(f'{path}: nodes.imu.plugin: no plugin; a new node needs one (a '
                               'registered node name, enbarr list nodes): arduino_emulator, '
                               'arduino_pwm, attitude_filter, azimuth_allocation,')
    assert 'sim_imu' in str(err)


def test_unknown_plugin_suggests_close_match(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imuu}
        """)
    err = load_error(path)
    assert str(err).startswith(
        f"{path}: nodes.imu.plugin: unknown node 'sim_imuu' (did you mean 'sim_imu'?); "
        'known nodes: ')
    for name in ('sim_imu', 'velocity_control', 'thruster_converter', 'sim_thrusters'):
        assert name in str(err)


def test_unknown_plugin_in_included_file_names_that_file(tmp_path: Path) -> None:
    base = write(tmp_path / 'base.yaml', """
        nodes:
          imu: {plugin: no_such_imu}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        nodes:
          imu: {namespace: sensors}
        """)
    err = load_error(child)
    assert str(err).startswith(f"{base}: nodes.imu.plugin: unknown node 'no_such_imu'")


def test_include_cycle_shows_the_chain(tmp_path: Path) -> None:
    a = write(tmp_path / 'a.yaml', 'include: [b.yaml]\n')
    b = write(tmp_path / 'b.yaml', 'include: [a.yaml]\nnodes: {imu: {plugin: sim_imu}}\n')
    err = load_error(a)
    assert str(err) == f'{a}: include cycle: {a} -> {b} -> {a}'


def test_include_not_found(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        include: [missing_base.yaml]
        nodes:
          imu: {plugin: sim_imu}
        """)
    err = load_error(path)
    assert str(err).startswith(f"{path}: include: profile 'missing_base.yaml' not found "
                               f'(looked in: {tmp_path}')
    assert 'installed profiles: ' in str(err) and 'enbarr_sim' in str(err)
    assert err.key == 'include'


def test_include_must_be_a_list_of_names(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', 'include: {a: 1}\n')
    assert str(load_error(path)) == (
        f'{path}: include: expected a list of profile names or paths')


def test_profile_not_found_lists_installed(tmp_path: Path) -> None:
    err = load_error('does_not_exist')
    assert "profile 'does_not_exist' not found" in str(err)
    installed = str(err).split('installed profiles: ')[1].split(', ')
    assert 'enbarr_sim' in installed and installed == sorted(installed)
    assert 'core' not in installed  # a fragment: not something to run


def test_empty_list_parameter(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu:
            plugin: sim_imu
            parameters: {gyro_bias: []}
        """)
    err = load_error(path)
    assert str(err) == (f'{path}: nodes.imu.parameters.gyro_bias: an empty list has no ROS '
                        'parameter type; leave the parameter out to keep its default')


def test_mixed_type_list_parameter(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu:
            plugin: sim_imu
            parameters: {gyro_bias: [0.1, fast, 0.3]}
        """)
    err = load_error(path)
    assert str(err) == (f'{path}: nodes.imu.parameters.gyro_bias: a list parameter holds '
                        "values of one type (numbers, strings or booleans), got "
                        "[0.1, 'fast', 0.3]")


def test_booleans_do_not_count_as_numbers_in_lists(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, parameters: {gyro_bias: [1, true, 0]}}
        """)
    assert 'a list parameter holds values of one type' in str(load_error(path))


def test_nested_bad_value_in_common_parameters(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        parameters:
          thrusters:
            front_right: {position: [0.1, {x: 1}, 0.0]}
        nodes:
          imu: {plugin: sim_imu}
        """)
    err = load_error(path)
    assert str(err).startswith(
        f'{path}: parameters.thrusters.front_right.position: a list parameter holds values')


def test_bad_nested_parameter_from_included_file_names_that_file(tmp_path: Path) -> None:
    """The bad value sits in the included file: the error names it, not the includer."""
    base = write(tmp_path / 'base.yaml', """
        nodes:
          imu:
            plugin: sim_imu
            parameters:
              gyro_bias: [0.1, 0.2, zero]
          sim:
            plugin: rov_simulator
            parameters:
              vehicle: {inertia: [], mass: 11.5}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        nodes:
          imu:
            parameters: {gyro_noise: 0.01}
        """)
    err = load_error(child)
    assert str(err).startswith(f'{base}: nodes.imu.parameters.gyro_bias: a list parameter')
    assert (err.path, err.key) == (base, 'nodes.imu.parameters.gyro_bias')


def test_bad_nested_node_parameter_from_included_file_names_its_key(tmp_path: Path) -> None:
    base = write(tmp_path / 'base.yaml', """
        nodes:
          sim:
            plugin: rov_simulator
            parameters:
              vehicle: {inertia: [], mass: 11.5}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        nodes:
          imu:
            parameters: {gyro_noise: 0.01}
        """)
    err = load_error(child)
    assert (err.path, err.key) == (base, 'nodes.sim.parameters.vehicle.inertia')
    assert 'an empty list has no ROS parameter type' in str(err)


def test_parameter_value_must_have_a_ros_type(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, parameters: {gyro_noise: null}}
        """)
    assert str(load_error(path)) == (
        f'{path}: nodes.imu.parameters.gyro_noise: expected a number, string, boolean or '
        'list of them, got nothing')


@pytest.mark.parametrize('namespace', ['bad ns', '1robot', 'a//b', 'a-b'])
def test_bad_namespace(tmp_path: Path, namespace: str) -> None:
    path = write(tmp_path / 'p.yaml', f"""
        nodes:
          imu: {{plugin: sim_imu, namespace: '{namespace}'}}
        """)
    assert str(load_error(path)) == (
        f'{path}: nodes.imu.namespace: {namespace!r} is not a valid ROS namespace')


def test_good_namespace_remapping_and_group(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu:
            plugin: sim_imu
            namespace: /rov1/sensors
            remappings: {imu/data_raw: imu0/data_raw}
            group: sensors
        groups:
          sensors: {restart_limit: 5, restart_delay: 0.5}
        """)
    imu = load_profile(path).node('imu')
    assert (imu.namespace, imu.remappings, imu.group) == (
        '/rov1/sensors', (('imu/data_raw', 'imu0/data_raw'),), 'sensors')


def test_group_settings(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, group: sensors}
        groups:
          sensors: {restart_limit: 5, restart_delay: 0.5}
        """)
    g = load_profile(path).groups['sensors']
    assert (g.restart_limit, g.restart_delay) == (5, 0.5)


def test_bad_remapping(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, remappings: {imu/data: 'bad topic'}}
        """)
    assert str(load_error(path)) == (
        f"{path}: nodes.imu.remappings: 'bad topic' is not a valid topic name to remap: topic "
        "name must not contain characters other than alphanumerics, '_', '~', '{', or '}'")


def test_group_with_no_nodes(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, group: sensors}
        groups:
          sensors: {restart_limit: 1}
          drivers: {restart_limit: 2}
        """)
    assert str(load_error(path)) == (
        f"{path}: groups.drivers: group 'drivers' has no nodes; groups in use: sensors")


def test_group_settings_are_checked(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        groups:
          main: {restart_limit: 1.5}
        """)
    assert str(load_error(path)) == (
        f'{path}: groups.main.restart_limit: expected an integer with 0 <= value <= 10000, '
        'got 1.5')


def test_record_without_path(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {topics: [/imu/data], flush_seconds: 0.5}
        """)
    err = load_error(path)
    assert str(err) == f'{path}: record.path: expected a directory path'


def test_record_section(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {path: bags/run, topics: [/imu/data], flush_seconds: 0.5, split_size: 100,
                 split_seconds: 60}
        """)
    r = load_profile(path).record
    assert r is not None and (r.path, r.topics, r.flush_seconds, r.split_size,
                              r.split_seconds) == ('bags/run', ('/imu/data',), 0.5, 100.0, 60.0)


def test_record_keeps_raw_images_only_when_asked(tmp_path: Path) -> None:
    """record.skip_raw_images (default true) reaches the recorder bringup adds."""
    from enbarr_core.bringup.compose import add_recorder
    for text, skip in (('{path: bags/run}', True), ('{path: bags/run, skip_raw_images: false}',
                                                    False)):
        path = write(tmp_path / 'p.yaml', f"""
            nodes:
              imu: {{plugin: sim_imu}}
            record: {text}
            """)
        profile = add_recorder(load_profile(path))
        assert profile.record is not None and profile.record.skip_raw_images is skip
        [recorder] = [n for n in profile.nodes if n.name == 'recorder']
        assert recorder.parameters['skip_raw_images'] is skip
    # --output on a profile without a record section: the default too
    path = write(tmp_path / 'p.yaml', 'nodes: {imu: {plugin: sim_imu}}\n')
    record = profiles.with_record(load_profile(path), str(tmp_path / 'bag')).record
    assert record is not None and record.skip_raw_images is True
    bad = write(tmp_path / 'q.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {path: bags/run, skip_raw_images: 'no'}
        """)
    assert str(load_error(bad)) == (
        f"{bad}: record.skip_raw_images: expected true or false, got 'no'")


def test_record_flush_seconds_must_be_positive(tmp_path: Path) -> None:
    bad = write(tmp_path / 'q.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {path: bags/run, flush_seconds: 0}
        """)
    assert str(load_error(bad)) == (
        f'{bad}: record.flush_seconds: expected a number with 0 < value <= 3600, got 0')


def test_record_split_must_not_be_negative(tmp_path: Path) -> None:
    bad = write(tmp_path / 'q.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {path: bags/run, split_size: -5}
        """)
    assert str(load_error(bad)) == (
        f'{bad}: record.split_size: expected a number with 0 <= value <= 1000000, got -5')


def test_record_segment_seconds_is_renamed(tmp_path: Path) -> None:
    bad = write(tmp_path / 'q.yaml', """
        nodes:
          imu: {plugin: sim_imu}
        record: {path: bags/run, segment_seconds: 1.0}
        """)
    assert str(load_error(bad)).startswith(
        f'{bad}: record.segment_seconds: renamed flush_seconds: a bag is one file now')


def test_profile_without_nodes(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, enabled: false}
        """)
    assert str(load_error(path)) == f'{path}: nodes: the profile runs no nodes'


def test_enabled_must_be_boolean(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, enabled: 'no way'}
        """)
    assert str(load_error(path)) == f'{path}: nodes.imu.enabled: expected true or false'


# -- --set errors ------------------------------------------------------------------------------
@pytest.mark.parametrize('item', ['control_loop', 'control_loop.kp', 'kp=1', '.kp=1',
                                  'control_loop.=1'])
def test_set_malformed(item: str) -> None:
    err = load_error(SIM, (item,))
    assert str(err) == (f'--set {item!r}: expected NODE.PARAM=VALUE, e.g. '
                        'velocity_control.kp=[1.0,1.0,1.0,1.0,1.0,1.0]')


def test_set_unknown_node_lists_nodes() -> None:
    err = load_error(SIM, ('controller.kp=[1,1,1,1,1,1]',))
    assert str(err).startswith("--set 'controller.kp=[1,1,1,1,1,1]': no node 'controller'; "
                               'nodes: ')
    assert 'control_loop' in str(err) and 'imu' in str(err)


def test_set_bad_yaml_value_is_one_line() -> None:
    err = load_error(SIM, ('control_loop.kp=[1, 2',))
    text = str(err)
    assert text.startswith("--set 'control_loop.kp=[1, 2': value is not valid YAML")
    assert "expected ',' or ']'" in text
    assert '\n' not in text  # the CLI prints errors as one line


def test_set_value_without_ros_type() -> None:
    err = load_error(SIM, ('control_loop.kp=[]',))
    assert str(err) == ('--set: control_loop.kp: an empty list has no ROS parameter type; '
                        'leave the parameter out to keep its default')


def test_set_value_of_mixed_types() -> None:
    err = load_error(SIM, ('control_loop.kp=[1, a]',))
    assert 'a list parameter holds values of one type' in str(err)


# -- duplicate keys: refused with file and line, at any depth ----------------------------------
@pytest.mark.parametrize('text, line, key', [
    ("""
     nodes:
       imu: {plugin: sim_imu}
       imu: {plugin: sim_thrusters}
     """, 3, 'imu'),
    ("""
     profile: a
     nodes:
       imu:
         plugin: sim_imu
         parameters:
           rate: 100.0
           rate: 200.0
     """, 7, 'rate'),
    ("""
     nodes: {imu: {plugin: sim_imu}}
     nodes: {}
     """, 2, 'nodes'),
    ("""
     parameters:
       vehicle: {mass: 1.0, mass: 2.0}
     nodes: {imu: {plugin: sim_imu}}
     """, 2, 'mass'),
])
def test_duplicate_keys_are_refused_with_file_and_line(tmp_path: Path, text: str, line: int,
                                                       key: str) -> None:
    # Before the fix the last one silently won: the vehicle ran with no IMU.
    path = write(tmp_path / 'dup.yaml', text)
    err = load_error(path)
    assert str(err).startswith(f'{path}: line {line}'), str(err)
    assert f'duplicate key {key!r}' in str(err)


def test_duplicate_key_in_an_included_file_names_that_file(tmp_path: Path) -> None:
    inc = write(tmp_path / 'inc.yaml', """
        nodes:
          imu: {plugin: sim_imu}
          imu: {plugin: sim_imu}
        """)
    path = write(tmp_path / 'top.yaml', 'include: [inc.yaml]\n')
    assert str(load_error(path)).startswith(f'{inc}: line 3')


def test_yaml_merge_keys_are_not_duplicates(tmp_path: Path) -> None:
    path = write(tmp_path / 'merge.yaml', """
        nodes:
          imu: &imu {plugin: sim_imu, parameters: {rate: 100.0}}
          imu2:
            <<: *imu
            parameters: {rate: 200.0}
        """)
    assert load_profile(path).node('imu2').parameters == {'rate': 200.0}


def test_duplicate_key_in_a_set_value_is_refused() -> None:
    err = load_error(SIM, ('imu.gyro={a: 1, a: 2}',))
    assert "duplicate key 'a'" in str(err) and '--set' in str(err)


# -- untrusted files: bounded memory and output -----------------------------------------------
BOMB = '\n'.join(['parameters:', '  p:', '  - &a [x, x, x, x, x, x, x, x, x, x]']
                 + [f'  - &{chr(98 + i)} [{", ".join(["*" + chr(97 + i)] * 10)}]'
                    for i in range(8)]
                 + ['nodes: {imu: {plugin: sim_imu}}'])


def test_alias_bomb_is_refused(tmp_path: Path) -> None:
    # 10^9 strings once expanded; before the fix the flattening walked them all.
    path = write(tmp_path / 'bomb.yaml', BOMB)
    err = load_error(path)
    assert 'expands to more than' in str(err) and str(err).startswith(path), str(err)


def test_a_few_aliases_are_fine(tmp_path: Path) -> None:
    path = write(tmp_path / 'alias.yaml', """
        nodes:
          imu: {plugin: sim_imu, parameters: {rate: &r 100.0}}
          imu2: {plugin: sim_imu, parameters: {rate: *r}}
        """)
    assert load_profile(path).node('imu2').parameters == {'rate': 100.0}


def test_huge_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / 'huge.yaml'
    with path.open('w') as f:
        f.write('nodes: {imu: {plugin: sim_imu}}\n')
        f.write('#' * (profiles.MAX_FILE_BYTES + 10) + '\n')
    err = load_error(str(path))
    assert 'too large' in str(err) and str(err).startswith(str(path))


@pytest.mark.parametrize('depth', [100, 5000])
def test_deep_nesting_is_refused_without_a_traceback(tmp_path: Path, depth: int) -> None:
    # Before the fix 5000 levels raised RecursionError (a traceback).
    path = write(tmp_path / 'deep.yaml', 'parameters: ' + '[' * depth + ']' * depth + '\n')
    err = load_error(path)
    assert 'nested deeper than' in str(err) and 'line 1' in str(err), str(err)


def test_deep_mapping_nesting_is_refused(tmp_path: Path) -> None:
    text = 'parameters:\n' + ''.join('  ' * (i + 1) + f'k{i}:\n' for i in range(80)) + \
        '  ' * 81 + 'v: 1\n'
    err = load_error(write(tmp_path / 'deep.yaml', text))
    assert 'nested deeper than' in str(err)


def test_very_long_key_is_refused_and_not_echoed(tmp_path: Path) -> None:
    path = write(tmp_path / 'long.yaml', 'nodes:\n  ' + 'k' * 1000 + ': {plugin: sim_imu}\n')
    err = load_error(path)  # YAML itself refuses implicit keys past 1024 characters
    assert 'longer than' in str(err) and len(str(err)) < 1000, str(err)[:300]


def test_very_long_value_is_refused_and_not_echoed(tmp_path: Path) -> None:
    path = write(tmp_path / 'long.yaml',
                 'nodes:\n  imu: {plugin: "' + 'x' * 200_000 + '"}\n')
    err = load_error(path)
    assert 'longer than' in str(err) and len(str(err)) < 1000, str(err)[:300]


def test_huge_list_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path / 'list.yaml', 'nodes: {imu: {plugin: sim_imu, parameters: {p: ['
                 + ', '.join(['1'] * 5000) + ']}}}\n')
    err = load_error(path)
    assert 'more than' in str(err) and 'items' in str(err) and len(str(err)) < 1000


def test_bad_value_messages_are_bounded(tmp_path: Path) -> None:
    # A list of mixed types near the limits is echoed in the message: cut short.
    values = ', '.join(['1', '"a"'] * 2000)
    path = write(tmp_path / 'mixed.yaml',
                 'nodes: {imu: {plugin: sim_imu, parameters: {p: [' + values + ']}}}\n')
    err = load_error(path)
    assert 'one type' in str(err) and len(str(err)) < profiles.MAX_MESSAGE + 200


def test_alias_bomb_in_a_set_value_is_refused() -> None:
    value = '[' + ', '.join(['&a [x, x, x, x, x, x, x, x, x, x]'] + ['*a'] * 9) + ']'
    err = load_error(SIM, (f'imu.p={value}',))  # small; only checks the loader is the same
    assert '--set' in str(err)


def test_set_value_too_long_is_refused() -> None:
    err = load_error(SIM, ('imu.p=' + 'x' * 100_000,))
    assert 'longer than' in str(err) and len(str(err)) < 1000


# -- every number finite and in range -------------------------------------------------------
NODE = 'nodes:\n  imu: {plugin: sim_imu}\n'


@pytest.mark.parametrize('section, value, says', [
    # .nan passed 'v < 0' and crashed the supervisor on the first restart (sleep(nan)).
    ('groups: {main: {restart_delay: .nan}}', '.nan', 'groups.main.restart_delay: expected a '
     'number with 0 <= value <= 3600, got nan'),
    ('groups: {main: {restart_delay: .inf}}', '.inf', 'groups.main.restart_delay: expected a '
     'number with 0 <= value <= 3600, got inf'),
    ('groups: {main: {restart_delay: 1e308}}', '1e308', 'groups.main.restart_delay: '),
    ('groups: {main: {restart_limit: 100001}}', '', 'groups.main.restart_limit: expected an '
     'integer with 0 <= value <= 10000, got 100001'),
    ('record: {path: b, flush_seconds: .nan}', '', 'record.flush_seconds: expected a number '
     'with 0 < value <= 3600, got nan'),
    ('record: {path: b, split_size: .inf}', '', 'record.split_size: expected a number with '
     '0 <= value <= 1000000, got inf'),
    ('record: {path: b, split_seconds: -.inf}', '', 'record.split_seconds: expected a number '
     'with 0 <= value <= 1000000, got -inf'),
])
def test_profile_numbers_must_be_finite_and_in_range(tmp_path: Path, section: str, value: str,
                                                     says: str) -> None:
    path = write(tmp_path / 'p.yaml', NODE + section + '\n')
    assert str(load_error(path)).startswith(f'{path}: {says}')


@pytest.mark.parametrize('value, says', [
    ('.nan', 'expected a finite number, got nan'),
    ('-.inf', 'expected a finite number, got -inf'),
    ('1e400', 'expected a finite number, got inf'),  # overflows to inf as it is read
    ('[1.0, .nan]', 'element [1]: expected a finite number, got nan'),
    ('9223372036854775808', '9223372036854775808 does not fit a 64-bit ROS integer'),
    ('[1, -9223372036854775809]', 'element [1]: -9223372036854775809 does not fit'),
])
def test_parameter_numbers_must_be_finite_and_fit(tmp_path: Path, value: str, says: str) -> None:
    path = write(tmp_path / 'p.yaml', NODE.replace('sim_imu}', 'sim_imu, parameters: {rate: '
                                                   + value + '}}'))
    assert str(load_error(path)).startswith(f'{path}: nodes.imu.parameters.rate: {says}')
    err = load_error(SIM, (f'imu.rate={value}',))
    assert str(err).startswith(f'--set: imu.rate: {says}')


def test_largest_ros_integers_are_accepted(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', NODE.replace(
        'sim_imu}', 'sim_imu, parameters: {a: 9223372036854775807, b: -9223372036854775808}}'))
    assert load_profile(path).node('imu').parameters == {'a': (1 << 63) - 1, 'b': -(1 << 63)}


# -- YAML 1.2 numbers ---------------------------------------------------------------------------
@pytest.mark.parametrize('text, value', [
    ('1e9', 1e9),              # YAML 1.1 (PyYAML) read this as the string '1e9'
    ('[1e3, 2]', [1000.0, 2.0]),
    ('-2.5E-3', -0.0025),
    ('012', 12),               # decimal in 1.2, octal 10 in 1.1
    ('0x1f', 31),
    ('0o17', 15),
    ('1_000', '1_000'),        # 1000 in 1.1, a string in 1.2
    ('1:20', '1:20'),          # sexagesimal 80 in 1.1
    ('true', True),
    ('FALSE', False),
    ('off', 'off'),            # False in 1.1: ROS_AUTOMATIC_DISCOVERY_RANGE: OFF was 'False'
    ('yes', 'yes'),
])
def test_set_values_are_read_as_yaml_1_2(text: str, value: object) -> None:
    prof = load_profile(SIM, (f'control_loop.max_gap={text}',))
    got = prof.node('control_loop').parameters['max_gap']
    assert got == value and type(got) is type(value)


def test_profile_files_are_read_as_yaml_1_2(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes:
          imu: {plugin: sim_imu, parameters: {rate: 4e2, gyro_noise: [1e-3, 2e-3, 0.5]}}
        groups: {main: {restart_delay: 5e-1}}
        """)
    prof = load_profile(path)
    assert prof.node('imu').parameters == {'rate': 400.0, 'gyro_noise': [1e-3, 2e-3, 0.5]}
    assert prof.groups['main'].restart_delay == 0.5


# -- environment -----------------------------------------------------------------------------
@pytest.mark.parametrize('name, value, says', [
    # Before: 99999 ended in a Fast-DDS error spew, 'abc' in a traceback.
    ('ROS_DOMAIN_ID', '99999', 'expected an integer from 0 to 232'),
    ('ROS_DOMAIN_ID', 'abc', "expected an integer from 0 to 232 (Fast-DDS maps the domain to "
     "UDP ports; higher ones do not fit), got 'abc'"),
    ('ROS_DOMAIN_ID', '233', 'expected an integer from 0 to 232'),
    ('ROS_DOMAIN_ID', '-1', "got '-1'"),
    ('ROS_DOMAIN_ID', '4.0', "got '4.0'"),
    ('ROS_DOMAIN_ID', 'true', "got 'True'"),
    ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'localhost', "expected one of SUBNET, LOCALHOST, OFF, "
     "SYSTEM_DEFAULT (did you mean 'LOCALHOST'?), got 'localhost'"),
    ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'NETWORK', 'expected one of SUBNET, LOCALHOST, OFF'),
    ('ROS_STATIC_PEERS', '"127.0.0.1;bad host"', "expected hosts (names or IP addresses) "
     "separated by \";\", got 'bad host'"),
    ('ROS_STATIC_PEERS', '"localhost:7400"', "got 'localhost:7400'"),
    ('ROS_STATIC_PEERS', '"a;;b"', "got ''"),
    ('ANY_VARIABLE', '"a\\0b"', 'a value cannot hold a NUL character'),
    ('ANY_VARIABLE', '.nan', 'expected a finite number, got nan'),
    ('ANY_VARIABLE', '[1, 2]', 'expected a scalar, got a list'),
    ('1BAD', '1', 'an environment variable name is letters, digits and _'),
])
def test_environment_values_are_checked(tmp_path: Path, name: str, value: str,
                                        says: str) -> None:
    path = write(tmp_path / 'p.yaml', NODE + f'environment: {{{name}: {value}}}\n')
    err = load_error(path)
    assert str(err).startswith(f'{path}: environment.{name}: '), str(err)
    assert says in str(err) and err.key == f'environment.{name}'


@pytest.mark.parametrize('name, value', [
    ('ROS_DOMAIN_ID', '0'), ('ROS_DOMAIN_ID', '232'), ('ROS_DOMAIN_ID', '"42"'),
    ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET'), ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'OFF'),
    ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SYSTEM_DEFAULT'),
    ('ROS_STATIC_PEERS', '"127.0.0.1;::1;localhost;vessel-1.lan"'), ('ROS_STATIC_PEERS', '""'),
    ('OTHER', '3.5'),
])
def test_good_environment_values_pass_as_strings(tmp_path: Path, name: str,
                                                 value: str) -> None:
    path = write(tmp_path / 'p.yaml', NODE + f'environment: {{{name}: {value}}}\n')
    env = load_profile(path).environment
    assert list(env) == [name] and isinstance(env[name], str)


# -- remappings and recorded topics: ROS 2 name rules -----------------------------------------
@pytest.mark.parametrize('target', [
    # Before: each passed the profile check, then RCLInvalidROSArgsError with a traceback.
    'imu//x', 'imu/', 'a~b', 'imu/{x}',
    '{node}/x', 'a__b', '~x', '~', '1a', '', 'a.b',
])
def test_bad_remap_targets_are_refused(tmp_path: Path, target: str) -> None:
    path = write(tmp_path / 'p.yaml',
                 NODE.replace('sim_imu}', f"sim_imu, remappings: {{imu/data: '{target}'}}}}"))
    err = load_error(path)
    assert str(err).startswith(f'{path}: nodes.imu.remappings: {target!r} is not a valid topic '
                               'name to remap: '), str(err)


@pytest.mark.parametrize('name', ['imu/data', '/imu/data', '~/data', 'a/_b', 'A', 'rt/x'])
def test_good_remaps_pass(tmp_path: Path, name: str) -> None:
    path = write(tmp_path / 'p.yaml',
                 NODE.replace('sim_imu}', f"sim_imu, remappings: {{'{name}': '{name}'}}}}"))
    assert load_profile(path).node('imu').remappings == ((name, name),)


def test_recorded_topics_are_checked(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', NODE + "record: {path: b, topics: ['/imu//data']}\n")
    assert str(load_error(path)) == (f"{path}: record.topics: '/imu//data' is not a valid topic "
                                     "name: topic name must not contain repeated '/'")
    with pytest.raises(ProfileError, match="--record-topic 'imu/': not a valid topic name: "
                                           'topic name must not end with a forward slash'):
        profiles.with_record(load_profile(SIM), 'bags/x', ['imu/'])


# -- a typo in a node's name ------------------------------------------------------------------
def test_node_name_typo_suggests_the_declared_node(tmp_path: Path) -> None:
    # Before: 'every node needs a plugin ...' and the list of plugins, nothing about the typo.
    path = write(tmp_path / 'p.yaml', """
        include: [saucer_sim]
        nodes:
          dp_contrl:
            parameters: {kp: [1.0, 1.0, 1.0]}
        """)
    err = load_error(path)
    assert str(err).startswith(f"{path}: nodes.dp_contrl: no plugin (did you mean the node "
                               "'dp_control'?); a new node needs one"), str(err)


def test_top_level_typo_suggests_the_key(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', NODE + 'enviroment: {ROS_DOMAIN_ID: 3}\n')
    assert "enviroment: unknown key (did you mean 'environment'?)" in str(load_error(path))


# -- fragments (include-only) -----------------------------------------------------------------
def test_a_fragment_is_refused_to_run_and_fine_to_include() -> None:
    err = load_error('core')
    assert str(err) == (f'{CORE}: a fragment, only for include: [core] in a vessel profile; '
                        'run one that includes it (enbarr list profiles)')
    assert load_profile('core', allow_fragment=True).node_names()[0] == 'command_receiver'
    assert load_profile('enbarr_sim').files[0] == CORE  # including it is what it is for


def test_fragment_must_be_boolean(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', NODE + 'fragment: yes please\n')
    assert str(load_error(path)) == f'{path}: fragment: expected true or false'


def test_installed_profiles_tell_fragments_and_descriptions() -> None:
    listed = {p.name: p for p in profiles.installed_profiles()}
    assert {n for n, p in listed.items() if p.fragment} == {'core', 'saucer_core', 'skiff_core',
                                                            'saucer_ca_core'}
    assert listed['enbarr_sim'].description == (
        'Enbarr ROV, everything simulated, scripted surface commands.')
    assert all(p.description and p.readable for p in listed.values())
    scenarios = {p.name: p for p in profiles.installed_profiles('scenarios')}
    assert 'box_path' in scenarios and all(p.description for p in scenarios.values())


def test_an_unreadable_file_is_listed_with_its_reason(tmp_path: Path) -> None:
    bad = tmp_path / 'broken.yaml'
    bad.write_text('nodes: [\n')
    s = profiles.summarize(bad)
    assert not s.readable and s.description.startswith(f'unreadable: {bad}: line ')


# Names whose verdict rcl itself gives below: the profile check must refuse exactly those rcl
# refuses in a remap rule (either side), so that no remap reaches a node to fail there.
REMAP_NAMES = ['imu//x', 'imu/', 'a~b', 'imu/{x}', 'imu/{node}', '~/x', '~', '/a', 'a', '1a',
               'a b', '_a', '~x', '/', '//a', 'a/~/b', '{node}', '{ns}/a', 'a/_b', 'a__b',
               '/a/b/', 'A', 'a/1b', 'rt/a', 'a{', 'a}b', '~/{node}', 'a.b', '', 'a/b_c/d9']


def test_remap_check_agrees_with_rcl(context: object) -> None:
    from rclpy.node import Node
    disagree = []
    for name in REMAP_NAMES:
        for rule in (f'{name}:=x', f'x:={name}'):
            try:
                Node('n', namespace='/ns', context=context,
                     cli_args=['--ros-args', '-r', rule]).destroy_node()
                rcl_ok = True
            except Exception:  # noqa: BLE001 - rclpy's RCLInvalidROSArgsError, not public
                rcl_ok = False
            ours = profiles.topic_name_problem(name, remap=True)
            if rcl_ok != (ours is None):
                disagree.append((rule, rcl_ok, ours))
    assert not disagree


def test_huge_integers_are_refused_without_a_traceback(tmp_path: Path) -> None:
    # Python refuses int() past 4300 digits and float() of a huge int: a ValueError or an
    # OverflowError traceback each, before.
    path = write(tmp_path / 'p.yaml', NODE.replace(
        'sim_imu}', 'sim_imu, parameters: {rate: ' + '1' * 5000 + '}}'))
    assert str(load_error(path)) == (f'{path}: line 2, column 45: invalid YAML: an integer of '
                                     '5000 digits (at most 100)')
    path = write(tmp_path / 'q.yaml', NODE + 'groups: {main: {restart_limit: ' + '9' * 90
                 + '}}\n')
    assert 'groups.main.restart_limit: expected an integer with 0 <= value <= 10000' in str(
        load_error(path))
    path = write(tmp_path / 'r.yaml', NODE + 'environment: {ROS_DOMAIN_ID: "' + '1' * 5000
                 + '"}\n')
    assert 'environment.ROS_DOMAIN_ID: expected an integer from 0 to 232' in str(
        load_error(path))


# -- one profile split between two computers (--only-group / --skip-group) -------------------
@pytest.fixture(scope='module')
def split() -> profiles.Profile:
    return load_profile('saucer_fusion_split_sim')  # groups main and operator


def test_skip_group_drops_the_groups_nodes_as_enabled_false_would(
        split: profiles.Profile) -> None:
    vessel = profiles.select_groups(split, skip=['operator'])
    assert vessel.group_names() == ['main'] and list(vessel.groups) == ['main']
    assert 'fusion' not in vessel.node_names() and 'detector' not in vessel.node_names()
    assert len(vessel.nodes) == len(split.nodes) - 2
    assert vessel.partial and not split.partial
    assert not profiles.select_groups(split, skip=[]).partial


def test_only_group_keeps_the_groups_nodes_alone(split: profiles.Profile) -> None:
    operator = profiles.select_groups(split, only=['operator'])
    assert operator.node_names() == ['detector', 'fusion']
    assert list(operator.groups) == ['operator']
    assert operator.frames == split.frames  # the fusion reads the camera's mount from them


def test_an_unknown_group_is_refused_naming_the_groups(split: profiles.Profile) -> None:
    with pytest.raises(ProfileError) as info:
        profiles.select_groups(split, skip=['operater'])
    assert str(info.value) == (
        f"{split.path}: --skip-group 'operater': no such group; the groups of the profile are "
        "main, operator (did you mean 'operator'?)")
    with pytest.raises(ProfileError, match="--only-group 'topside': no such group"):
        profiles.select_groups(split, only=['topside'])


def test_skipping_every_group_is_refused(split: profiles.Profile) -> None:
    with pytest.raises(ProfileError, match='no group left to run'):
        profiles.select_groups(split, skip=['main', 'operator'])
