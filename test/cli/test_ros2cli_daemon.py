"""The ros2 daemon (tank_control/ros2cli/daemon.py; docs/ros2cli.md, "The daemon"): started on
demand by a command, it answers from a graph it keeps; one per ROS_DOMAIN_ID and discovery
settings, on a private unix socket; `ros2 daemon start|stop|status`; it ends on stop or after its
idle timeout; hostile input on its socket is answered with an error and changes nothing; a
command that cannot use it discovers the graph itself.

Each test gives its daemon a socket directory of its own (``XDG_RUNTIME_DIR`` in tmp_path) and
stops it at its end."""
from __future__ import annotations

import json
import os
import socket
import stat
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.ros2cli import fixture_argv, ros2

from tank_control.ros2cli import daemon
from tank_control.ros2cli.common import CliError

WAIT = 60.0


@pytest.fixture
def daemon_env(ros_env: dict[str, str], tmp_path: Path) -> Iterator[dict[str, str]]:
    """``ros_env`` with a socket directory of the test's own; the daemon is stopped (or
    killed) at the end."""
    run = tmp_path / 'run'
    run.mkdir(mode=0o700)
    env = {**ros_env, 'XDG_RUNTIME_DIR': str(run)}
    env.pop(daemon.NO_DAEMON_ENV, None)
    yield env
    path = daemon.socket_path(env)
    try:
        status = daemon._ping(path)
    except CliError:            # the test's own untrusted socket file
        path.unlink()
        return
    daemon.stop(path)
    if status is not None and daemon._alive(status['pid']):
        os.kill(status['pid'], 9)


def wait_until(condition, timeout: float = WAIT) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)     # polling a process table / file system: no event to wait on
    return True


def exchange(path: Path, payload: bytes, timeout: float = WAIT) -> dict:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(str(path))
        sock.sendall(payload)
        data = b''
        while not data.endswith(b'\n'):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    return json.loads(data)


def test_commands_start_the_daemon_and_answer_as_without_it(procs, daemon_env):
    procs.start('fixture', fixture_argv('fixture'), env=daemon_env)
    procs.start('other', fixture_argv('other'), env=daemon_env)
    assert ros2(daemon_env, 'daemon', 'status').stdout.strip() == 'The daemon is not running'
    # the first listing starts the daemon and waits for a complete graph
    listed = ros2(daemon_env, 'node', 'list')
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == ['/fixture', '/other']
    status = ros2(daemon_env, 'daemon', 'status').stdout
    assert status.startswith('The daemon is running (pid ')
    path = daemon.socket_path(daemon_env)
    assert path.parent == Path(daemon_env['XDG_RUNTIME_DIR'])
    assert stat.S_ISSOCK(path.lstat().st_mode) and stat.S_IMODE(path.lstat().st_mode) == 0o600
    pid = daemon._ping(path)['pid']
    # the same answers with and without the daemon
    for args in (('param', 'get', '/fixture', 'gain'), ('param', 'list', '/fixture'),
                 ('param', 'describe', '/fixture', 'count'), ('node', 'list')):
        via, direct = ros2(daemon_env, *args), ros2(daemon_env, *args, '--no-daemon')
        assert (via.returncode, via.stdout, via.stderr) == \
            (direct.returncode, direct.stdout, direct.stderr), args
    refused = ros2(daemon_env, 'param', 'set', '/fixture', 'gain', '11.0')
    assert refused.returncode == 1 and 'gain' in refused.stderr
    done = ros2(daemon_env, 'param', 'set', '/fixture', 'gain', '2.5')
    assert (done.returncode, done.stdout.strip()) == (0, 'Set parameter successful')
    got = ros2(daemon_env, 'param', 'get', '/fixture', 'gain', '--no-daemon')
    assert got.stdout.strip() == 'Double value is: 2.5'
    assert daemon._ping(path)['pid'] == pid          # one daemon served them all
    # stopped cleanly: the process ends, the socket goes
    assert ros2(daemon_env, 'daemon', 'stop').stdout.strip() == 'The daemon has been stopped'
    assert wait_until(lambda: not daemon._alive(pid))
    assert not path.exists()
    assert ros2(daemon_env, 'daemon', 'status').stdout.strip() == 'The daemon is not running'


def test_one_daemon_per_domain_and_discovery_settings(tmp_path):
    base = {'XDG_RUNTIME_DIR': str(tmp_path), 'ROS_DOMAIN_ID': '7'}
    paths = {daemon.socket_path(env) for env in (
        base, {**base, 'ROS_DOMAIN_ID': '8'},
        {**base, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'},
        {**base, 'FASTDDS_DEFAULT_PROFILES_FILE': '/etc/profile.xml'})}
    assert len(paths) == 4
    assert all(p.name.startswith('ros2-daemon-d7-') for p in paths - {
        daemon.socket_path({**base, 'ROS_DOMAIN_ID': '8'})})
    assert daemon.socket_path(base) == daemon.socket_path(dict(base))     # stable


def test_hostile_requests_get_an_error_and_the_daemon_keeps_serving(daemon_env):
    started = ros2(daemon_env, 'daemon', 'start', '--idle-timeout', '600')
    assert started.returncode == 0, started.stderr
    path = daemon.socket_path(daemon_env)
    # a client that connects and sends nothing does not hold the others up
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as idle:
        idle.connect(str(path))
        assert exchange(path, b'{"op": "ping"}\n')['ok'] is True
    cases = {
        b'not json\n': 'not JSON',
        b'\xff\xfe\n': 'not JSON',
        b'[1, 2]\n': '"op"',
        b'{"op": "format_disk"}\n': 'unknown op',
        b'{"op": "run", "argv": "param get"}\n': '"argv"',
        b'{"op": "run", "argv": [1, 2]}\n': '"argv"',
        b'{"op": "run", "argv": ["run", "tank_control", "plant_node"]}\n': 'not served',
        b'{"op": "run", "argv": ["topic", "pub", "/x", "std_msgs/msg/Float64"]}\n': 'not served',
        b'x' * (daemon.MAX_REQUEST + 10): 'longer than',
    }
    for payload, error in cases.items():
        answer = exchange(path, payload)
        assert answer['ok'] is False and error in answer['error'], (payload[:40], answer)
    # arguments its parser refuses: argparse's message, exit code 2, the daemon still there
    answer = exchange(path, b'{"op": "run", "argv": ["param", "get", "--bogus"]}\n')
    assert answer['ok'] is True and answer['rc'] == 2 and 'error:' in answer['stderr']
    assert exchange(path, b'{"op": "ping"}\n')['ok'] is True


def test_a_socket_others_could_use_is_never_trusted(daemon_env, procs):
    path = daemon.socket_path(daemon_env)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as fake:
        fake.bind(str(path))
        fake.listen(1)
        os.chmod(path, 0o666)
        status = ros2(daemon_env, 'daemon', 'status')
        assert status.returncode == 1
        assert status.stderr.strip() == (f'{path}: not a private socket of this user; the ros2 '
                                          'daemon does not use it (remove it)')
        # a command discovers the graph itself instead
        procs.start('fixture', fixture_argv('fixture'), env=daemon_env)
        got = ros2(daemon_env, 'param', 'get', '/fixture', 'count', '--timeout', '60')
        assert (got.returncode, got.stdout.strip()) == (0, 'Integer value is: 5'), got.stderr


def test_an_idle_daemon_ends_by_itself(daemon_env):
    started = ros2(daemon_env, 'daemon', 'start', '--idle-timeout', '1')
    assert started.returncode == 0, started.stderr
    pid = int(started.stdout.split('pid ')[1].split(',')[0])
    path = daemon.socket_path(daemon_env)
    assert wait_until(lambda: not daemon._alive(pid))
    assert not path.exists()
