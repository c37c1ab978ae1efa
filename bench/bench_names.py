"""The plant's time to process one ``manipulated`` with many unknown channel names (issue 30 §4).

Starts plant_node (wall, IPDT, 20 ms ticks) of the checkout on ``PYTHONPATH``, waits for its
measurements, publishes ONE ``manipulated`` with N unknown names followed by a valid one
(``u = 1``) and reports how long until the plant integrates the valid one (its input callbacks
are busy with the big message until then), for each of ``--runs`` plant starts; the median is
printed.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_names.py --names 100000 --runs 3
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time

import rclpy
from sensor_msgs.msg import JointState

TS = 0.02


def one_run(node, names: int, watch_s: float) -> float:
    """Seconds from publishing the N-name message until the plant integrates the valid
    ``u = 1`` published right after it (IPDT, gain 1, no dead time: y leaves 0)."""
    seen: list[tuple[float, float]] = []          # (arrival, y)
    sub = node.create_subscription(
        JointState, 'measurement',
        lambda m: seen.append((time.monotonic(), m.position[0])), 100)
    pub = node.create_publisher(JointState, 'manipulated', 10)
    with tempfile.TemporaryDirectory() as tmp:
        params = os.path.join(tmp, 'plant.yaml')
        with open(params, 'w') as out:
            out.write('plant:\n  ros__parameters:\n    plant: ipdt\n    gain: 1.0\n'
                      f'    dead_time: 0.0\n    sample_time: {TS}\n    clock_mode: wall\n')
        log = open(os.path.join(tmp, 'plant.log'), 'w')  # noqa: SIM115 (closed in finally)
        proc = subprocess.Popen([sys.executable, '-m', 'tank_control.nodes.plant_node',
                                 '--ros-args', '--params-file', params],
                                stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 60
            while len(seen) < 20 or pub.get_subscription_count() == 0:
                assert time.monotonic() < deadline, 'plant did not start'
                rclpy.spin_once(node, timeout_sec=0.05)
            msg = JointState()
            msg.name = [f'x{i}' for i in range(names)]
            msg.position = [1.0] * names
            msg.header.stamp = node.get_clock().now().to_msg()
            valid = JointState(name=['u'], position=[1.0])
            sent = time.monotonic()
            pub.publish(msg)
            valid.header.stamp = node.get_clock().now().to_msg()
            pub.publish(valid)
            end = sent + watch_s
            took = watch_s
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.05)
                moved = [t for t, y in seen if t > sent and y != 0.0]
                if moved:
                    took = moved[0] - sent
                    break
            log.flush()
            with open(log.name) as text:
                lines = text.read().count('unknown channel')
            print(f'  {took:.3f} s, {lines} log lines on unknown channels', flush=True)
            return took
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()
            node.destroy_subscription(sub)
            node.destroy_publisher(pub)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--names', type=int, default=100_000)
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--watch', type=float, default=120.0,
                        help='seconds watched after the message (a longer stall shows as this)')
    args = parser.parse_args()
    if 'ROS_DOMAIN_ID' not in os.environ:      # a domain of its own (as the tests claim one)
        from tank_control.harness import domains
        os.environ['ROS_DOMAIN_ID'] = str(domains.claim()[0])
    rclpy.init()
    node = rclpy.create_node('bench_names_probe')
    gaps = [one_run(node, args.names, args.watch) for _ in range(args.runs)]
    print(f'names {args.names}: time until the next valid input is integrated [s] '
          f'{", ".join(f"{g:.3f}" for g in gaps)}; median {statistics.median(gaps):.3f} '
          f'(tick {TS} s; {args.watch:g} = not within the watch)')
    node.destroy_node()
    rclpy.shutdown()


if __name__ == '__main__':
    main()
