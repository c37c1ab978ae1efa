"""Test isolation for a real DDS graph.

* Every pytest session takes its own ``ROS_DOMAIN_ID``, held by an exclusive
  file lock, so two test runs on one machine never see each other.
* Discovery stays on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).
* Processes started through the ``procs`` fixture run in their own process
  groups and are stopped (SIGINT → SIGTERM → SIGKILL) at the end of the test.
"""
from __future__ import annotations

import fcntl
import os
import random
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tank_control.harness.processes import ProcessGroup

REPO = Path(__file__).resolve().parents[1]
_LOCK_DIR = Path(tempfile.gettempdir()) / 'tank_control_domains'
_DOMAIN_IDS = list(range(1, 101))   # valid for LOCALHOST discovery on Linux


def _claim_domain_id() -> tuple[int, object]:
    """Lock a free domain id for this process's lifetime (the lock dies with it)."""
    _LOCK_DIR.mkdir(exist_ok=True)
    candidates = _DOMAIN_IDS[:]
    random.SystemRandom().shuffle(candidates)
    for domain_id in candidates:
        handle = open(_LOCK_DIR / f'{domain_id}.lock', 'w')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain_id, handle
    raise RuntimeError('no free ROS_DOMAIN_ID for this test session')


_DOMAIN_ID, _DOMAIN_LOCK = _claim_domain_id()
os.environ['ROS_DOMAIN_ID'] = str(_DOMAIN_ID)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '0')


@pytest.fixture(scope='session')
def ros_env() -> dict[str, str]:
    """Environment for child processes: this session's domain, unbuffered output."""
    env = dict(os.environ)
    env['PYTHONUNBUFFERED'] = '1'
    return env


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


@pytest.fixture
def probe(rclpy_session: None) -> Iterator['Probe']:
    """A node inside the test process, with an event-driven wait."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    node = rclpy.create_node(f'test_probe_{os.getpid()}_{time.monotonic_ns()}')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    yield Probe(node, executor)
    executor.remove_node(node)
    node.destroy_node()


class Probe:
    """Wraps a test node: ``wait_for(cond, timeout)`` spins until ``cond()`` holds."""

    def __init__(self, node, executor) -> None:
        self.node = node
        self.executor = executor

    def wait_for(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while not condition():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.1, remaining))
        return True
