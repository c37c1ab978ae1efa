"""Lockstep ticks per second against the bare rclpy floor, measured in one run.

Two kinds of measurement, interleaved run by run so that both see the same machine:

* **Bare rings** — N processes (2 or 3), each a node that republishes every
  ``sensor_msgs/JointState`` it receives on ``ring_i`` to ``ring_{i+1}`` (reliable QoS,
  depth 10, the signal QoS of the nodes); member 0 closes the ring and counts round trips.
  Each member is spun by the ``SingleThreadedExecutor`` (``default``) or rclpy's
  ``EventsExecutor`` (``events``). Reported: round trips/s and CPU ms per round trip per
  process (``/proc`` utime + stime over the measured trips).
* **The project's lockstep** — ``tank-control run FILE --mode lockstep --rtf 0`` as users run
  it (three node processes plus the harness with its recorder). Reported:
  ``metrics.json`` ``run.ticks_per_s`` (ticks over the wall time from un-pausing the plant to
  the last tick) and ``run.cpu_ms_per_tick`` of each process, and the ratio of ticks/s to
  the three-process ring with the events executor measured in the same run.

    .venv/bin/python bench/bench_lockstep.py [--runs 3] [--trips 3000] [--only ring|lockstep]
                                             [--baseline OTHER_PYTHON ...]
                                             [--scenario LABEL_PART ...]

Prints one line per measurement and a markdown table of medians (min–max) with the load
average before and after.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
WARMUP = 200              # round trips before the measured ones

#: (label, scenario file, simulated seconds) of the project's lockstep runs
SCENARIOS = (
    ('IPDT PID', REPO / 'config' / 'ipdt_pid.yaml', 300.0),
    ('tank two-loop PI', REPO / 'config' / 'scenarios' / 'tank_pi.yaml', 3000.0),
    ('tank MPCS-QP', REPO / 'config' / 'scenarios' / 'tank_mpcs_qp.yaml', 3000.0),
)


# ---------------------------------------------------------------- ring member (child process)
def ring_member(index: int, size: int, executor_kind: str, trips: int) -> int:
    """One member of the ring; member 0 starts it (re-sending the start until it returns)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental import EventsExecutor
    from sensor_msgs.msg import JointState

    from tank_control.harness.processes import process_cpu_seconds
    from tank_control.nodes.messages import SIGNAL_QOS

    rclpy.init()
    node = rclpy.create_node(f'ring_{index}')
    pub = node.create_publisher(JointState, f'ring_{(index + 1) % size}', SIGNAL_QOS)
    total = WARMUP + trips
    state = {'count': 0, 'marks': []}

    def on_message(msg: JointState) -> None:
        seq = msg.position[0]
        if seq == state['count'] - 1 and index != 0:
            pub.publish(msg)    # a re-sent start message: pass it on, do not count it
            return
        if seq != state['count']:
            return              # a copy of a re-sent start message coming back
        state['count'] += 1
        if state['count'] in (WARMUP, total):
            state['marks'].append((time.monotonic(), process_cpu_seconds(os.getpid())))
        if index == 0:
            if state['count'] >= total:
                return
            msg.position = [float(state['count'])]
        pub.publish(msg)

    node.create_subscription(JointState, f'ring_{index}', on_message, SIGNAL_QOS)
    executor = EventsExecutor() if executor_kind == 'events' else SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + 60
    start = JointState(name=['y'], position=[0.0])
    sent = -1.0
    while state['count'] < total and time.monotonic() < deadline:
        # Member 0 sends the start message, again every 0.5 s until the ring has carried it
        # once (a member not yet matched drops it); copies are ignored when they come back.
        if index == 0 and state['count'] == 0 and time.monotonic() - sent > 0.5:
            pub.publish(start)
            sent = time.monotonic()
        executor.spin_once(timeout_sec=0.1)
    # The others stay until the member before them has left, so that the last message they
    # passed on is delivered (member 0 leaves first, after the last round trip).
    while index != 0 and node.count_publishers(f'ring_{index}') > 0 \
            and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
    if len(state['marks']) < 2:
        print(f'ring member {index}: stopped at {state["count"]} of {total} messages',
              file=sys.stderr, flush=True)
    else:
        (t0, c0), (t1, c1) = state['marks']
        print(json.dumps({'index': index, 'rate': trips / (t1 - t0),
                          'cpu_ms': 1e3 * (c1 - c0) / trips}), flush=True)
    executor.remove_node(node)       # before destroy_node: see tank_control/nodes/runtime.py
    node.destroy_node()
    executor.shutdown()
    rclpy.try_shutdown()
    return 0 if len(state['marks']) == 2 else 1


def ring(size: int, executor_kind: str, trips: int, env: dict[str, str]) -> dict:
    """Round trips/s and CPU ms per trip of each member of one ring run."""
    procs = [subprocess.Popen([sys.executable, __file__, '--ring-member', str(i), str(size),
                               executor_kind, str(trips)], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for i in range(size)]
    outs, errors = [], []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        if proc.returncode != 0:
            errors.append(err[-2000:])
        else:
            outs.append(json.loads(out.strip().splitlines()[-1]))
    if errors:
        raise RuntimeError('ring failed: ' + ' | '.join(errors))
    return {'rate': outs[0]['rate'], 'cpu_ms': [o['cpu_ms'] for o in outs]}


# ---------------------------------------------------------------- the project's lockstep
def lockstep(config: Path, duration: float, env: dict[str, str],
             python: str = sys.executable) -> dict:
    out = Path(tempfile.mkdtemp(prefix='bench_lockstep_'))
    subprocess.run([python, '-m', 'tank_control.harness.cli', 'run', str(config),
                    '--out', str(out), '--mode', 'lockstep', '--rtf', '0',
                    '--duration', str(duration), '--quiet'], env=env, check=True,
                   stdout=subprocess.DEVNULL, cwd=out)   # cwd: `-m` must not import ./tank_control
    run = json.loads((out / 'metrics.json').read_text())['run']
    shutil.rmtree(out)
    return {'rate': run['ticks_per_s'], 'cpu_ms': run.get('cpu_ms_per_tick', {}),
            'missed': run['missed_samples']}


def _median_range(values: list[float], fmt: str = '.0f') -> str:
    return f'{statistics.median(values):{fmt}} ({min(values):{fmt}}–{max(values):{fmt}})'


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == '--ring-member':
        index, size, kind, trips = sys.argv[2:6]
        return ring_member(int(index), int(size), kind, int(trips))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--trips', type=int, default=3000, help='measured round trips per ring')
    parser.add_argument('--only', choices=('ring', 'lockstep'))
    parser.add_argument('--domain', type=int, default=97)
    parser.add_argument('--baseline', action='append', default=[],
                        help='the python of another installation (e.g. another checkout\'s '
                             '.venv/bin/python) whose lockstep runs too, in the same runs '
                             '(repeatable)')
    parser.add_argument('--scenario', action='append', default=[],
                        help='run only the lockstep scenarios whose label contains this '
                             '(repeatable; default: all)')
    args = parser.parse_args()
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    load_before = os.getloadavg()
    rings = [(size, kind) for size in (2, 3) for kind in ('default', 'events')]
    results: dict[str, list[dict]] = {}
    for run in range(args.runs):
        if args.only != 'lockstep':
            for size, kind in rings:
                label = f'bare ring, {size} processes, {kind} executor'
                r = ring(size, kind, args.trips, env)
                results.setdefault(label, []).append(r)
                print(f'run {run + 1}: {label}: {r["rate"]:.0f} round trips/s, CPU ms/trip '
                      f'{[round(c, 3) for c in r["cpu_ms"]]}', flush=True)
        if args.only != 'ring':
            pythons = [('', sys.executable)] + [(f' ({python})', python)
                                                for python in args.baseline]
            for label, config, duration in SCENARIOS:
                if args.scenario and not any(part in label for part in args.scenario):
                    continue
                for suffix, python in pythons:
                    r = lockstep(config, duration, env, python)
                    results.setdefault(label + suffix, []).append(r)
                    cpu = {k: round(v, 3) for k, v in r['cpu_ms'].items()}
                    print(f'run {run + 1}: {label}{suffix}: {r["rate"]:.0f} ticks/s, '
                          f'CPU ms/tick {cpu}, missed samples {r["missed"]}', flush=True)
    load_after = os.getloadavg()
    floor = results.get('bare ring, 3 processes, events executor')
    print(f'\nload average (1 min) before {load_before[0]:.2f}, after {load_after[0]:.2f}; '
          f'{args.runs} runs, medians (min–max)\n')
    print('| measurement | per s | ratio to the 3-process events ring | CPU ms per tick/trip, '
          'by process |')
    print('|---|---|---|---|')
    for label, rs in results.items():
        rates = [r['rate'] for r in rs]
        ratio = (_median_range([r / f['rate'] for r, f in zip(rates, floor)], '.2f')
                 if floor and len(floor) == len(rates) else '')
        first = rs[0]['cpu_ms']
        if not first:
            cpu = ''
        elif isinstance(first, dict):
            cpu = ', '.join(f'{name} {statistics.median(r["cpu_ms"][name] for r in rs):.2f}'
                            for name in first)
        else:
            cpu = ', '.join(f'{statistics.median(r["cpu_ms"][i] for r in rs):.2f}'
                            for i in range(len(first)))
        print(f'| {label} | {_median_range(rates)} | {ratio} | {cpu} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
