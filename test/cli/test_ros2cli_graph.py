"""`ros2 topic|node|service` over real DDS against one test-only node (module scope)."""
from __future__ import annotations

import re
import signal

import pytest
import yaml
from support.param_node import SPECS
from support.ros2cli import Streaming, fixture_argv, ros2, ros2_parallel, until_complete

from tank_control.harness.processes import ProcessGroup

PERIOD = next(spec.default for spec in SPECS if spec.name == 'period')   # [s] of /signal
# Discovery waits of the commands that must succeed. The default (5 s) covers the 3.5 s a
# missed discovery exchange takes on a quiet host, not a CI host running other suites.
WAIT = ('--timeout', '30')


@pytest.fixture(scope='module')
def fixture_node(tmp_path_factory, ros_env):
    """The node ``/fixture`` for every test of this module."""
    with ProcessGroup(tmp_path_factory.mktemp('graph_logs')) as group:
        yield group.start('fixture', fixture_argv('fixture'), env=ros_env)


@pytest.fixture
def graph(fixture_node, probe):
    assert probe.wait_for(lambda: 'fixture' in probe.node.get_node_names(), 60), \
        fixture_node.tail()
    return probe


def test_topic_list_info_type_echo(graph, ros_env):
    # Echo subscribes to /signal, so it runs after the commands that count endpoints.
    listed, typed, info, verbose, topic_type = ros2_parallel(
        ros_env,
        ('topic', 'list'), ('topic', 'list', '-t'), ('topic', 'info', '/signal', *WAIT),
        ('topic', 'info', 'signal', '-v', *WAIT), ('topic', 'type', '/signal', *WAIT))
    once, field = ros2_parallel(ros_env, ('topic', 'echo', '--once', '/signal', *WAIT),
                                ('topic', 'echo', '/signal', '--once', '--field', 'name', *WAIT))
    for result in (listed, typed, info, verbose, topic_type, once, field):
        assert result.returncode == 0, (result.args, result.stderr)
    # A participant's endpoints are discovered one by one: wait for every line asserted.
    topics = {'/signal', '/command', '/parameter_events', '/rosout'}
    typed_lines = {'/signal [sensor_msgs/msg/JointState]', '/command [std_msgs/msg/Float64]'}
    listed = until_complete(ros_env, listed, lambda r: topics <= set(r.stdout.split()))
    typed = until_complete(ros_env, typed, lambda r: typed_lines <= set(r.stdout.splitlines()))

    assert topics <= set(listed.stdout.split())
    assert typed_lines <= set(typed.stdout.splitlines())
    assert info.stdout.splitlines() == ['Type: sensor_msgs/msg/JointState',
                                        'Publisher count: 1', 'Subscription count: 0']
    assert 'Node name: fixture' in verbose.stdout and 'Endpoint type: PUBLISHER' in verbose.stdout
    assert 'Reliability: RELIABLE' in verbose.stdout
    assert topic_type.stdout.strip() == 'sensor_msgs/msg/JointState'

    # One message as YAML, closed by the --- separator.
    body, separator, rest = once.stdout.partition('---\n')
    assert separator and rest == ''
    message = yaml.safe_load(body)
    assert message['name'] == ['y'] and len(message['position']) == 1
    assert message['position'][0] >= 1.0 and message['velocity'] == []
    assert set(message['header']['stamp']) == {'sec', 'nanosec'}
    assert message['header']['stamp']['sec'] > 1_000_000_000      # wall-clock stamp
    assert field.stdout == '- y\n---\n'


def test_topic_echo_stream_and_hz(graph, ros_env):
    echo = Streaming(ros_env, 'topic', 'echo', '/signal', '--field', 'position')
    hz = Streaming(ros_env, 'topic', 'hz', '/signal', '--window', '20')
    try:
        assert echo.read_until(lambda lines: lines.count('---') >= 3, 20), echo.lines
        counts = [float(line[2:]) for line in echo.lines if line.startswith('- ')]
        assert counts == sorted(counts) and len(set(counts)) == len(counts)
        assert echo.interrupt() == 0, echo.stderr

        # Two lines per report: average rate, then min/max/std dev/window.
        assert hz.read_until(lambda lines: any('window: 20' in line for line in lines), 20), \
            hz.lines
        rate_line = [line for line in hz.lines if line.startswith('average rate:')][-1]
        stats = hz.lines[hz.lines.index(rate_line) + 1]
        rate = float(rate_line.split(':')[1])
        # (How close the rate comes to 1 / PERIOD depends on the host's load: not asserted.)
        assert rate > 0
        found = re.fullmatch(r'\tmin: ([\d.]+)s max: ([\d.]+)s std dev: ([\d.]+)s window: 20',
                             stats)
        assert found, stats
        low, high, _ = map(float, found.groups())
        # the mean period lies between min and max, up to the printed rounding (3 decimals)
        assert low - 5e-4 <= 1.0 / rate <= high + 5e-4
        assert hz.interrupt(signal.SIGTERM) == 0, hz.stderr
    finally:
        echo.close()
        hz.close()


def test_topic_pub(graph, ros_env):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    floats, states = [], []
    graph.node.create_subscription(Float64, '/cli_test/value', floats.append, 10)
    graph.node.create_subscription(JointState, '/cli_test/state', states.append, 10)
    once, times = ros2_parallel(
        ros_env,
        ('topic', 'pub', '--once', '/cli_test/value', 'std_msgs/msg/Float64', '{data: 1.5}', *WAIT),
        ('topic', 'pub', '-t', '3', '-r', '20', '/cli_test/state', 'sensor_msgs/JointState',
         '{header: {stamp: {sec: 7, nanosec: 5}, frame_id: tank}, name: [h, T_out], '
         'position: [12, 30.5]}', *WAIT))
    assert once.returncode == 0, once.stderr
    assert once.stdout.startswith('publisher: beginning loop\npublishing #1: std_msgs.msg.Float64')
    assert times.returncode == 0, times.stderr
    assert times.stdout.count('publishing #') == 3
    assert graph.wait_for(lambda: floats and len(states) == 3, 30)
    assert floats[0].data == 1.5
    state = states[-1]
    assert (state.header.stamp.sec, state.header.stamp.nanosec) == (7, 5)
    assert state.header.frame_id == 'tank'
    assert list(state.name) == ['h', 'T_out'] and list(state.position) == [12.0, 30.5]

    bad_field, bad_type, bad_yaml = ros2_parallel(
        ros_env,
        ('topic', 'pub', '--once', '/x', 'std_msgs/msg/Float64', '{value: 1}'),
        ('topic', 'pub', '--once', '/x', 'std_msgs/msg/NoSuchType', '{}'),
        ('topic', 'pub', '--once', '/x', 'std_msgs/msg/Float64', '{data: [1'))
    for result, words in ((bad_field, ('value', 'data')), (bad_type, ('NoSuchType',)),
                          (bad_yaml, ('YAML',))):
        assert result.returncode == 1, result.stdout
        assert len(result.stderr.strip().splitlines()) == 1
        assert all(word in result.stderr for word in words), result.stderr



def test_topic_pub_stamps_header_auto_and_time_now_anew_for_each_message(graph, ros_env):
    """ros2cli's stamp keywords over DDS: ``header: auto`` and a Time field ``now`` carry the
    publishing process's wall-clock time, taken again for each message of ``--times``; any
    other string in such a field is one line on stderr, exit 1."""
    import time

    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    states, clocks = [], []
    graph.node.create_subscription(JointState, '/cli_test/stamped', states.append, 10)
    graph.node.create_subscription(Clock, '/cli_test/clock_now', clocks.append, 10)
    before = time.time_ns()
    stamped, clock, bad = ros2_parallel(
        ros_env,
        ('topic', 'pub', '-t', '3', '-r', '20', '/cli_test/stamped', 'sensor_msgs/msg/JointState',
         '{header: auto, name: [y], position: [1.0]}', *WAIT),
        ('topic', 'pub', '--once', '/cli_test/clock_now', 'rosgraph_msgs/msg/Clock',
         '{clock: now}', *WAIT),
        ('topic', 'pub', '--once', '/x', 'sensor_msgs/msg/JointState', '{header: now}'))
    after = time.time_ns()
    assert stamped.returncode == 0, stamped.stderr
    assert clock.returncode == 0, clock.stderr
    assert graph.wait_for(lambda: len(states) == 3 and clocks, 30)
    ns = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in states]
    assert before <= ns[0] < ns[1] < ns[2] <= after, (before, ns, after)
    assert all(m.header.frame_id == '' and list(m.name) == ['y'] for m in states)
    assert before <= clocks[0].clock.sec * 1_000_000_000 + clocks[0].clock.nanosec <= after
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
    assert "'header'" in bad.stderr and "'auto'" in bad.stderr, bad.stderr

def _sections(text: str) -> dict[str, set[str]]:
    """`ros2 node info` output as {section title: its entry lines, stripped}."""
    sections = re.split(r'\n  (?=\S)', text)
    return {title.strip(): {line.strip() for line in body.splitlines()}
            for title, _, body in (section.partition(':\n') for section in sections[1:])}


def _has_entries(by_title: dict[str, set[str]], expected: dict[str, set[str]]) -> bool:
    return all(entries <= by_title.get(title, set()) for title, entries in expected.items())


def test_node_and_service_verbs(graph, ros_env):
    nodes, info, services, params, trigger, set_bool = ros2_parallel(
        ros_env,
        ('node', 'list'), ('node', 'info', '/fixture', *WAIT), ('service', 'list', '-t'),
        ('param', 'list', '--timeout', '2'),
        ('service', 'call', '/fixture/trigger', 'std_srvs/srv/Trigger', *WAIT),
        ('service', 'call', 'fixture/enable', 'std_srvs/srv/SetBool', '{data: true}', *WAIT))
    for result in (nodes, info, services, params, trigger, set_bool):
        assert result.returncode == 0, (result.args, result.stderr)
    nodes = until_complete(ros_env, nodes, lambda r: '/fixture' in r.stdout.split())
    service_lines = {'/fixture/trigger [std_srvs/srv/Trigger]',
                     '/fixture/get_parameters [rcl_interfaces/srv/GetParameters]'}
    services = until_complete(ros_env, services,
                              lambda r: service_lines <= set(r.stdout.splitlines()))
    probe_silent = f"'{graph.node.get_fully_qualified_name()}' did not answer"
    params = until_complete(ros_env, params, lambda r: '/fixture:' in r.stdout.split() and
                            probe_silent in r.stderr)
    assert '/fixture' in nodes.stdout.splitlines()
    assert not any('_ros2cli' in line for line in nodes.stdout.splitlines())   # hidden

    expected = {'Subscribers': {'/command: std_msgs/msg/Float64'},
                'Publishers': {'/signal: sensor_msgs/msg/JointState'},
                'Service Servers': {'/fixture/trigger: std_srvs/srv/Trigger',
                                    '/fixture/enable: std_srvs/srv/SetBool'}}
    info = until_complete(ros_env, info, lambda r: _has_entries(_sections(r.stdout), expected))
    assert info.stdout.startswith('/fixture\n  Subscribers:\n')
    by_title = _sections(info.stdout)
    for title, entries in expected.items():
        assert entries <= by_title[title], (title, info.stdout)

    assert service_lines <= set(services.stdout.splitlines())

    # Without a node name: every node with parameter services, its parameters indented.
    lines = params.stdout.splitlines()
    assert '/fixture:' in lines and '  gain' in lines[lines.index('/fixture:'):]
    # The test's own probe node is not spinning: reported on stderr, the rest still listed.
    assert probe_silent in params.stderr

    assert trigger.stdout.startswith(
        'requester: making request: std_srvs.srv.Trigger_Request()\n\nresponse:\n'
        'std_srvs.srv.Trigger_Response(success=True, message=')
    assert 'SetBool_Request(data=True)' in set_bool.stdout
    assert 'SetBool_Response(success=True' in set_bool.stdout
    got = ros2(ros_env, 'param', 'get', '/fixture', 'enabled')
    assert got.stdout.strip() == 'Boolean value is: True'   # the service reached the node


def test_missing_things_fail_instead_of_hanging(graph, ros_env):
    """Each wait ends at its --timeout with one line on stderr (ros2_parallel kills at 120 s:
    eleven processes starting at once take a while on a loaded 2-core host)."""
    results = ros2_parallel(
        ros_env,
        ('param', 'get', '/no_such_node', 'gain', '--timeout', '1'),
        ('param', 'set', '/no_such_node', 'gain', '1.0', '--timeout', '1'),
        ('param', 'dump', '/no_such_node', '--timeout', '1'),
        ('node', 'info', '/no_such_node', '--timeout', '1'),
        ('topic', 'echo', '--once', '/no_such_topic', '--timeout', '1'),
        ('topic', 'echo', '--once', '/silent_1', 'std_msgs/msg/Float64', '--timeout', '1'),
        ('topic', 'info', '/no_such_topic', '--timeout', '1'),
        ('topic', 'hz', '/no_such_topic', '--timeout', '1'),
        ('topic', 'pub', '--once', '/silent_2', 'std_msgs/msg/Float64', '--timeout', '1'),
        ('service', 'call', '/no_such/service', 'std_srvs/srv/Trigger', '--timeout', '1'),
        ('service', 'call', '/fixture/trigger', 'std_srvs/srv/NoSuch', '--timeout', '1'),
        timeout=120)
    for result in results:
        assert result.returncode == 1, (result.args, result.stdout)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and 'Traceback' not in result.stderr, (result.args, lines)
    assert 'Node not found' in results[0].stderr
    assert "Unable to find node '/no_such_node'" in results[3].stderr
    assert "'/no_such_topic'" in results[4].stderr
