"""Lockstep ticks per second: plant + PID controller + reference in three processes.

Runs config/ipdt_pid.yaml (IPDT + MDP PID, plant and controller at 0.1 s) in
lockstep as fast as possible (``real_time_factor: 0``) and reads the plant's
tick counter from ``/diagnostics`` (published every 0.5 s, so the measurement
adds no subscriber to the signal topics). The rate of a run is the tick count
difference over the wall time between the first diagnostics after a warm-up
and the last one of the window.

    .venv/bin/python bench/bench_lockstep.py [--runs 5] [--window 5] [--config FILE]
                                             [--no-anticipate]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def one_run(config: Path, window: float, warmup: float, domain: int,
            anticipate: bool = True) -> float:
    """Ticks per second of one run."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    from tank_control.core.params_file import read as read_params_file
    from tank_control.core.params_file import write as write_params_file
    from tank_control.harness.processes import ProcessGroup

    params = read_params_file(config)
    params['plant'].update({'real_time_factor': 0.0, 'diagnostics_period': 0.5,
                            'clock_mode': 'lockstep'})
    params['reference']['lockstep.anticipate'] = anticipate
    nodes = ('plant', 'controller', 'reference')
    tmp = Path(tempfile.mkdtemp(prefix='bench_lockstep_'))
    path = write_params_file({n: params[n] for n in ('/**', *nodes) if n in params},
                             tmp / 'scenario.yaml')
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    samples: list[tuple[float, int]] = []

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == 'plant':
                values = {kv.key: kv.value for kv in status.values}
                samples.append((time.monotonic(), int(values['ticks'])))

    rclpy.init()
    node = rclpy.create_node('bench_lockstep')
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    with ProcessGroup(tmp / 'logs') as group:
        for name in nodes:
            group.start(name, [sys.executable, '-m', f'tank_control.nodes.{name}_node',
                               '--ros-args', '--params-file', str(path)], env=env)
        # Warm-up: until the loop runs (ticks advancing), then the measuring window.
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (len(samples) < 2 or samples[-1][1] < 50):
            rclpy.spin_once(node, timeout_sec=0.1)
        start = time.monotonic() + warmup
        while time.monotonic() < start + window:
            rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.try_shutdown()
    inside = [(t, k) for t, k in samples if t >= start]
    if len(inside) < 2:
        raise RuntimeError(f'too few diagnostics in the window; logs in {tmp / "logs"}')
    (t0, k0), (t1, k1) = inside[0], inside[-1]
    return (k1 - k0) / (t1 - t0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--window', type=float, default=5.0, help='measured wall seconds per run')
    parser.add_argument('--warmup', type=float, default=1.0)
    parser.add_argument('--config', type=Path, default=REPO / 'config' / 'ipdt_pid.yaml')
    parser.add_argument('--domain', type=int, default=97)
    parser.add_argument('--no-anticipate', action='store_true',
                        help='reference answers each tick only on its /clock (3 hops per tick)')
    args = parser.parse_args()
    rates = []
    for i in range(args.runs):
        rate = one_run(args.config, args.window, args.warmup, args.domain,
                       anticipate=not args.no_anticipate)
        rates.append(rate)
        print(f'run {i + 1}: {rate:.0f} ticks/s')
    print(f'median of {len(rates)} runs: {statistics.median(rates):.0f} ticks/s '
          f'(min {min(rates):.0f}, max {max(rates):.0f})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
