"""Test isolation for a real DDS graph.

* Every pytest session takes its own ``ROS_DOMAIN_ID``, held by an exclusive
  file lock and on which no DDS participant of this host was found (``domains.claim``), so
  two test runs on one machine never see each other, nor a graph started by hand. The
  session says it holds the domain (``domains.EXCLUSIVE_ENV``): a harness run in it does not
  wait ``harness.discovery_time`` for a graph that was there before; a test that puts a
  foreign graph on the domain takes the environment ``shared_ros_env`` instead.
* Discovery stays on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), with the
  harness's announcement profile (``domains.start_profile_env``) for this process and the
  nodes its tests start.
* Processes started through the ``procs`` fixture run in their own process
  groups and are stopped (SIGINT → SIGTERM → SIGKILL) at the end of the test.
* ``--no-graph`` (``make test-fast``) runs only the tests that need no ROS graph: a test
  is marked ``ros`` when it uses a graph fixture (``GRAPH_FIXTURES``) or says so with
  ``pytest.mark.ros``; the others run with DDS switched off (an out-of-range
  ``ROS_DOMAIN_ID`` for child processes, ``rclpy.init`` failing in this one), so an
  unmarked test that does need the graph fails with a message saying to mark it.
* Test files run longest first (``FILE_SECONDS``, ``test/durations.json``; pytest-xdist takes
  them in that order with ``--no-loadscope-reorder``): the last files a worker takes are short,
  so the workers finish together. ``--record-durations`` rewrites the table from a run.
"""
from __future__ import annotations

import collections
import contextlib
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tank_control.harness import domains
from tank_control.harness.processes import ProcessGroup

REPO = Path(__file__).resolve().parents[1]
#: Fixtures that put a test on the ROS graph (it is then marked ``ros``).
GRAPH_FIXTURES = frozenset({'procs', 'probe', 'module_probe', 'rclpy_session', 'ros_env',
                            'node_cmd'})
#: Wall seconds each test file took in a full run (``--record-durations``), to run the long
#: ones first; a file not in it is estimated from its tests (``ESTIMATE_S``).
FILE_SECONDS = Path(__file__).with_name('durations.json')
#: Estimated seconds of a test on the graph and of one without, for a file not yet timed.
ESTIMATE_S = {'ros': 4.0, 'other': 0.2}
#: A domain id no participant can use (Fast DDS refuses ids above 232).
NO_GRAPH_DOMAIN = '250'
_DOMAIN_LOCK: object = None   # held for the session's lifetime

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
# a ros2 daemon started by a test's `ros2` command ends with the session (ros2_daemons), or
# after this many idle seconds should the session be killed
os.environ['TANK_CONTROL_ROS2_DAEMON_IDLE'] = '300'
# This process's participant lives as long as the session and the nodes its tests start come
# and go: all announce themselves as a run's processes do (domains.start_profile_env: often at
# first, then every 0.5 s instead of 3), so a node started by a test is found at once, not at
# the session participant's next announcement. Set before anything creates a participant
# (Fast DDS reads the variable once); a test that names a profile of its own keeps it.
os.environ.update(domains.start_profile_env(os.environ))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption('--no-graph', action='store_true',
                     help='run only the tests that need no ROS graph (make test-fast)')
    parser.addoption('--record-durations', action='store_true',
                     help=f'write each test file\'s wall seconds to {FILE_SECONDS.name}')


def pytest_configure(config: pytest.Config) -> None:
    global _DOMAIN_LOCK
    config.addinivalue_line('markers', 'ros: the test needs a ROS graph (DDS); '
                            'deselected by --no-graph')
    config.addinivalue_line('markers', 'slow: more than ~10 s without a graph; '
                            'left out of make test-fast')
    if config.getoption('--no-graph'):
        os.environ['ROS_DOMAIN_ID'] = NO_GRAPH_DOMAIN
        import rclpy

        def refuse(what: str) -> Callable[..., None]:
            def refused(*args: object, **kwargs: object) -> None:
                pytest.fail(f'this test {what} under --no-graph: mark it @pytest.mark.ros or '
                            'give it a graph fixture', pytrace=False)
            return refused
        rclpy.init = refuse('starts ROS (rclpy.init)')
        domains.claim = refuse('claims a ROS_DOMAIN_ID (domains.claim; sweep --ros does)')
    elif _DOMAIN_LOCK is None:
        domain_id, _DOMAIN_LOCK = domains.claim()
        os.environ['ROS_DOMAIN_ID'] = str(domain_id)
        os.environ[domains.EXCLUSIVE_ENV] = str(domain_id)   # held: no discovery wait in runs


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if GRAPH_FIXTURES.intersection(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.ros)
    if config.getoption('--no-graph'):
        keep = [i for i in items if i.get_closest_marker('ros') is None]
        config.hook.pytest_deselected(items=[i for i in items if i not in keep])
        items[:] = keep
    items.sort(key=_longest_first(items))        # stable: a file's tests keep their order


def _file_of(nodeid: str) -> str:
    return nodeid.split('::', 1)[0]


def _longest_first(items: list[pytest.Item]) -> Callable[[pytest.Item], tuple[float, str]]:
    """Sort key: files by their recorded seconds, longest first (then by name)."""
    try:
        recorded = json.loads(FILE_SECONDS.read_text())
    except (OSError, ValueError):
        recorded = {}
    estimate: collections.Counter[str] = collections.Counter()
    for item in items:
        kind = 'ros' if item.get_closest_marker('ros') else 'other'
        estimate[_file_of(item.nodeid)] += ESTIMATE_S[kind]

    def key(item: pytest.Item) -> tuple[float, str]:
        name = _file_of(item.nodeid)
        seconds = recorded.get(name)
        return (-(seconds if isinstance(seconds, (int, float)) else estimate[name]), name)
    return key


_FILE_TIMES: collections.Counter[str] = collections.Counter()


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """(``--record-durations``) each phase's wall seconds, by file; with pytest-xdist the
    controller receives every worker's reports."""
    _FILE_TIMES[_file_of(report.nodeid)] += report.duration


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if (session.config.getoption('--record-durations') and _FILE_TIMES
            and not hasattr(session.config, 'workerinput')):
        table = {name: round(seconds, 1) for name, seconds in sorted(_FILE_TIMES.items())}
        FILE_SECONDS.write_text(json.dumps(table, indent=0) + '\n')


@pytest.fixture(scope='session', autouse=True)
def ros2_daemons() -> Iterator[None]:
    """Stops the ros2 daemons (``ros2cli/daemon``) of this session's domain at its end:
    a `ros2` command run by a test starts one on demand."""
    yield
    domain = os.environ.get('ROS_DOMAIN_ID', '')
    if domain and domain != NO_GRAPH_DOMAIN:
        from tank_control.ros2cli import daemon
        daemon.stop_domain(domain)


@pytest.fixture(scope='session')
def ros_env() -> dict[str, str]:
    """Environment for child processes: this session's domain, unbuffered output."""
    env = dict(os.environ)
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture(scope='session')
def shared_ros_env(ros_env: dict[str, str]) -> dict[str, str]:
    """``ros_env`` for a test that starts a graph of its own beside a harness run (the
    domain is then not the run's alone): the run looks for another graph for its whole
    ``harness.discovery_time``."""
    return {k: v for k, v in ros_env.items() if k != domains.EXCLUSIVE_ENV}


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[ProcessGroup]:
    """Start processes for one test; all are stopped when the test ends."""
    group = ProcessGroup(tmp_path / 'logs')
    try:
        yield group
    finally:
        group.stop_all()


@pytest.fixture
def node_cmd() -> Callable[..., list[str]]:
    """argv that runs a node module of this checkout with the test's interpreter."""
    def build(module: str, *ros_args: str) -> list[str]:
        argv = [sys.executable, '-m', f'tank_control.nodes.{module}']
        if ros_args:
            argv += ['--ros-args', *ros_args]
        return argv
    return build


@pytest.fixture(scope='session')
def rclpy_session() -> Iterator[None]:
    """rclpy initialised once for the in-test probe nodes."""
    import rclpy
    rclpy.init()
    yield
    rclpy.try_shutdown()


@contextlib.contextmanager
def probe_node() -> Iterator['Probe']:
    """A node inside the test process, with an event-driven wait (rclpy initialised)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    node = rclpy.create_node(f'test_probe_{os.getpid()}_{time.monotonic_ns()}')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        yield Probe(node, executor)
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()


@pytest.fixture
def probe(rclpy_session: None) -> Iterator['Probe']:
    """A node inside the test process, with an event-driven wait."""
    with probe_node() as node:
        yield node


@pytest.fixture(scope='module')
def module_probe(rclpy_session: None) -> Iterator['Probe']:
    """``probe`` shared by the tests of a module (with a module-scoped graph they share)."""
    with probe_node() as node:
        yield node


class Probe:
    """Wraps a test node: ``wait_for(cond, timeout)`` spins until ``cond()`` holds."""

    def __init__(self, node, executor) -> None:
        self.node = node
        self.executor = executor
        self._primed: list[Any] = []          # parameter clients whose empty set was answered

    def wait_for(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while not condition():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.1, remaining))
        return True

    def read(self, send: Callable[[], Any], timeout: float = 30.0) -> Any:
        """The result of a service request without effect (a read, an empty set, a command
        refused without effect), ``send()`` again every 2 s without an answer: a response is
        lost while the server has not matched the client's response reader, which happens
        while discovery goes on (tank_control/nodes/services.py). AssertionError after
        ``timeout`` s."""
        futures = [send()]
        deadline = time.monotonic() + timeout
        while not self.wait_for(lambda: any(f.done() for f in futures), 2.0):
            assert time.monotonic() < deadline, f'no answer in {timeout:g} s'
            futures.append(send())
        return next(f for f in futures if f.done()).result()

    def set_once(self, client: Any, name: str, value: Any, timeout: float = 30.0) -> Any:
        """The result of setting parameter ``name`` through ``client`` (an
        ``AsyncParameterClient``), sent once — a set has an effect — after an empty set on the
        same client had its answer (``read``): the node has then matched the client's response
        reader, so the response cannot be lost (tank_control/nodes/services.py)."""
        from rclpy.parameter import Parameter
        if client not in self._primed:
            self.read(lambda: client.set_parameters([]))
            self._primed.append(client)
        future = client.set_parameters([Parameter(name, value=value)])
        assert self.wait_for(future.done, timeout), f'no answer to setting {name} in {timeout:g} s'
        return future.result().results[0]
