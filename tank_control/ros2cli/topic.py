"""``ros2 topic list|echo|pub|hz|info|type``: topics of the graph.

Message types are resolved by name (``pkg/msg/Type``); messages are printed and
parsed as YAML (see ``messages``). ``echo`` matches the QoS of the publishers it
finds (reliability, durability), like ros2cli.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections import deque
from typing import TYPE_CHECKING, Any

from tank_control.ros2cli.common import (
    CliError, add_daemon_argument, absolute_name, add_spin_time_argument, client_node, is_hidden, settle_graph,
    spin_until)
from tank_control.ros2cli.messages import from_yaml, resolve_type, restamp, to_python, to_yaml

if TYPE_CHECKING:
    from rclpy.node import Node

DISCOVERY_TIMEOUT = 10.0   # [s] default wait for a topic (and for --once: its first message)


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser('topic', help='Various topic related sub-commands',
                                 description='Various topic related sub-commands')
    verbs = parser.add_subparsers(title='Commands', dest='verb', metavar='VERB')
    verbs.required = True

    p = verbs.add_parser('list', help='Output a list of available topics',
                         description='Output a list of available topics')
    p.add_argument('-t', '--show-types', action='store_true',
                   help='additionally show the topic type')
    p.add_argument('-c', '--count-topics', action='store_true',
                   help='only display the number of topics discovered')
    p.add_argument('--include-hidden-topics', action='store_true',
                   help='consider hidden topics as well')
    add_spin_time_argument(p)
    add_daemon_argument(p)
    p.set_defaults(func=list_verb)

    p = verbs.add_parser('echo', help='Output messages from a topic',
                         description='Output messages from a topic as YAML, separated by ---')
    p.add_argument('topic_name', metavar='TOPIC', help="name of the topic (e.g. '/measurement')")
    p.add_argument('message_type', metavar='TYPE', nargs='?',
                   help="type of the message (e.g. 'sensor_msgs/msg/JointState'); "
                        'discovered from the graph if omitted')
    p.add_argument('--once', action='store_true', help='print the first message and exit')
    p.add_argument('--field', metavar='FIELD', help="print one field, e.g. 'header.stamp'")
    _timeout(p, 'seconds to wait for the topic to appear and, with --once, for the message '
                f'(default {DISCOVERY_TIMEOUT:g})')
    p.set_defaults(func=echo_verb)

    p = verbs.add_parser('pub', help='Publish a message to a topic',
                         description='Publish a message to a topic')
    p.add_argument('topic_name', metavar='TOPIC', help="name of the topic (e.g. '/setpoint')")
    p.add_argument('message_type', metavar='TYPE', help="type (e.g. 'std_msgs/msg/Float64')")
    p.add_argument('values', metavar='VALUES', nargs='?', default='{}',
                   help="values to fill the message with, YAML (e.g. '{data: 1.5}'); a "
                        "std_msgs/msg/Header field given as 'auto' or a builtin_interfaces/msg/"
                        "Time field given as 'now' holds the current (wall-clock) time, taken "
                        'again for each message published')
    p.add_argument('-r', '--rate', type=float, default=1.0, metavar='N',
                   help='publishing rate in Hz (default 1)')
    p.add_argument('-p', '--print', dest='print_nth', type=int, default=1, metavar='N',
                   help='print every N-th published message (0: none)')
    group = p.add_mutually_exclusive_group()
    group.add_argument('-1', '--once', action='store_true', help='publish one message and exit')
    group.add_argument('-t', '--times', type=int, default=0, metavar='N',
                       help='publish this number of times and then exit')
    p.add_argument('-w', '--wait-matching-subscriptions', type=int, default=None, metavar='N',
                   help='wait for N matching subscriptions before publishing (default 1 with '
                        '--once/--times, else 0)')
    p.add_argument('--keep-alive', type=float, default=0.1, metavar='SECONDS',
                   help='keep publishing node alive after the last message (default 0.1)')
    _timeout(p, 'seconds to wait for matching subscriptions and acknowledgements '
                f'(default {DISCOVERY_TIMEOUT:g})')
    p.set_defaults(func=pub_verb)

    p = verbs.add_parser('hz', help='Print the average publishing rate to screen',
                         description='Print the average receiving rate of a topic each second')
    p.add_argument('topic_name', metavar='TOPIC', help='name of the topic')
    p.add_argument('--window', '-w', type=int, default=10000, metavar='N',
                   help='window size, in # of messages, for calculating rate (default 10000)')
    _timeout(p, f'seconds to wait for the topic to appear (default {DISCOVERY_TIMEOUT:g})')
    p.set_defaults(func=hz_verb)

    p = verbs.add_parser('info', help='Print information about a topic',
                         description='Print information about a topic')
    p.add_argument('topic_name', metavar='TOPIC', help='name of the topic')
    p.add_argument('-v', '--verbose', action='store_true',
                   help='print detailed information: node, QoS of each endpoint')
    _timeout(p, 'seconds to wait for the topic to appear (default 5)', default=5.0)
    p.set_defaults(func=info_verb)

    p = verbs.add_parser('type', help='Print the type of a topic',
                         description='Print the type of a topic')
    p.add_argument('topic_name', metavar='TOPIC', help='name of the topic')
    _timeout(p, 'seconds to wait for the topic to appear (default 5)', default=5.0)
    p.set_defaults(func=type_verb)


def _timeout(parser: argparse.ArgumentParser, text: str,
             default: float = DISCOVERY_TIMEOUT) -> None:
    parser.add_argument('--timeout', type=float, default=default, metavar='SECONDS', help=text)


# graph helpers ------------------------------------------------------------------------------

def topic_types(node: 'Node', topic: str) -> list[str]:
    return next((types for name, types in node.get_topic_names_and_types() if name == topic), [])


def wait_for_topic(node: 'Node', topic: str, timeout: float) -> list[str]:
    """Types of ``topic`` once it is in the graph; CliError after ``timeout`` s."""
    if not spin_until(node, lambda: bool(topic_types(node, topic)), timeout):
        raise CliError(f"Unknown topic '{topic}' (not found within {timeout:g} s)")
    return topic_types(node, topic)


def _single_type(node: 'Node', topic: str, given: str | None, timeout: float) -> type:
    if given:
        return resolve_type(given)
    types = wait_for_topic(node, topic, timeout)
    if len(types) > 1:
        raise CliError(f"Topic '{topic}' has more than one type: {', '.join(types)}; "
                       'pass the TYPE argument')
    return resolve_type(types[0])


def subscriber_qos(node: 'Node', topic: str) -> Any:
    """Reliable/transient-local only if every known publisher offers it (ros2cli's rule)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    publishers = node.get_publishers_info_by_topic(topic)
    qos = QoSProfile(depth=10)
    if publishers and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for p in publishers):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    if any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    return qos


# verbs --------------------------------------------------------------------------------------

def list_verb(args: argparse.Namespace) -> int:
    with client_node() as node:
        settle_graph(node, args.spin_time)
        topics = sorted((name, types) for name, types in node.get_topic_names_and_types()
                        if args.include_hidden_topics or not is_hidden(name))
    if args.count_topics:
        print(len(topics))
        return 0
    for name, types in topics:
        print(f'{name} [{", ".join(types)}]' if args.show_types else name)
    return 0


def _field(msg: Any, path: str | None) -> Any:
    if not path:
        return msg
    value = msg
    for part in path.split('.'):
        if not hasattr(type(value), 'get_fields_and_field_types') or \
                part not in type(value).get_fields_and_field_types():
            raise CliError(f"Invalid field '{path}': no field '{part}'")
        value = getattr(value, part)
    return value


def _field_text(value: Any) -> str:
    import yaml
    if hasattr(type(value), 'get_fields_and_field_types'):
        return to_yaml(value)
    wrapped = to_python_value(value)
    return yaml.safe_dump(wrapped, default_flow_style=False, sort_keys=False, width=1000) \
        if isinstance(wrapped, (list, dict)) else f'{wrapped}\n'


def to_python_value(value: Any) -> Any:
    if hasattr(value, 'tolist'):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [to_python(v) if hasattr(type(v), 'get_fields_and_field_types') else v
                for v in value]
    if hasattr(value, 'typecode'):   # array.array
        return list(value)
    return value


def echo_verb(args: argparse.Namespace) -> int:
    topic = absolute_name(args.topic_name)
    with client_node() as node:
        msg_type = _single_type(node, topic, args.message_type, args.timeout)
        if args.field:
            _field(msg_type(), args.field)      # reject a wrong field before waiting
        received: deque[Any] = deque()
        node.create_subscription(msg_type, topic, lambda msg: received.append(msg),
                                 subscriber_qos(node, topic))
        wait = args.timeout if args.once else None
        while True:
            if not spin_until(node, lambda: bool(received), wait):
                raise CliError(f"No message received on '{topic}' within {args.timeout:g} s")
            while received:
                sys.stdout.write(_field_text(_field(received.popleft(), args.field)) + '---\n')
                sys.stdout.flush()
                if args.once:
                    return 0


#: most messages a counted ``topic pub`` keeps for readers that match late
MAX_KEPT = 1000


def pub_verb(args: argparse.Namespace) -> int:
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    topic = absolute_name(args.topic_name)
    msg_type = resolve_type(args.message_type)
    stamps: list[Any] = []          # header: auto / Time: now, stamped anew for each message
    msg = from_yaml(msg_type, args.values, stamps)
    if args.rate <= 0 or not math.isfinite(args.rate):
        raise CliError(f'--rate must be a positive number of Hz, got {args.rate:g}')
    times = 1 if args.once else args.times
    if times < 0:
        raise CliError(f'--times must be 0 (without end) or more, got {times}')
    wait_subs = args.wait_matching_subscriptions
    if wait_subs is None:
        wait_subs = 1 if times else 0
    # a counted publication keeps every message until each matched reader has it: a reader
    # that matched this writer a moment after the writer matched it (discovery is not
    # symmetric) gets all of them, not only the last of a history of one
    qos = QoSProfile(depth=min(times, MAX_KEPT) if times else 1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    with client_node() as node:
        publisher = node.create_publisher(msg_type, topic, qos)
        if wait_subs and not spin_until(
                node, lambda: publisher.get_subscription_count() >= wait_subs, args.timeout):
            raise CliError(f"Timed out waiting for {wait_subs} matching subscription(s) on "
                           f"'{topic}' ({args.timeout:g} s)")
        print('publisher: beginning loop')
        count = 0
        next_time = time.monotonic()
        while not times or count < times:
            spin_until(node, lambda: time.monotonic() >= next_time, None)  # noqa: B023 - waited on here
            if stamps:
                restamp(stamps)
            publisher.publish(msg)
            count += 1
            if args.print_nth and count % args.print_nth == 0:
                print(f'publishing #{count}: {msg!r}\n', flush=True)
            next_time += 1.0 / args.rate
        if not publisher.wait_for_all_acked(Duration(seconds=args.timeout)):
            raise CliError(f"Not every subscription of '{topic}' acknowledged the messages "
                           f'within {args.timeout:g} s')
        deadline = time.monotonic() + args.keep_alive
        spin_until(node, lambda: time.monotonic() >= deadline, None)
    return 0


def hz_report(stamps: list[float]) -> str:
    """ros2cli's two lines from receive times [s]: rate over the window, interval stats."""
    intervals = [b - a for a, b in zip(stamps, stamps[1:])]
    mean = statistics.fmean(intervals)
    std = statistics.pstdev(intervals)
    return (f'average rate: {1.0 / mean:.3f}\n'
            f'\tmin: {min(intervals):.3f}s max: {max(intervals):.3f}s '
            f'std dev: {std:.5f}s window: {len(stamps)}')


def hz_verb(args: argparse.Namespace) -> int:
    topic = absolute_name(args.topic_name)
    if args.window < 2:
        raise CliError(f'--window must be at least 2 messages, got {args.window}')
    with client_node() as node:
        msg_type = _single_type(node, topic, None, args.timeout)
        stamps: deque[float] = deque(maxlen=args.window)
        fresh = [0]

        def on_message(_: bytes) -> None:
            stamps.append(time.monotonic())
            fresh[0] += 1

        node.create_subscription(msg_type, topic, on_message, subscriber_qos(node, topic),
                                 raw=True)
        next_report = time.monotonic() + 1.0
        while True:
            spin_until(node, lambda: time.monotonic() >= next_report, None)  # noqa: B023 - waited on here
            next_report += 1.0
            if not fresh[0]:
                print('no new messages', flush=True)
            elif len(stamps) >= 2:
                print(hz_report(list(stamps)), flush=True)
            fresh[0] = 0


def info_verb(args: argparse.Namespace) -> int:
    topic = absolute_name(args.topic_name)
    with client_node() as node:
        wait_for_topic(node, topic, args.timeout)
        settle_graph(node, spin_time=0.3, snapshot_of=lambda: (
            topic_types(node, topic), len(node.get_publishers_info_by_topic(topic)),
            len(node.get_subscriptions_info_by_topic(topic))))
        types = topic_types(node, topic)
        publishers = node.get_publishers_info_by_topic(topic)
        subscriptions = node.get_subscriptions_info_by_topic(topic)
    lines = [f'Type: {", ".join(types)}']
    if args.verbose:
        lines.append('')
        lines.append(f'Publisher count: {len(publishers)}')
        lines.append('')
        lines += [f'{p}\n' for p in publishers]
        lines.append(f'Subscription count: {len(subscriptions)}')
        lines.append('')
        lines += [f'{s}\n' for s in subscriptions]
    else:
        lines.append(f'Publisher count: {len(publishers)}')
        lines.append(f'Subscription count: {len(subscriptions)}')
    print('\n'.join(lines).rstrip('\n'))
    return 0


def type_verb(args: argparse.Namespace) -> int:
    topic = absolute_name(args.topic_name)
    with client_node() as node:
        types = wait_for_topic(node, topic, args.timeout)
    print('\n'.join(types))
    return 0
