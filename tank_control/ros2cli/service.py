"""``ros2 service list|call|type``: services of the graph."""
from __future__ import annotations

import argparse
import math
import time

from tank_control.ros2cli.common import (
    CliError, add_daemon_argument, absolute_name, add_spin_time_argument, call_service, client_node, is_hidden,
    settle_graph, spin_until)
from tank_control.ros2cli.messages import from_yaml, resolve_type

CALL_TIMEOUT = 10.0   # [s] default wait for the service to appear and answer


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser('service', help='Various service related sub-commands',
                                 description='Various service related sub-commands')
    verbs = parser.add_subparsers(title='Commands', dest='verb', metavar='VERB')
    verbs.required = True

    p = verbs.add_parser('list', help='Output a list of available services',
                         description='Output a list of available services')
    p.add_argument('-t', '--show-types', action='store_true',
                   help='additionally show the service type')
    p.add_argument('-c', '--count-services', action='store_true',
                   help='only display the number of services discovered')
    p.add_argument('--include-hidden-services', action='store_true',
                   help='consider hidden services as well')
    add_spin_time_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=list_verb)

    p = verbs.add_parser('call', help='Call a service', description='Call a service')
    p.add_argument('service_name', metavar='NAME',
                   help="name of the ROS service to call (e.g. '/plant/reset')")
    p.add_argument('service_type', metavar='TYPE',
                   help="type of the ROS service (e.g. 'std_srvs/srv/Trigger')")
    p.add_argument('values', metavar='VALUES', nargs='?', default='{}',
                   help="values to fill the request with, YAML (e.g. '{data: true}')")
    p.add_argument('-r', '--rate', type=float, default=None, metavar='N',
                   help='repeat the call at this rate in Hz (until Ctrl-C)')
    p.add_argument('--timeout', type=float, default=CALL_TIMEOUT, metavar='SECONDS',
                   help='seconds to wait for the service to appear and answer '
                        f'(default {CALL_TIMEOUT:g})')
    p.set_defaults(func=call_verb)

    p = verbs.add_parser('type', help='Output a service type', description='Output a service type')
    p.add_argument('service_name', metavar='NAME', help='name of the ROS service')
    p.add_argument('--timeout', type=float, default=5.0, metavar='SECONDS',
                   help='seconds to wait for the service to appear (default 5)')
    p.set_defaults(func=type_verb)


def list_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        settle_graph(node, args.spin_time)
        services = sorted((name, types) for name, types in node.get_service_names_and_types()
                          if args.include_hidden_services or not is_hidden(name))
    if args.count_services:
        print(len(services))
        return 0
    for name, types in services:
        print(f'{name} [{", ".join(types)}]' if args.show_types else name)
    return 0


def call_verb(args: argparse.Namespace) -> int:
    name = absolute_name(args.service_name)
    srv_type = resolve_type(args.service_type, kind='srv')
    request = from_yaml(srv_type.Request, args.values)
    if args.rate is not None and (args.rate <= 0 or not math.isfinite(args.rate)):
        raise CliError(f'--rate must be a positive number of Hz, got {args.rate:g}')
    with client_node() as node:
        next_time = time.monotonic()
        while True:
            print(f'requester: making request: {request!r}\n', flush=True)
            response = call_service(node, srv_type, name, request, args.timeout)
            print(f'response:\n{response!r}\n', flush=True)
            if args.rate is None:
                return 0
            next_time += 1.0 / args.rate
            spin_until(node, lambda: time.monotonic() >= next_time, None)  # noqa: B023 - waited on here


def type_verb(args: argparse.Namespace) -> int:
    name = absolute_name(args.service_name)

    def types() -> list[str]:
        return next((t for n, t in node.get_service_names_and_types() if n == name), [])

    with client_node() as node:
        if not spin_until(node, lambda: bool(types()), args.timeout):
            raise CliError(f"Unknown service '{name}' (not found within {args.timeout:g} s)")
        print('\n'.join(types()))
    return 0
