"""Wall time of `ros2` commands on a running graph, with and without the ros2 daemon:
p50 and p95 (nearest rank) of ``--calls`` calls of each, each in a fresh process as a user
typing it would see it, and the median CPU time (user + system) of the command's process: on a
busy host the wall time mostly waits for a core, the CPU time does not.

The graph: plant, controller and reference of config/ipdt_pid.yaml at real time, in a domain
claimed for the run (``harness.domains.claim``); the daemon gets a socket directory of its own
and is stopped at the end. The first call with the daemon starts it and is not counted (it
waits for a complete graph, 3.5 s); the others answer from its graph. Without the daemon
(``--no-daemon``) each call joins the graph and discovers it.

    .venv/bin/python bench/bench_ros2cli.py [--calls 20] [--daemon-only]
"""
from __future__ import annotations

import argparse
import math
import os
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
COMMANDS = [
    ('param', 'get', '/controller', 'kp'),
    ('param', 'set', '/controller', 'u_max', '100.0'),
    ('param', 'list', '/controller'),
    ('param', 'describe', '/controller', 'kp'),
    ('node', 'list'),
    ('topic', 'list'),
]
NODES = ('plant_node', 'controller_node', 'reference_node')


CPU: list[float] = []     # CPU seconds (user + system) of each timed command's process


def timed(argv: list[str], env: dict[str, str]) -> tuple[float, str]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    result = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    CPU.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    if result.returncode != 0:
        raise SystemExit(f'{" ".join(argv)} failed: {result.stderr.strip()}')
    return elapsed, result.stdout


def p95(times: list[float]) -> float:
    return sorted(times)[math.ceil(0.95 * len(times)) - 1]


def main() -> int:
    from tank_control.harness import domains
    from tank_control.ros2cli import daemon

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=20, help='calls per command (default 20)')
    parser.add_argument('--daemon-only', action='store_true',
                        help='time only the calls through the daemon')
    args = parser.parse_args()
    domain, lock = domains.claim()
    run_dir = tempfile.mkdtemp(prefix='ros2d-')
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               XDG_RUNTIME_DIR=run_dir, PYTHONPATH=str(REPO))
    env.pop(daemon.NO_DAEMON_ENV, None)
    params = str(REPO / 'config' / 'ipdt_pid.yaml')
    nodes = [subprocess.Popen([sys.executable, '-m', f'tank_control.nodes.{module}', '--ros-args',
                               '--params-file', params], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
             for module in NODES]
    ros2 = [sys.executable, '-m', 'tank_control.ros2cli.main']
    try:
        deadline = time.monotonic() + 60
        while timed(ros2 + ['node', 'list', '--no-daemon'], env)[1].split() != \
                ['/controller', '/plant', '/reference']:
            if time.monotonic() > deadline:
                raise SystemExit('the graph did not come up within 60 s')
        first, _ = timed(ros2 + ['node', 'list'], env)          # starts the daemon
        print(f'domain {domain}; load average {os.getloadavg()[0]:.1f}; {args.calls} calls '
              f'each [s]; the first call (starting the daemon): {first:.2f} s')
        print(f'{"command":46s} {"daemon p50":>10s} {"p95":>6s} {"cpu p50":>8s} '
              f'{"direct p50":>11s} {"p95":>6s} {"cpu p50":>8s}')
        for command in COMMANDS:
            rows = [(math.nan, math.nan, math.nan)] * 2
            for i, extra in enumerate(([], ['--no-daemon'])[:1 if args.daemon_only else 2]):
                CPU.clear()
                times = [timed(ros2 + list(command) + extra, env)[0] for _ in range(args.calls)]
                rows[i] = (statistics.median(times), p95(times), statistics.median(CPU))
            (dm, dp, dc), (nm, np_, nc) = rows
            print(f'{"ros2 " + " ".join(command):46s} {dm:10.2f} {dp:6.2f} {dc:8.2f} '
                  f'{nm:11.2f} {np_:6.2f} {nc:8.2f}')
    finally:
        daemon.stop_domain(str(domain), env)
        for node in nodes:
            os.killpg(node.pid, signal.SIGINT)
        for node in nodes:
            node.wait(timeout=30)
        lock.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
