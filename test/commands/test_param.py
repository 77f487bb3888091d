"""``enbarr param``: ros2param's verbs against a real Enbarr node (node tier, in process).

The expected lines are typed from ros2cli's ros2param (Jazzy, 0.32.2: ``verb/get.py``,
``set.py``, ``list.py``, ``describe.py``, ``dump.py``, ``api/__init__.py``), never read from
the code under test. The tool's node and the guidance node share the test's executor, so the
guidance node answers while the tool waits.
"""

from __future__ import annotations

import argparse
import io
from typing import Any

import pytest
from rclpy.parameter import Parameter
from support.saucer import overrides
import yaml

from enbarr_core.commands.param import ParamCommand, ParamTool, run
from enbarr_core.framework.errors import EnbarrError
from enbarr_core.guidance.guidance_node import GuidanceNode

TIMEOUT = 10.0  # [s] a bound on discovery and answers; never a claim on speed


def parse(*words: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='enbarr param')
    ParamCommand().add_arguments(parser)
    return parser.parse_args(list(words))


class Harness:
    """The guidance node and the tool, on the test's executor."""

    def __init__(self, context: Any, executor: Any, namespace: str = '') -> None:
        self.node = GuidanceNode(node_name='guidance', namespace=namespace, context=context,
                                 parameter_overrides=overrides())
        executor.add_node(self.node)
        self.tool = ParamTool(timeout=TIMEOUT, context=context, executor=executor)

    def __call__(self, *words: str) -> tuple[int, str, str]:
        out, err = io.StringIO(), io.StringIO()
        rc = run(self.tool, parse(*words), out=out, err=err)
        return rc, out.getvalue(), err.getvalue()

    def close(self) -> None:
        self.tool.close()


@pytest.fixture
def h(context: Any, executor: Any) -> Any:
    harness = Harness(context, executor)
    try:
        yield harness
    finally:
        harness.close()


def test_get_prints_ros2params_labels(h):
    assert h('get', '/guidance', 'avoidance.gamma') == (0, 'Double value is: 0.5\n', '')
    assert h('get', 'guidance', 'avoidance.enabled') == (0, 'Boolean value is: False\n', '')
    assert h('get', '/guidance', 'path.heading') == (0, 'String value is: fixed\n', '')
    assert h('get', '/guidance', 'path.waypoints') == (0, 'Double values are: [0.0]\n', '')
    assert h('get', '/guidance', 'avoidance.gamma', '--hide-type') == (0, '0.5\n', '')


def test_get_every_type(h, context, executor):
    from rclpy.node import Node
    from enbarr_core.framework.params import ParamSpec, SettingsBinding
    node = Node('types', context=context)
    SettingsBinding(node, [
        ParamSpec('count', 3, 'How many', '', 0, 10),
        ParamSpec('counts', [1, 2], 'How many each'),
        ParamSpec('flags', [True, False], 'Flags'),
        ParamSpec('names', ['a', 'b'], 'Names'),
    ], dict, lambda settings: None)
    executor.add_node(node)
    assert h('get', 'types', 'count') == (0, 'Integer value is: 3\n', '')
    assert h('get', 'types', 'counts') == (0, 'Integer values are: [1, 2]\n', '')
    assert h('get', 'types', 'flags') == (0, 'Boolean values are: [True, False]\n', '')
    assert h('get', 'types', 'names') == (0, "String values are: ['a', 'b']\n", '')
    assert h('describe', 'types', 'count') == (0, 'Parameter name: count\n'
                                                  '  Type: integer\n'
                                                  '  Description: How many\n'
                                                  '  Constraints:\n'
                                                  '    Min value: 0\n'
                                                  '    Max value: 10\n'
                                                  '    Step: 1\n', '')
    assert h('set', 'types', 'counts', '[4, 5, 6]')[0:2] == (0, 'Set parameter successful\n')
    assert h('get', 'types', 'counts', '--hide-type') == (0, '[4, 5, 6]\n', '')
    assert error(h, 'set', 'types', 'counts', '[4.0]') == (
        "/types counts is an integer array; '[4.0]' is a double array")


def test_set_double_is_applied_to_the_settings(h):
    assert h('set', '/guidance', 'avoidance.gamma', '0.3') == (0, 'Set parameter successful\n',
                                                               '')
    assert h.node.get_parameter('avoidance.gamma').value == 0.3
    assert h.node.settings.avoidance.cbf.gamma == 0.3
    assert h('get', '/guidance', 'avoidance.gamma') == (0, 'Double value is: 0.3\n', '')


def test_set_array_gain_and_boolean(h):
    assert h('set', 'guidance', 'path.waypoints', '[1.0, 2.0, 3.0, 4.0]')[0:2] == (
        0, 'Set parameter successful\n')
    assert list(h.node.get_parameter('path.waypoints').value) == [1.0, 2.0, 3.0, 4.0]
    assert h('get', '/guidance', 'path.waypoints') == (
        0, 'Double values are: [1.0, 2.0, 3.0, 4.0]\n', '')
    assert h('set', '/guidance', 'avoidance.vessel_radius', '0.4')[0] == 0
    assert h('set', '/guidance', 'avoidance.enabled', 'true')[0:2] == (
        0, 'Set parameter successful\n')
    assert h('get', '/guidance', 'avoidance.enabled') == (0, 'Boolean value is: True\n', '')


def test_refused_value_prints_the_nodes_reason_and_keeps_the_old_one(h):
    rc, out, err = h('set', '/guidance', 'path.heading', 'sideways')
    assert (rc, out) == (2, '')
    assert err.startswith('Setting parameter failed: ') and err.endswith('\n')
    assert 'expected fixed or course' in err and err.count('\n') == 1
    assert h.node.get_parameter('path.heading').value == 'fixed'
    # a value out of the declared range: refused by rclpy with its own reason
    rc, out, err = h('set', '/guidance', 'avoidance.gamma', '20.0')
    assert (rc, out) == (2, '') and err.startswith('Setting parameter failed: ')
    assert h.node.get_parameter('avoidance.gamma').value == 0.5


def test_list_one_node_and_types_and_prefixes(h):
    rc, out, err = h('list', '/guidance')
    assert rc == 0 and err == ''
    lines = out.splitlines()
    assert lines == sorted(lines) and all(line.startswith('  ') for line in lines)
    assert '  avoidance.gamma' in lines and '  path.waypoints' in lines
    assert len(lines) == len(h.node.list_parameters([], 0).names)
    rc, out, _ = h('list', 'guidance', '--param-prefixes', 'path', '--param-type')
    assert out == ('  path.accel (type: double)\n'
                   '  path.acceptance_radius (type: double)\n'
                   '  path.heading (type: string)\n'
                   '  path.lookahead (type: double)\n'
                   '  path.speed (type: double)\n'
                   '  path.waypoints (type: double array)\n')
    rc, out, _ = h('list', '/guidance', '--filter', 'avoidance.g.*')
    assert out == '  avoidance.gamma\n'


def test_list_without_a_node_heads_each_node(h):
    rc, out, _ = h('list', '--spin-time', '0.5', '--param-prefixes', 'avoidance', '--filter',
                    'avoidance.gam')
    assert (rc, out) == (0, '/guidance:\n  avoidance.gamma\n')


def test_hidden_nodes_only_when_asked(h, context, executor):
    from rclpy.node import Node
    hidden = Node('_hidden', context=context)
    hidden.declare_parameter('secret', 1.5)
    executor.add_node(hidden)
    rc, out, _ = h('list', '--spin-time', '0.5', '--param-prefixes', 'secret')
    assert (rc, out) == (0, '')
    rc, out, _ = h('list', '--spin-time', '0.5', '--param-prefixes', 'secret',
                   '--include-hidden-nodes')
    assert (rc, out) == (0, '/_hidden:\n  secret\n')


def test_list_goes_on_past_a_node_without_parameter_services(h, context, executor):
    from rclpy.node import Node
    executor.add_node(Node('_mute', context=context, start_parameter_services=False))
    h.tool.timeout = 0.5
    rc, out, err = h('list', '--spin-time', '0.5', '--param-prefixes', 'avoidance',
                     '--filter', 'avoidance.gam', '--include-hidden-nodes')
    assert (rc, out) == (0, '/guidance:\n  avoidance.gamma\n')
    # (a node an earlier test left in this domain would be named too, on a line of its own)
    lines = err.splitlines()
    assert ('Wait for service timed out waiting for parameter services for node /_mute'
            in lines)
    assert all(line.startswith('Wait for service timed out waiting for parameter services '
                               'for node /') for line in lines)
    message = error(h, 'list', '/_mute')
    assert message == '/_mute has no parameter services (none answered within 0.5 s)'


def test_describe_prints_type_description_and_range(h):
    rc, out, err = h('describe', '/guidance', 'avoidance.gamma', 'avoidance.level')
    assert (rc, err) == (0, '')
    assert out == ('Parameter name: avoidance.gamma\n'
                   '  Type: double\n'
                   '  Description: Barrier decay rate: dB/dt >= -gamma B [1/s]\n'
                   '  Constraints:\n'
                   '    Min value: 0.01\n'
                   '    Max value: 10.0\n'
                   'Parameter name: avoidance.level\n'
                   '  Type: string\n'
                   '  Description: Where the barrier functions act: guidance (the desired '
                   'position, in the guidance node) or force (the force, in the DP control '
                   'node; the guidance then keeps only its blind hold)\n'
                   '  Constraints:\n'
                   '    Read only: true\n')


def test_dump_is_ros2s_layout_and_round_trips(h, tmp_path):
    h.node.set_parameters([Parameter('path.waypoints', value=[1.0, 2.0])])
    rc, out, err = h('dump', 'guidance')
    assert (rc, err) == (0, '')
    assert out.endswith('\n\n')  # print() of yaml.dump's text, as ros2param does
    assert out.startswith('/guidance:\n  ros__parameters:\n    avoidance:\n')
    assert '    path:\n' in out and '      waypoints:\n      - 1.0\n      - 2.0\n' in out
    dumped = yaml.safe_load(out)
    params = dumped['/guidance']['ros__parameters']
    assert params['avoidance']['gamma'] == 0.5
    names = h.node.list_parameters([], 0).names
    flat = {}
    for name in names:
        tree = params
        for part in name.split('.'):
            tree = tree[part]
        flat[name] = tree
    assert flat == {n: h.node.get_parameter(n).value for n in names}
    # and the file loads back (ros2 param load's lines), changed values applied
    dumped['/guidance']['ros__parameters']['avoidance']['gamma'] = 0.25
    # read-only ones are refused, as by ros2 param load
    del dumped['/guidance']['ros__parameters']['avoidance']['level']
    del dumped['/guidance']['ros__parameters']['start_type_description_service']
    path = tmp_path / 'guidance.yaml'
    path.write_text(yaml.safe_dump(dumped))
    rc, out, err = h('load', '/guidance', str(path))
    assert (rc, err) == (0, ''), err
    assert 'Set parameter avoidance.gamma successful\n' in out
    assert h.node.get_parameter('avoidance.gamma').value == 0.25


def test_load_reports_a_refused_parameter(h, tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('/guidance:\n  ros__parameters:\n    path:\n      heading: sideways\n'
                    '      speed: 0.3\n')
    rc, out, err = h('load', 'guidance', str(path))
    assert rc == 2
    assert out == 'Set parameter path.speed successful\n'
    assert err.startswith('Set parameter path.heading failed: ')
    assert h.node.get_parameter('path.speed').value == 0.3


def test_load_wildcard_section_unless_told_not_to(h, tmp_path):
    path = tmp_path / 'all.yaml'
    path.write_text('/**:\n  ros__parameters:\n    path:\n      speed: 0.4\n')
    assert error(h, 'load', 'guidance', str(path), '--no-use-wildcard') == (
        f'{path}: Param file does not contain selected parameters')
    assert h.node.get_parameter('path.speed').value == 0.2
    assert h('load', 'guidance', str(path)) == (0, 'Set parameter path.speed successful\n', '')
    assert h.node.get_parameter('path.speed').value == 0.4


def test_load_of_a_file_that_is_no_parameter_file(h, tmp_path):
    path = tmp_path / 'list.yaml'
    path.write_text('- 1\n- 2\n')
    assert error(h, 'load', 'guidance', str(path)).startswith(f'{path}: ')


def test_node_in_a_namespace(context, executor):
    harness = Harness(context, executor, namespace='/vessel')
    try:
        assert harness('get', 'vessel/guidance', 'avoidance.gamma')[1] == 'Double value is: 0.5\n'
    finally:
        harness.close()


# Errors: one line each, as EnbarrError (the command line prints it and exits 2)

def error(h: Harness, *words: str) -> str:
    with pytest.raises(EnbarrError) as info:
        h(*words)
    message = str(info.value)
    assert '\n' not in message
    return message


def test_unknown_node_names_the_nodes_there_are(h):
    h.tool.timeout = 0.5
    message = error(h, 'get', '/guidanc', 'avoidance.gamma')
    assert message.startswith('node /guidanc not found')
    assert 'did you mean /guidance?' in message and 'Nodes: /guidance' in message
    message = error(h, 'list', '/nothing_like_it')
    assert 'did you mean' not in message and 'Nodes: /guidance' in message


def test_no_nodes_at_all_names_the_domain(context, executor, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '117')
    tool = ParamTool(timeout=0.5, context=context, executor=executor)
    try:
        with pytest.raises(EnbarrError, match=r'no nodes seen .*ROS_DOMAIN_ID=117'):
            run(tool, parse('get', '/guidance', 'x'), out=io.StringIO(), err=io.StringIO())
    finally:
        tool.close()


@pytest.mark.parametrize('words', [
    ('get', '/guidance', 'avoidance.gama'),
    ('set', '/guidance', 'avoidance.gama', '0.3'),
    ('describe', '/guidance', 'avoidance.gamma', 'avoidance.gama'),
])
def test_undeclared_parameter(h, words):
    message = error(h, *words)
    assert message == ('/guidance declares no parameter avoidance.gama; did you mean '
                       'avoidance.gamma? (enbarr param list /guidance lists them)')


def test_wrong_type_is_refused_before_sending(h):
    assert error(h, 'set', '/guidance', 'avoidance.gamma', '1') == (
        "/guidance avoidance.gamma is a double; '1' is an integer (write it with a decimal "
        'point, e.g. 1.0)')
    assert error(h, 'set', '/guidance', 'avoidance.enabled', 'yes please') == (
        "/guidance avoidance.enabled is a boolean; 'yes please' is a string")
    assert h.node.get_parameter('avoidance.gamma').value == 0.5


def test_value_that_is_not_yaml(h):
    assert error(h, 'set', '/guidance', 'path.heading', 'a: b: c').startswith(
        "value 'a: b: c' is not YAML")


def test_no_answer_within_the_timeout(context, executor):
    """A node whose executor never spins: found on the graph, but it never answers."""
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    import rclpy
    other = Context()
    rclpy.init(context=other, signal_handler_options=SignalHandlerOptions.NO)
    try:
        silent = GuidanceNode(node_name='silent', context=other, parameter_overrides=overrides())
        tool = ParamTool(timeout=1.0, context=context, executor=executor)
        try:
            with pytest.raises(EnbarrError, match=r'^/silent: no answer from its '
                               r'get_parameters service within 1 s$'):
                run(tool, parse('get', 'silent', 'avoidance.gamma'), out=io.StringIO(),
                    err=io.StringIO())
        finally:
            tool.close()
            silent.destroy_node()
    finally:
        rclpy.try_shutdown(context=other)
