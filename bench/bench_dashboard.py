"""Dashboard: screen updates per second and dropped samples, six signals at 100 Hz.

A publisher node in this process sends ``measurement`` (channels y1, y2), ``setpoint`` (y1, y2)
and ``manipulated`` (u1, u2) every 10 ms on a wall timer — six signals sampled at 100 Hz —
stamped with a running tick number; dashboard_node (a separate process, as users run it) serves
a page opened in headless Chromium. Over ``--seconds`` the page counts its redraws (screen
updates) and the rows it received per topic; dropped = published − received in the page.
Each run is on a fresh ROS_DOMAIN_ID claimed like the tests'.

    .venv/bin/python bench/bench_dashboard.py [--runs 3] [--seconds 20]

Prints one line per run and a markdown table of medians (min–max) with the load average.
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
TOPICS = {'measurement': ('y1', 'y2'), 'setpoint': ('y1', 'y2'), 'manipulated': ('u1', 'u2')}
PERIOD = 0.01          # s: 100 Hz


def one_run(seconds: float) -> dict[str, float]:
    sys.path.insert(0, str(REPO / 'test'))
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from support.browser import dashboard_url, headless_chromium

    from tank_control.harness import domains
    from tank_control.harness.processes import ProcessGroup
    from tank_control.nodes.messages import SIGNAL_QOS, to_joint_state

    domain, lock = domains.claim()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    logs = Path(tempfile.mkdtemp(prefix='bench_dashboard_'))
    with ProcessGroup(logs) as group:
        dash = group.start('dashboard', [sys.executable, '-m', 'tank_control.nodes.dashboard_node',
                                         '--ros-args', '-p', 'port:=0'], env=env)
        url = dashboard_url(dash)
        rclpy.init()
        node = rclpy.create_node('bench_publisher')
        pubs = {t: node.create_publisher(JointState, t, SIGNAL_QOS) for t in TOPICS}
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        sent = {'n': 0}

        def tick() -> None:
            k = sent['n']
            for topic, names in TOPICS.items():
                pubs[topic].publish(to_joint_state(k * 10_000_000, names,
                                                   [k * 1e-3 + i for i in range(len(names))]))
            sent['n'] += 1
        try:
            with headless_chromium() as page:
                page.get(url)
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline and page.execute_script(
                        'return document.getElementById("connection").textContent') != 'live':
                    time.sleep(0.1)
                # publish until the dashboard has matched our publishers, then measure
                while (len(node.get_subscriptions_info_by_topic('/measurement')) == 0
                       and time.monotonic() < deadline):
                    executor.spin_once(timeout_sec=0.1)
                timer = node.create_timer(PERIOD, tick)
                executor.spin_once(timeout_sec=0.5)          # warm-up
                frames0 = page.execute_script('return window.tankDashboard.stats.frames')
                start, n0 = time.monotonic(), sent['n']
                while time.monotonic() - start < seconds:
                    executor.spin_once(timeout_sec=0.05)
                node.destroy_timer(timer)
                elapsed = time.monotonic() - start
                frames = page.execute_script('return window.tankDashboard.stats.frames') - frames0
                published = sent['n']
                # let the last batch arrive (one update period plus delivery)
                end = time.monotonic() + 10
                script = 'return window.tankDashboard.stats.byTopic'
                while time.monotonic() < end and min(
                        page.execute_script(script).get(t, 0) for t in TOPICS) < published:
                    time.sleep(0.1)
                received = page.execute_script(script)
                lost = page.execute_script('return window.tankDashboard.stats.lost')
        finally:
            executor.remove_node(node)
            node.destroy_node()
            rclpy.try_shutdown()
    lock.close()
    return {'updates_per_s': frames / elapsed, 'rate_hz': (published - n0) / elapsed,
            'published': published * len(TOPICS),
            'dropped': sum(published - received.get(t, 0) for t in TOPICS),
            'lost_in_store': lost}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--seconds', type=float, default=20.0)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    results = []
    for run in range(args.runs):
        r = one_run(args.seconds)
        results.append(r)
        print(f'run {run + 1}: {r["updates_per_s"]:.1f} updates/s, publishing at '
              f'{r["rate_hz"]:.1f} Hz, {r["published"]} messages ({r["published"] * 2} samples), '
              f'dropped {r["dropped"]}, lost in the store {r["lost_in_store"]}', flush=True)
    load_after = os.getloadavg()[0]

    def cell(key: str, fmt: str) -> str:
        values = [r[key] for r in results]
        return (f'{format(statistics.median(values), fmt)} '
                f'({format(min(values), fmt)}–{format(max(values), fmt)})')
    print(f'\nload average {load_before:.2f} before, {load_after:.2f} after; medians of '
          f'{args.runs} (min–max)\n')
    print('| screen updates/s | publishing rate Hz | messages published | dropped | lost in store |')
    print('|---|---|---|---|---|')
    print(f'| {cell("updates_per_s", ".1f")} | {cell("rate_hz", ".1f")} | '
          f'{cell("published", ".0f")} | {cell("dropped", ".0f")} | {cell("lost_in_store", ".0f")} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
