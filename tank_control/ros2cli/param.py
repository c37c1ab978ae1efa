"""``ros2 param list|get|set|describe|dump|load``: a node's parameters over its services.

Uses the rcl_interfaces services every rclpy/rclcpp node offers
(``<node>/list_parameters``, ``get_parameters``, ``set_parameters``,
``describe_parameters``). ``dump`` writes the standard parameter file layout
(``/node: ros__parameters: ...``) in the dialect of ``core/ros_yaml`` (strings
such as ``y`` or ``on`` quoted), which ``load`` and ``--params-file`` read back
as the same values.
"""
from __future__ import annotations

import argparse
import re
import sys
from typing import TYPE_CHECKING, Any

from tank_control.nodes.services import RESEND_AFTER, answers
from tank_control.ros2cli.common import (
    CliError, add_daemon_argument, absolute_name, add_spin_time_argument, add_timeout_argument, call_service,
    client_node, is_hidden, settle_graph, spin_until, wait_for_node)

if TYPE_CHECKING:
    from rclpy.node import Node

_TYPE_NAMES = {0: 'not set', 1: 'boolean', 2: 'integer', 3: 'double', 4: 'string',
               5: 'byte array', 6: 'boolean array', 7: 'integer array', 8: 'double array',
               9: 'string array'}
_GET_LABELS = {1: 'Boolean value is:', 2: 'Integer value is:', 3: 'Double value is:',
               4: 'String value is:', 5: 'Byte values are:', 6: 'Boolean values are:',
               7: 'Integer values are:', 8: 'Double values are:', 9: 'String values are:'}


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser('param', help='Various param related sub-commands',
                                 description='Various param related sub-commands')
    verbs = parser.add_subparsers(title='Commands', dest='verb', metavar='VERB')
    verbs.required = True

    p = verbs.add_parser('list', help='Output a list of available parameters',
                         description='Output a list of available parameters')
    p.add_argument('node_name', nargs='?', metavar='NODE',
                   help='name of the node (all nodes if omitted)')
    p.add_argument('--filter', metavar='REGEX', help='only parameters matching this regex')
    p.add_argument('--param-type', action='store_true', help='print the type of each parameter')
    p.add_argument('-a', '--include-hidden-nodes', action='store_true',
                   help='consider hidden nodes as well')
    add_timeout_argument(p)
    add_spin_time_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=list_verb)

    p = verbs.add_parser('get', help='Get parameter', description='Get parameter')
    p.add_argument('node_name', metavar='NODE', help='name of the node')
    p.add_argument('parameter_name', metavar='NAME', help='name of the parameter')
    p.add_argument('--hide-type', action='store_true', help='print only the value')
    add_timeout_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=get_verb)

    p = verbs.add_parser('set', help='Set parameter', description=(
        'Set parameter. VALUE is YAML: 1.5 (double), 2 (integer; a double parameter '
        'takes it as 2.0), true, text, [1.0, 2.0].'))
    p.add_argument('node_name', metavar='NODE', help='name of the node')
    p.add_argument('parameter_name', metavar='NAME', help='name of the parameter')
    p.add_argument('value', metavar='VALUE', help='value of the parameter (YAML)')
    add_timeout_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=set_verb)

    p = verbs.add_parser('describe', help='Show descriptive information about declared parameters',
                         description='Show descriptive information about declared parameters')
    p.add_argument('node_name', metavar='NODE', help='name of the node')
    p.add_argument('parameter_names', metavar='NAME', nargs='+', help='names of the parameters')
    add_timeout_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=describe_verb)

    p = verbs.add_parser('dump', help='Show all of the parameters of a node in a YAML file format',
                         description='Print all parameters of a node as a parameter file '
                                     '(accepted by `ros2 param load` and --params-file)')
    p.add_argument('node_name', metavar='NODE', help='name of the node')
    add_timeout_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=dump_verb)

    p = verbs.add_parser('load', help='Load parameter file for a node',
                         description='Load parameter file for a node')
    p.add_argument('node_name', metavar='NODE', help='name of the node')
    p.add_argument('parameter_file', metavar='FILE', help='parameter file (YAML)')
    p.add_argument('--no-use-wildcard', action='store_true',
                   help="do not load parameters in the '/**' namespace into the node")
    add_timeout_argument(p)
    p.set_defaults(func=load_verb)


# service helpers ----------------------------------------------------------------------------

def _list_names(node: 'Node', target: str, timeout: float) -> list[str]:
    from rcl_interfaces.srv import ListParameters
    request = ListParameters.Request()
    request.depth = ListParameters.Request.DEPTH_RECURSIVE
    response = call_service(node, ListParameters, f'{target}/list_parameters', request, timeout,
                            resend_after=RESEND_AFTER)
    return sorted(response.result.names)


def _per_name(call, names: list[str]) -> list[Any]:
    """Answers for ``names``; rclpy answers nothing when one name is undeclared, so then
    each name is asked alone and undeclared ones get ``None``."""
    answers = call(names)
    if len(answers) == len(names):
        return answers
    return [(call([name]) or [None])[0] for name in names]


def _get_values(node: 'Node', target: str, names: list[str], timeout: float) -> list[Any]:
    """ParameterValue per name (``None`` for an undeclared parameter)."""
    from rcl_interfaces.srv import GetParameters

    def call(batch: list[str]) -> list[Any]:
        return list(call_service(node, GetParameters, f'{target}/get_parameters',
                                 GetParameters.Request(names=batch), timeout,
                                 resend_after=RESEND_AFTER).values)
    return _per_name(call, names)


def _describe(node: 'Node', target: str, names: list[str], timeout: float) -> list[Any]:
    """ParameterDescriptor per name (``None`` for an undeclared parameter)."""
    from rcl_interfaces.srv import DescribeParameters

    def call(batch: list[str]) -> list[Any]:
        return list(call_service(node, DescribeParameters, f'{target}/describe_parameters',
                                 DescribeParameters.Request(names=batch), timeout,
                                 resend_after=RESEND_AFTER).descriptors)
    return _per_name(call, names)


def _set(node: 'Node', target: str, parameters: list[Any], timeout: float) -> list[Any]:
    from rcl_interfaces.srv import SetParameters
    response = call_service(node, SetParameters, f'{target}/set_parameters',
                            SetParameters.Request(parameters=parameters), timeout,
                            prime_with=SetParameters.Request())
    return list(response.results)


def _connect(node: 'Node', node_name: str, timeout: float) -> str:
    target = absolute_name(node_name)
    wait_for_node(node, target, timeout)
    return target


def _python(value: Any) -> Any:
    from rclpy.parameter import parameter_value_to_python
    return parameter_value_to_python(value)


# values -------------------------------------------------------------------------------------

def value_from_python(value: Any, declared_type: int, raw: str | None = None) -> Any:
    """A ParameterValue for ``value`` (or the YAML text ``raw``), fitted to the declared type.

    ``raw`` is typed as in a parameter file (``1e-3`` is a double, where ros2cli's plain
    YAML would send the string '1e-3'). An integer (list) is taken as a double (list) by a
    double parameter, an empty list takes the declared array type, and a string parameter
    takes ``raw`` as text; anything else keeps its YAML type and the node decides (and
    gives its reason when it refuses).
    """
    from rcl_interfaces.msg import ParameterType as T
    from rcl_interfaces.msg import ParameterValue
    import yaml
    from rclpy.parameter import Parameter, get_parameter_value

    from tank_control.core import ros_yaml
    if raw is not None:
        msg = get_parameter_value(raw)
        try:
            value = ros_yaml.load(raw)       # as a params file would type it: 1e-3 is a number
        except yaml.YAMLError:
            value = raw
        if msg.type == T.PARAMETER_STRING and not isinstance(value, str):
            try:
                msg = Parameter('p', value=value).get_parameter_value()
            except TypeError:
                pass
    else:
        try:
            msg = Parameter('p', value=value).get_parameter_value()
        except TypeError:   # e.g. a list mixing types
            msg = ParameterValue(type=T.PARAMETER_STRING, string_value=str(value))
    number = (int, float)
    numbers = isinstance(value, list) and all(
        isinstance(v, number) and not isinstance(v, bool) for v in value)
    if declared_type == T.PARAMETER_DOUBLE and isinstance(value, int) and \
            not isinstance(value, bool):
        return ParameterValue(type=T.PARAMETER_DOUBLE, double_value=float(value))
    if declared_type == T.PARAMETER_DOUBLE_ARRAY and numbers:
        return ParameterValue(type=T.PARAMETER_DOUBLE_ARRAY,
                              double_array_value=[float(v) for v in value])
    if declared_type in (T.PARAMETER_BOOL_ARRAY, T.PARAMETER_INTEGER_ARRAY,
                         T.PARAMETER_STRING_ARRAY) and value == []:
        return ParameterValue(type=declared_type)
    if declared_type == T.PARAMETER_STRING and msg.type != T.PARAMETER_STRING and \
            raw is not None:
        return ParameterValue(type=T.PARAMETER_STRING, string_value=raw)
    return msg


def _format_value(value: Any) -> str:
    python = _python(value)
    return str(python)


# verbs --------------------------------------------------------------------------------------

def _list_all(node: 'Node', targets: list[str], timeout: float) -> dict[str, list[str] | None]:
    """Parameter names of many nodes at once; ``None`` for a node that did not answer."""
    from rcl_interfaces.srv import ListParameters
    request = ListParameters.Request(depth=ListParameters.Request.DEPTH_RECURSIVE)
    clients = {t: node.create_client(ListParameters, f'{t}/list_parameters') for t in targets}
    try:
        spin_until(node, lambda: all(c.service_is_ready() for c in clients.values()), timeout)
        found = answers({t: (c, request) for t, c in clients.items() if c.service_is_ready()},
                        lambda done, wait: spin_until(node, done, wait), timeout, RESEND_AFTER)

        def names(target: str) -> list[str] | None:
            future = found.get(target)
            answer = future.result() if future is not None else None
            return sorted(answer.result.names) if answer is not None else None
        return {t: names(t) for t in targets}
    finally:
        for client in clients.values():
            node.destroy_client(client)


def list_verb(args: argparse.Namespace) -> int:
    pattern = re.compile(args.filter) if args.filter else None
    with client_node() as node:
        if args.node_name:
            target = _connect(node, args.node_name, args.timeout)
            listing = {target: _list_names(node, target, args.timeout)}
        else:
            settle_graph(node, args.spin_time)
            services = {name for name, _ in node.get_service_names_and_types()}
            targets = sorted(n for n in node.get_fully_qualified_node_names()
                             if f'{n}/list_parameters' in services and
                             (args.include_hidden_nodes or not is_hidden(n)))
            listing = _list_all(node, targets, args.timeout)
        for target, names in listing.items():
            if names is None:
                print(f"Warning: node '{target}' did not answer within {args.timeout:g} s",
                      file=sys.stderr)
                continue
            names = [n for n in names if pattern is None or pattern.search(n)]
            types = {}
            if args.param_type and names:
                values = _get_values(node, target, names, args.timeout)
                types = {n: _TYPE_NAMES.get(v.type, '?') if v else '?'
                         for n, v in zip(names, values)}
            if not args.node_name:
                print(f'{target}:')
            for name in names:
                print(f'  {name} (type: {types[name]})' if args.param_type else f'  {name}')
    return 0


def get_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        target = _connect(node, args.node_name, args.timeout)
        [value] = _get_values(node, target, [args.parameter_name], args.timeout)
        if value is None or value.type == 0:
            from tank_control.core.params import nearest
            names = _list_names(node, target, args.timeout)
            guess = None if args.parameter_name in names else nearest(args.parameter_name, names)
            hint = f'; did you mean {guess}?' if guess else ''
            raise CliError(f"Parameter not set: '{args.parameter_name}' on {target}{hint}")
    text = _format_value(value)
    print(text if args.hide_type else f'{_GET_LABELS[value.type]} {text}')
    return 0


def set_verb(args: argparse.Namespace) -> int:
    from rcl_interfaces.msg import Parameter
    with client_node() as node:
        target = _connect(node, args.node_name, args.timeout)
        [descriptor] = _describe(node, target, [args.parameter_name], args.timeout)
        declared = descriptor.type if descriptor is not None else 0
        value = value_from_python(None, declared, raw=args.value)
        [result] = _set(node, target, [Parameter(name=args.parameter_name, value=value)],
                        args.timeout)
    if not result.successful:
        reason = result.reason or 'rejected by the node'
        raise CliError(f'Set parameter failed: {reason}')
    print('Set parameter successful' + (f': {result.reason}' if result.reason else ''))
    return 0


def describe_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        target = _connect(node, args.node_name, args.timeout)
        descriptors = _describe(node, target, list(args.parameter_names), args.timeout)
    missing = [n for n, d in zip(args.parameter_names, descriptors) if d is None]
    for descriptor in descriptors:
        if descriptor is not None:
            print(describe_text(descriptor))
    if missing:
        raise CliError(f"Parameter not declared on {target}: {', '.join(missing)}")
    return 0


def describe_text(descriptor: Any) -> str:
    """ros2cli's layout: name, type, description, then the constraints that exist."""
    lines = [f'Parameter name: {descriptor.name}',
             f'  Type: {_TYPE_NAMES.get(descriptor.type, "?")}']
    if descriptor.description:
        lines.append(f'  Description: {descriptor.description}')
    constraints = []
    if descriptor.read_only:
        constraints.append('    Read only: true')
    if descriptor.dynamic_typing:
        constraints.append('    Dynamic typing: true')
    if descriptor.additional_constraints:
        constraints.append(f'    Additional constraints: {descriptor.additional_constraints}')
    for ranges in (descriptor.integer_range, descriptor.floating_point_range):
        for r in ranges:
            constraints += [f'    Min value: {r.from_value}', f'    Max value: {r.to_value}']
            if r.step:
                constraints.append(f'    Step: {r.step}')
    if constraints:
        lines += ['  Constraints:'] + constraints
    return '\n'.join(lines)


def dump_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        target = _connect(node, args.node_name, args.timeout)
        names = _list_names(node, target, args.timeout)
        values = _get_values(node, target, names, args.timeout) if names else []
    flat = {n: _python(v) for n, v in sorted(zip(names, values), key=lambda item: item[0])
            if v is not None and v.type != 0}
    from tank_control.core import params_file
    sys.stdout.write(params_file.dumps({target: flat}))   # the dialect the loader reads
    return 0


def parameters_from_file(path: str, target: str, use_wildcard: bool = True) -> dict[str, Any]:
    """Flat name → value for ``target`` from a parameter file (wildcards first, then exact),
    read by the package's one parameter-file reader."""
    from tank_control.core import params_file
    from tank_control.core.params import ConfigError
    try:
        sections = params_file.read(path)
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    flat = params_file.values_for(sections, target, use_wildcard)
    if flat is None:
        raise CliError(f"Param file does not contain parameters for {target}, only for nodes: "
                       f"{', '.join(sections)}")
    return flat


def load_verb(args: argparse.Namespace) -> int:
    from rcl_interfaces.msg import Parameter, ParameterDescriptor
    with client_node() as node:
        target = _connect(node, args.node_name, args.timeout)
        flat = parameters_from_file(args.parameter_file, target, not args.no_use_wildcard)
        names = list(flat)
        descriptors = _describe(node, target, names, args.timeout)
        current = _get_values(node, target, names, args.timeout)
        to_set, skipped = [], []
        for name, descriptor, now in zip(names, descriptors, current):
            if descriptor is None:
                descriptor = ParameterDescriptor()  # undeclared: the node gives the reason
            elif descriptor.read_only and now is not None and _python(now) == flat[name]:
                skipped.append(name)   # a dump of a node loads back: unchanged read-only values
                continue
            to_set.append(Parameter(name=name, value=value_from_python(flat[name],
                                                                       descriptor.type)))
        results = _set(node, target, to_set, args.timeout) if to_set else []
    failures = 0
    for parameter, result in zip(to_set, results):
        if result.successful:
            print(f'Set parameter {parameter.name} successful')
        else:
            failures += 1
            print(f'Set parameter {parameter.name} failed: {result.reason}', file=sys.stderr)
    for name in skipped:
        print(f'Set parameter {name} skipped: read-only and unchanged')
    if failures:
        raise CliError(f'{failures} of {len(names)} parameters from '
                       f"'{args.parameter_file}' were rejected by {target}")
    return 0
