"""``enbarr param list|get|set|describe|dump|load``: ``ros2 param`` for a pip install.

The ``ros2`` command line (ros2cli) is not on PyPI, so an install from wheels has no
``ros2 param``. This command takes the same words and prints the same lines as ros2cli's
``ros2param`` package of ROS 2 Jazzy (version 0.32.2, ``ros2param/verb/*.py``), by calling the
same standard parameter services (``rcl_interfaces/srv/ListParameters``, ``GetParameters``,
``SetParameters``, ``DescribeParameters``) from a short-lived hidden node. With a full ROS
install ``ros2 param`` works on Enbarr's nodes as before; the two are interchangeable.

Where it differs, on purpose: every failure is one line ``enbarr param: error: ...`` with
exit code 2 (ros2param prints some failures and still exits 0), a node that is not found is
named with the nodes that are there, and a value of the wrong type is refused before it is
sent, saying which type the parameter has. ``--timeout`` bounds both the search for the node
and each service answer.

The node's discovery settings are the environment's (``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE``): an operator reaches a vessel over the network.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
import difflib
import os
import re
import sys
import time
from typing import Any

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_seconds
from enbarr_core.framework.errors import EnbarrError

#: Default bound on finding the node and on each service answer [s]. Two processes on one
#: host discover each other in a fraction of a second or in a few seconds (ros2cli's daemon
#: hides that by caching the graph; there is no daemon here).
DEFAULT_TIMEOUT_S = 5.0
#: How long ``list`` without a node watches the graph before listing what it saw [s].
DEFAULT_SPIN_TIME_S = 3.0

#: ros2param's ``get_parameter_type_string`` (``ros2param/api/__init__.py``), by type number
#: (``rcl_interfaces/msg/ParameterType``).
TYPE_NAMES = {
    0: 'not set', 1: 'boolean', 2: 'integer', 3: 'double', 4: 'string', 5: 'byte array',
    6: 'boolean array', 7: 'integer array', 8: 'double array', 9: 'string array',
}
#: ros2param's ``get`` labels, by type number (``ros2param/verb/get.py``).
GET_LABELS = {
    0: 'Parameter not set.', 1: 'Boolean value is:', 2: 'Integer value is:',
    3: 'Double value is:', 4: 'String value is:', 5: 'Byte values are:',
    6: 'Boolean values are:', 7: 'Integer values are:', 8: 'Double values are:',
    9: 'String values are:',
}
#: The separator of nested parameter names (``rclpy.parameter.PARAMETER_SEPARATOR_STRING``).
SEPARATOR = '.'


class ParamCommand(Command):
    """``enbarr param ACTION ...``."""

    help = 'list, get, set, describe, dump and load node parameters (as ros2 param)'
    description = ('Read and tune the parameters of running nodes, with the syntax and output '
                   'of ros2 param (ROS 2 Jazzy, ros2param 0.32.2), for installs without the '
                   'ros2 command line. VALUE is YAML, as for ros2 param: 0.3 is a double, 3 an '
                   'integer, true a boolean, "[1.0, 2.0]" a double array; anything else a '
                   'string. Uses ROS_DOMAIN_ID and the discovery settings of the environment.')
    epilog = ('Examples: enbarr param list /guidance; enbarr param get /guidance '
              'avoidance.gamma; enbarr param set /guidance avoidance.gamma 0.3; enbarr param '
              'dump /guidance > guidance.yaml; enbarr param load /guidance guidance.yaml')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the actions and their arguments, as ros2param's verbs do."""
        sub = parser.add_subparsers(dest='action', required=True, metavar='ACTION')

        def verb(name: str, help_: str) -> argparse.ArgumentParser:
            p = sub.add_parser(name, help=help_, description=help_)
            p.add_argument('--timeout', type=float, default=DEFAULT_TIMEOUT_S, metavar='S',
                           help='wait up to S seconds for the node and for each answer '
                           f'(default {DEFAULT_TIMEOUT_S:g})')
            p.add_argument('--include-hidden-nodes', action='store_true',
                           help='consider hidden nodes as well')
            return p

        p = verb('list', 'Output a list of available parameters')
        p.add_argument('node_name', nargs='?', help='name of the ROS node')
        p.add_argument('--filter', nargs=1, help='only parameters matching the regex '
                       'expression will be shown (Python re syntax)')
        p.add_argument('--param-prefixes', nargs='+', default=[],
                       help='only list parameters with the provided prefixes')
        p.add_argument('--param-type', action='store_true',
                       help='print parameter types with parameter names')
        p.add_argument('--spin-time', type=float, default=DEFAULT_SPIN_TIME_S, metavar='S',
                       help='without NODE: watch the graph for S seconds '
                       f'(default {DEFAULT_SPIN_TIME_S:g})')
        p = verb('get', 'Get parameter')
        p.add_argument('node_name', help='name of the ROS node')
        p.add_argument('parameter_name', help='name of the parameter')
        p.add_argument('--hide-type', action='store_true', help='hide the type information')
        p = verb('set', 'Set parameter')
        p.add_argument('node_name', help='name of the ROS node')
        p.add_argument('parameter_name', help='name of the parameter')
        p.add_argument('value', help='value of the parameter (YAML)')
        p = verb('describe', 'Show descriptive information about declared parameters')
        p.add_argument('node_name', help='name of the ROS node')
        p.add_argument('parameter_names', nargs='+', help='names of the parameters')
        p = verb('dump', 'Show all of the parameters of a node in a YAML file format')
        p.add_argument('node_name', help='name of the ROS node')
        p = verb('load', 'Load parameter file for a node')
        p.add_argument('node_name', help='name of the ROS node')
        p.add_argument('parameter_file', help='parameter file')
        p.add_argument('--no-use-wildcard', action='store_true',
                       help="do not load parameters in the '/**' namespace into the node")

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the action on a short-lived node of its own; the exit code."""
        check_seconds('--timeout', args.timeout)
        if args.action == 'list':
            check_seconds('--spin-time', args.spin_time)
        with ParamTool(timeout=args.timeout) as tool:
            return run(tool, args, out=sys.stdout, err=sys.stderr)


def run(tool: ParamTool, args: argparse.Namespace, *, out: Any, err: Any) -> int:
    """Run ``args.action`` with ``tool``, printing to ``out``/``err``; the exit code."""
    actions: dict[str, Callable[[ParamTool, argparse.Namespace, Any, Any], int]] = {
        'list': _list, 'get': _get, 'set': _set, 'describe': _describe, 'dump': _dump,
        'load': _load}
    return actions[args.action](tool, args, out, err)


def absolute_node_name(name: str) -> str:
    """``guidance`` -> ``/guidance`` (ros2node's ``get_absolute_node_name``)."""
    return name if name.startswith('/') else '/' + name


def _list(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    hidden = args.include_hidden_nodes
    if args.node_name:
        nodes = [tool.find_node(args.node_name, hidden)]
    else:
        nodes = tool.node_names(hidden, settle=args.spin_time)
    regex = re.compile(args.filter[0]) if args.filter else None
    # ros2param sorts ros2node's NodeName tuples: by base name, then namespace.
    for full in sorted(nodes, key=_sort_key):
        try:
            names = sorted(tool.list_names(full, args.param_prefixes))
        except ServicesNotFound:
            if args.node_name:
                raise
            # As ros2param: one node without parameter services does not stop the listing.
            print('Wait for service timed out waiting for parameter services for node '
                  f'{full}', file=err)
            continue
        if regex is not None:
            names = [n for n in names if regex.match(n)]
        if not args.node_name and names:
            print(f'{full}:', file=out)
        types = {}
        if args.param_type:
            types = {d.name: TYPE_NAMES[d.type] for d in tool.describe(full, names)}
        for name in names:
            print(f'  {name} (type: {types[name]})' if args.param_type else f'  {name}',
                  file=out)
    return 0


def _get(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    node = tool.find_node(args.node_name, args.include_hidden_nodes)
    values = tool.get(node, [args.parameter_name])
    if not values:
        raise tool.not_declared(node, args.parameter_name)
    label, value = format_value(values[0])
    if args.hide_type:
        print(value, file=out)
    elif value is not None:
        print(label, value, file=out)
    else:
        print(label, file=out)
    return 0


def format_value(pvalue: Any) -> tuple[str, Any]:
    """Return the label and the value ``ros2 param get`` prints for a ``ParameterValue``."""
    fields = {1: 'bool_value', 2: 'integer_value', 3: 'double_value', 4: 'string_value',
              5: 'byte_array_value', 6: 'bool_array_value', 7: 'integer_array_value',
              8: 'double_array_value', 9: 'string_array_value'}
    if pvalue.type not in GET_LABELS:
        raise EnbarrError(f"unknown parameter type '{pvalue.type}'")
    if pvalue.type == 0:
        return GET_LABELS[0], None
    value = getattr(pvalue, fields[pvalue.type])
    if pvalue.type in (7, 8):  # array.array in rclpy; ros2param prints .tolist()
        value = value.tolist()
    return GET_LABELS[pvalue.type], value


def _set(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    from rcl_interfaces.msg import Parameter
    from rclpy.parameter import get_parameter_value
    import yaml

    node = tool.find_node(args.node_name, args.include_hidden_nodes)
    try:
        value = get_parameter_value(string_value=args.value)
    except yaml.YAMLError as error:  # ros2param lets all but a ParserError escape
        raise EnbarrError(f'value {args.value!r} is not YAML: '
                          f'{" ".join(str(error).split())}') from error
    descriptors = tool.describe(node, [args.parameter_name])
    if not descriptors:
        raise tool.not_declared(node, args.parameter_name)
    want = descriptors[0]
    if not want.dynamic_typing and want.type != value.type and want.type != 0:
        hint = ' (write it with a decimal point, e.g. 1.0)' if (
            (want.type, value.type) in ((3, 2), (8, 7))) else ''
        raise EnbarrError(f'{node} {args.parameter_name} is {_a(TYPE_NAMES[want.type])}; '
                          f'{args.value!r} is {_a(TYPE_NAMES.get(value.type, "value"))}{hint}')
    results = tool.set(node, [Parameter(name=args.parameter_name, value=value)])
    result = results[0]
    if result.successful:
        print('Set parameter successful' + (f': {result.reason}' if result.reason else ''),
              file=out)
        return 0
    print('Setting parameter failed' + (f': {_one_line(result.reason)}' if result.reason
                                         else ''), file=err)
    return 2


def _describe(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    node = tool.find_node(args.node_name, args.include_hidden_nodes)
    descriptors = tool.describe(node, args.parameter_names)
    if not descriptors:  # the service answers nothing when one name is not declared
        declared = set(tool.list_names(node, []))
        missing = [n for n in args.parameter_names if n not in declared]
        raise tool.not_declared(node, missing[0] if missing else args.parameter_names[0])
    for d in descriptors:
        print('Parameter name:', d.name, file=out)
        print('  Type:', TYPE_NAMES[d.type], file=out)
        if d.description:
            print('  Description:', d.description, file=out)
        print('  Constraints:', file=out)
        if d.read_only:
            print('    Read only: true', file=out)
        ranges = list(d.floating_point_range) + list(d.integer_range)
        if ranges:
            print('    Min value:', ranges[0].from_value, file=out)
            print('    Max value:', ranges[0].to_value, file=out)
            if ranges[0].step:
                print('    Step:', ranges[0].step, file=out)
        if d.additional_constraints:
            print('    Additional constraints:', d.additional_constraints, file=out)
    return 0


def _dump(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    from rclpy.parameter import parameter_value_to_python
    import yaml

    node = tool.find_node(args.node_name, args.include_hidden_nodes)
    names = sorted(tool.list_names(node, []))
    values = tool.get(node, names) if names else []
    if len(values) != len(names):
        raise EnbarrError(f'{node} answered {len(values)} values for {len(names)} parameters '
                          '(one was undeclared while dumping); try again')
    params: dict[str, Any] = {}
    for name, value in zip(names, values):
        _insert(params, name, parameter_value_to_python(value))
    print(yaml.dump({node: {'ros__parameters': params}}, default_flow_style=False), file=out)
    return 0


def _insert(tree: dict[str, Any], name: str, value: Any) -> None:
    """Nest ``a.b.c`` as ``{a: {b: {c: value}}}`` (ros2param's ``DumpVerb.insert_dict``)."""
    head, sep, rest = name.partition(SEPARATOR)
    if sep:
        _insert(tree.setdefault(head, {}), rest, value)
    else:
        tree[name] = value


def _load(tool: ParamTool, args: argparse.Namespace, out: Any, err: Any) -> int:
    from rclpy.parameter import parameter_dict_from_yaml_file
    import yaml

    node = tool.find_node(args.node_name, args.include_hidden_nodes)
    wildcard = not args.no_use_wildcard
    try:
        # ros2param's load sends every parameter of the file, whichever node it is under.
        params = list(parameter_dict_from_yaml_file(args.parameter_file, wildcard).values())
    # rclpy's reader does not check the file's shape first: a list at the top is an
    # AttributeError, a section of no parameters a RuntimeError.
    except (yaml.YAMLError, RuntimeError, TypeError, AttributeError, ValueError) as error:
        raise EnbarrError(f'{args.parameter_file}: {" ".join(str(error).split())}') from error
    results = tool.set(node, params)  # rcl_interfaces Parameter messages
    failed = 0
    for param, result in zip(params, results):
        reason = f': {_one_line(result.reason)}' if result.reason else ''
        if result.successful:
            print(f'Set parameter {param.name} successful{reason}', file=out)
        else:
            failed += 1
            print(f'Set parameter {param.name} failed{reason}', file=err)
    return 2 if failed else 0


def _a(noun: str) -> str:
    return ('an ' if noun[0] in 'aeiou' else 'a ') + noun


def _one_line(text: str) -> str:
    return ' '.join(text.split())


def _sort_key(full_name: str) -> tuple[str, str, str]:
    namespace, _, name = full_name.rpartition('/')
    return name, namespace or '/', full_name


class ServicesNotFound(EnbarrError):
    """A node on the graph whose parameter services did not appear within the timeout."""


class ParamTool:
    """A hidden, short-lived node that calls other nodes' parameter services.

    By default it has a context and an executor of its own (the command line). A test hands
    it its ``context`` and ``executor``, so that the nodes under test answer while the tool
    waits. Close it (or use it as a context manager) to destroy its node.
    """

    def __init__(self, *, timeout: float = DEFAULT_TIMEOUT_S, context: Any = None,
                 executor: Any = None) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.timeout = timeout
        self._own_context = context is None
        if context is None:
            from rclpy.context import Context
            context = Context()
            rclpy.init(context=context)
        self.context = context
        self.executor = executor or SingleThreadedExecutor(context=context)
        self._own_executor = executor is None
        # A leading underscore hides it, as ros2cli's own node is hidden.
        self.node = rclpy.create_node(
            f'_enbarr_param_{os.getpid()}', context=context, start_parameter_services=False,
            enable_rosout=False)
        self.executor.add_node(self.node)
        self._clients: dict[str, Any] = {}

    def __enter__(self) -> ParamTool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Destroy the node (and the context and executor when they are its own)."""
        import rclpy

        self.executor.remove_node(self.node)
        self.node.destroy_node()
        if self._own_executor:
            self.executor.shutdown()
        if self._own_context:
            rclpy.try_shutdown(context=self.context)

    # The graph

    def _visible(self, hidden: bool) -> list[str]:
        names = []
        for name, namespace in self.node.get_node_names_and_namespaces():
            if name.startswith('_') and not hidden:
                continue
            names.append(namespace.rstrip('/') + '/' + name)
        own = self.node.get_fully_qualified_name()
        return sorted(set(names) - {own})

    def _spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not condition():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.05, left))
        return True

    def node_names(self, hidden: bool = False, settle: float = DEFAULT_SPIN_TIME_S) -> list[str]:
        """Return the full names of the nodes seen on the graph within ``settle`` s."""
        self._spin_until(lambda: False, settle)
        return self._visible(hidden)

    def find_node(self, name: str, hidden: bool = False) -> str:
        """Return the full name of node ``name`` (leading slash optional) once it is seen.

        Raises ``EnbarrError`` naming the nodes there are (and the closest) when it does not
        appear within the timeout.
        """
        full = absolute_node_name(name)
        if self._spin_until(lambda: full in self._visible(True), self.timeout):
            return full
        nodes = self._visible(hidden)
        domain = os.environ.get('ROS_DOMAIN_ID', '0')
        if not nodes:
            raise EnbarrError(f'node {full} not found: no nodes seen within {self.timeout:g} s '
                              f'(ROS_DOMAIN_ID={domain}; is the vessel running and is it the '
                              'same domain?)')
        close = difflib.get_close_matches(full, nodes, n=1)
        mean = f'; did you mean {close[0]}?' if close else ''
        raise EnbarrError(f'node {full} not found within {self.timeout:g} s{mean} '
                          f'Nodes: {", ".join(nodes)}')

    # The parameter services

    def _client(self, node: str) -> Any:
        from rclpy.parameter_client import AsyncParameterClient

        if node not in self._clients:
            client = AsyncParameterClient(self.node, node)
            if not self._spin_until(client.services_are_ready, self.timeout):
                raise ServicesNotFound(f'{node} has no parameter services (none answered within '
                                  f'{self.timeout:g} s)')
            self._clients[node] = client
        return self._clients[node]

    def _call(self, node: str, service: str, future: Any) -> Any:
        self.executor.spin_until_future_complete(future, timeout_sec=self.timeout)
        if not future.done():
            future.cancel()
            raise EnbarrError(f'{node}: no answer from its {service} service within '
                              f'{self.timeout:g} s')
        if future.exception() is not None:
            raise EnbarrError(f'{node}: {service} failed: {future.exception()}')
        return future.result()

    def list_names(self, node: str, prefixes: Sequence[str]) -> list[str]:
        """Return the parameters ``node`` declares (with one of ``prefixes``, if any)."""
        future = self._client(node).list_parameters(prefixes=list(prefixes) or None)
        return list(self._call(node, 'list_parameters', future).result.names)

    def get(self, node: str, names: Sequence[str]) -> list[Any]:
        """Return the ``ParameterValue``s of ``names``; empty when one is not declared."""
        future = self._client(node).get_parameters(list(names))
        return list(self._call(node, 'get_parameters', future).values)

    def describe(self, node: str, names: Sequence[str]) -> list[Any]:
        """Return the ``ParameterDescriptor``s of ``names``; empty when one is undeclared."""
        future = self._client(node).describe_parameters(list(names))
        return list(self._call(node, 'describe_parameters', future).descriptors)

    def set(self, node: str, params: Sequence[Any]) -> list[Any]:
        """Set ``rcl_interfaces/Parameter`` messages one by one; their ``SetParametersResult``s."""
        future = self._client(node).set_parameters(list(params))
        results = list(self._call(node, 'set_parameters', future).results)
        if len(results) != len(params):
            raise EnbarrError(f'{node} answered {len(results)} results for {len(params)} '
                              'parameters')
        return results

    def not_declared(self, node: str, name: str) -> EnbarrError:
        """Return the error for a parameter ``node`` does not declare (closest one named)."""
        close = difflib.get_close_matches(name, self.list_names(node, []), n=1)
        mean = f'; did you mean {close[0]}?' if close else ''
        return EnbarrError(f'{node} declares no parameter {name}{mean} '
                           f'(enbarr param list {node} lists them)')
