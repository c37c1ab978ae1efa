"""Wall time of one `ros2` command (start-up, discovery, the call), median of several runs.

Starts the test-only node (test/fixtures/param_node.py) in a private ROS domain
and times each command in a fresh process, as a user typing it would see it.

    .venv/bin/python bench/bench_ros2cli.py [--runs 5]
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMANDS = [
    ('--help',),
    ('param', 'get', '/fixture', 'gain'),
    ('param', 'set', '/fixture', 'gain', '2.0'),
    ('param', 'dump', '/fixture'),
    ('topic', 'echo', '--once', '/signal'),
    ('service', 'call', '/fixture/trigger', 'std_srvs/srv/Trigger'),
    ('node', 'info', '/fixture'),
    ('node', 'list'),
    ('topic', 'list'),
]


def timed(argv: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    result = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f'{" ".join(argv)} failed: {result.stderr.strip()}')
    return elapsed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=5, help='runs per command (default 5)')
    parser.add_argument('--domain', type=int, default=97, help='ROS_DOMAIN_ID (default 97)')
    args = parser.parse_args()
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    node = subprocess.Popen([sys.executable, str(REPO / 'test' / 'fixtures' / 'param_node.py')],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        ros2 = [sys.executable, '-m', 'tank_control.ros2cli.main']
        timed(ros2 + ['param', 'get', '/fixture', 'gain', '--timeout', '30'], env)   # node is up
        print(f'load average: {os.getloadavg()[0]:.1f}; median of {args.runs} runs [s]')
        for command in COMMANDS:
            times = [timed(ros2 + list(command), env) for _ in range(args.runs)]
            print(f'{statistics.median(times):6.2f}  ros2 {" ".join(command)}')
    finally:
        os.killpg(node.pid, signal.SIGINT)
        node.wait(timeout=10)
    return 0


if __name__ == '__main__':
    sys.exit(main())
