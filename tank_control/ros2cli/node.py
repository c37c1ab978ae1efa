"""``ros2 node list|info``: nodes in the graph and their endpoints."""
from __future__ import annotations

import argparse

from tank_control.ros2cli.common import (
    CliError, add_daemon_argument, absolute_name, add_spin_time_argument, add_timeout_argument, client_node,
    is_hidden, settle_graph, split_node_name, wait_for_node)


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser('node', help='Various node related sub-commands',
                                 description='Various node related sub-commands')
    verbs = parser.add_subparsers(title='Commands', dest='verb', metavar='VERB')
    verbs.required = True

    p = verbs.add_parser('list', help='Output a list of available nodes',
                         description='Output a list of available nodes')
    p.add_argument('-a', '--all', action='store_true', help='display all nodes even hidden ones')
    p.add_argument('-c', '--count-nodes', action='store_true',
                   help='only display the number of nodes discovered')
    add_spin_time_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=list_verb)

    p = verbs.add_parser('info', help='Output information about a node',
                         description='Output information about a node')
    p.add_argument('node_name', metavar='NODE', help='node name to request information')
    p.add_argument('--include-hidden', action='store_true', help='display hidden topics, '
                   'services, and actions as well')
    add_timeout_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=info_verb)


def list_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        settle_graph(node, args.spin_time)
        names = sorted(n for n in node.get_fully_qualified_node_names()
                       if args.all or not is_hidden(n))
    if args.count_nodes:
        print(len(names))
    else:
        for name in names:
            print(name)
    return 0


def _section(title: str, entries: list[tuple[str, list[str]]], hidden: bool) -> list[str]:
    lines = [f'  {title}:']
    lines += [f'    {name}: {", ".join(types)}' for name, types in sorted(entries)
              if hidden or not is_hidden(name)]
    return lines


def info_verb(args: argparse.Namespace) -> int:
    from rclpy.action import (get_action_client_names_and_types_by_node,
                              get_action_server_names_and_types_by_node)
    full_name = absolute_name(args.node_name)
    name, namespace = split_node_name(full_name)
    with client_node() as node:
        try:
            wait_for_node(node, full_name, args.timeout)
        except CliError:
            raise CliError(f"Unable to find node '{full_name}' (waited {args.timeout:g} s)") \
                from None

        def endpoints() -> tuple:
            return (node.get_subscriber_names_and_types_by_node(name, namespace),
                    node.get_publisher_names_and_types_by_node(name, namespace),
                    node.get_service_names_and_types_by_node(name, namespace),
                    node.get_client_names_and_types_by_node(name, namespace),
                    get_action_server_names_and_types_by_node(node, name, namespace),
                    get_action_client_names_and_types_by_node(node, name, namespace))

        # The name is known before every endpoint is: wait until the endpoints settle.
        settle_graph(node, spin_time=0.3, snapshot_of=lambda: repr(endpoints()))
        subs, pubs, servers, clients, action_servers, action_clients = endpoints()
    lines = [full_name]
    for title, entries in (('Subscribers', subs), ('Publishers', pubs),
                           ('Service Servers', servers), ('Service Clients', clients),
                           ('Action Servers', action_servers), ('Action Clients', action_clients)):
        lines += _section(title, entries, args.include_hidden)
    print('\n'.join(lines))
    return 0
