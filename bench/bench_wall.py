"""Wall-clock timing of the loop against the bare rclpy floor, measured in one run.

Interleaved run by run so that every measurement sees the same machine:

* **Bare timer** — one process, one node, one rclpy timer every ``--period`` on the steady
  clock, spun like the project's nodes (``EventsExecutor`` driven by ``spin_once``,
  nodes/runtime.py). Reported: period deviation ``|Δt_call − period|`` p50/p99 [ms].
* **Bare ping-pong** — two processes; ``ping`` publishes a ``sensor_msgs/JointState`` every
  period stamped with the system time, ``pong`` echoes it with its receive time (the signal
  QoS of the nodes). Reported: one-way latency (both legs pooled, receive − send on the one
  system clock of this machine) p50/p99 [ms].
* **Bare observed relay** — the wall loop's topology with nothing but the hops: ``source``
  publishes a ``JointState`` every period (steady-clock timer) stamped with its sample instant
  on the system clock (instant 0 at the first call, like the plant's ``time_origin``),
  ``relay`` republishes each one at once with the same stamp (a measurement-triggered
  controller with no work), and ``observer`` takes both with its arrival time, as the
  harness's recorder does. Reported with the very formulas of the wall rows below (period
  deviation, age, latency): the floor those rows are compared with, like for like.
* **The project's wall mode** — ``tank-control run config/ipdt_pid.yaml --mode wall`` at the
  same period (plant and controller ``sample_time``), as users run it, once with
  ``controller.trigger=timer`` and once with ``measurement``; read from ``run.mcap`` (the
  recorder's arrival times, system clock) and ``metrics.json``:
  ``plant dev`` — deviation of the spacing of successive measurement arrivals from the
  spacing of their stamps, ``|Δarrival − Δstamp|`` (the plant timer's jitter plus the hop to
  the recorder's) p99; ``age`` — arrival − stamp of a measurement (a stamp equal to the sample
  instant: timer lateness plus one hop) p50/p99; ``latency`` — measurement → actuation:
  arrival of ``manipulated`` answering a measurement − arrival of that measurement (trigger
  measurement: the one stamped like it; timer: the next one) p50/p99; ``missed`` —
  ``run.missed_samples``.
  With ``--baseline EXE`` also another checkout's ``tank-control`` (its own default trigger,
  or ``--baseline-trigger``).

    .venv/bin/python bench/bench_wall.py [--runs 3] [--duration 20] [--period 0.01]
                                         [--baseline /work/main/.venv/bin/tank-control]
                                         [--baseline-trigger timer|measurement]

Prints one line per measurement and a markdown table of medians (min–max) over the runs, with
the load average before and after.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / 'config' / 'ipdt_pid.yaml'
SKIP_S = 1.0          # the first second of each bare measurement / run is not counted


# ------------------------------------------------------------------ children (one process each)
_EXECUTORS: dict[int, object] = {}


def _spin(node, seconds: float, done=lambda: False) -> None:
    """Spin ``node`` like the project's nodes (EventsExecutor, ``spin_once``) for ``seconds``
    or until ``done()``. One executor per node for the whole process: a node moved to a new
    EventsExecutor keeps a backlog of the messages that came in between (each later event
    takes the oldest message), measured here as a constant 90 ms of extra age."""
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    executor = _EXECUTORS.get(id(node))
    if executor is None:
        executor = _EXECUTORS[id(node)] = EventsExecutor()
        executor.add_node(node)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end and not done():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass                              # the pong, stopped by SIGTERM


def child_timer(period: float, duration: float) -> dict:
    import rclpy
    from rclpy.clock import Clock, ClockType
    rclpy.init()
    node = rclpy.create_node('bare_timer')
    calls: list[int] = []
    node.create_timer(period, lambda: calls.append(time.monotonic_ns()),
                      clock=Clock(clock_type=ClockType.STEADY_TIME))
    _spin(node, duration)
    node.destroy_node()
    rclpy.try_shutdown()
    t = np.array(calls, dtype=np.int64)
    t = t[t >= t[0] + int(SKIP_S * 1e9)]
    dev = np.abs(np.diff(t) - period * 1e9) / 1e6
    return {'dev_p50': float(np.percentile(dev, 50)), 'dev_p99': float(np.percentile(dev, 99)),
            'calls': int(len(t))}


def _republish(name: str, source: str, target: str, seconds: float, change=None) -> dict:
    """A node republishing every JointState of ``source`` on ``target`` at once (after
    ``change(msg)``, if given) for ``seconds``; stopped earlier by SIGTERM."""
    import rclpy
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import SIGNAL_QOS
    rclpy.init()
    node = rclpy.create_node(name)
    pub = node.create_publisher(JointState, target, SIGNAL_QOS)

    def again(msg: JointState) -> None:
        if change is not None:
            change(msg)
        pub.publish(msg)
    node.create_subscription(JointState, source, again, SIGNAL_QOS)
    _spin(node, seconds)
    node.destroy_node()
    rclpy.try_shutdown()
    return {}


def child_pong(duration: float) -> dict:
    """Echoes each ping with its receive time added (system clock, ns)."""
    def stamp(msg) -> None:
        msg.position = [msg.position[0], float(time.time_ns())]
    return _republish('bare_pong', 'bench_ping', 'bench_pong', duration + 15.0, stamp)


def child_ping(period: float, duration: float) -> dict:
    import rclpy
    from rclpy.clock import Clock, ClockType
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import SIGNAL_QOS, ns_to_stamp, stamp_to_ns
    rclpy.init()
    node = rclpy.create_node('bare_ping')
    pub = node.create_publisher(JointState, 'bench_ping', SIGNAL_QOS)
    legs: list[float] = []
    state = {'first': None, 'seq': 0}

    def on_pong(msg: JointState) -> None:
        now = time.time_ns()
        if state['first'] is None:
            state['first'] = now
        if now - state['first'] < SKIP_S * 1e9:
            return
        back = msg.position[1]
        legs.extend([(back - stamp_to_ns(msg.header.stamp)) / 1e6, (now - back) / 1e6])

    def send() -> None:
        msg = JointState()
        msg.header.stamp = ns_to_stamp(time.time_ns())
        msg.position = [float(state['seq'])]
        state['seq'] += 1
        pub.publish(msg)
    node.create_subscription(JointState, 'bench_pong', on_pong, SIGNAL_QOS)
    node.create_timer(period, send, clock=Clock(clock_type=ClockType.STEADY_TIME))
    # until the pong answered (discovery), then the measured duration
    _spin(node, 15.0, done=lambda: state['first'] is not None)
    _spin(node, duration)
    node.destroy_node()
    rclpy.try_shutdown()
    lat = np.array(legs)
    return {'lat_p50': float(np.percentile(lat, 50)), 'lat_p99': float(np.percentile(lat, 99)),
            'messages': int(len(lat) // 2)}


def child_source(period: float, duration: float) -> dict:
    """Publishes ``bench_sample`` every period stamped with its sample instant."""
    import rclpy
    from rclpy.clock import Clock, ClockType
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import SIGNAL_QOS, ns_to_stamp
    rclpy.init()
    node = rclpy.create_node('bare_source')
    pub = node.create_publisher(JointState, 'bench_sample', SIGNAL_QOS)
    period_ns = int(round(period * 1e9))
    origin: dict[str, int] = {}

    def send() -> None:
        steady = time.monotonic_ns()
        if not origin:
            origin.update(steady=steady, system=time.time_ns())
        k = round((steady - origin['steady']) / period_ns)     # the instant this call is for
        msg = JointState()
        msg.header.stamp = ns_to_stamp(origin['system'] + k * period_ns)
        msg.position = [float(k)]
        pub.publish(msg)
    # the relay and the observer are matched before the measured time starts
    while pub.get_subscription_count() < 2:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.create_timer(period, send, clock=Clock(clock_type=ClockType.STEADY_TIME))
    _spin(node, duration)
    node.destroy_node()
    rclpy.try_shutdown()
    return {}


def child_relay(duration: float) -> dict:
    return _republish('bare_relay', 'bench_sample', 'bench_answer', duration + 30.0)


def child_observer(period: float, duration: float) -> dict:
    """Arrival times of ``bench_sample`` and ``bench_answer``, measured like the wall rows."""
    import rclpy
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import SIGNAL_QOS, stamp_to_ns
    rclpy.init()
    node = rclpy.create_node('bare_observer')
    rows: dict[str, list[tuple[int, int]]] = {'/measurement': [], '/manipulated': []}

    def keep(topic: str):
        def on(msg: JointState) -> None:
            rows[topic].append((stamp_to_ns(msg.header.stamp), time.time_ns()))
        return on
    node.create_subscription(JointState, 'bench_sample', keep('/measurement'), SIGNAL_QOS)
    node.create_subscription(JointState, 'bench_answer', keep('/manipulated'), SIGNAL_QOS)
    _spin(node, 30.0, done=lambda: bool(rows['/measurement']))     # until the source runs
    _spin(node, duration)
    node.destroy_node()
    rclpy.try_shutdown()
    rec = {k: np.array(sorted(v, key=lambda r: r[1]), dtype=np.int64).reshape(-1, 2)
           for k, v in rows.items()}
    return observed_metrics(rec, 'measurement')


# ------------------------------------------------------------------------------- measurements
def _child(*args: str, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, __file__, '--child', *args], env=env,
                            stdout=subprocess.PIPE, text=True)


def _result(proc: subprocess.Popen) -> dict:
    out, _ = proc.communicate(timeout=300)
    return json.loads(out.strip().splitlines()[-1])


def bare(period: float, duration: float, env: dict) -> dict:
    timer = _result(_child('timer', str(period), str(duration), env=env))
    pong = _child('pong', str(period), str(duration), env=env)
    ping = _child('ping', str(period), str(duration), env=env)
    result = {**timer, **_result(ping)}
    pong.terminate()
    pong.wait(timeout=30)
    observer = _child('observer', str(period), str(duration), env=env)
    relay = _child('relay', str(period), str(duration), env=env)
    source = _child('source', str(period), str(duration), env=env)
    _result(source)
    result['observed'] = _result(observer)
    relay.terminate()
    relay.wait(timeout=30)
    return result


def read_recording(path: Path) -> dict[str, np.ndarray]:
    """topic → array of (stamp, arrival) [ns] of /measurement and /manipulated, by arrival."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    rows: dict[str, list[tuple[int, int]]] = {'/measurement': [], '/manipulated': []}
    with path.open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, msg, decoded in reader.iter_decoded_messages(topics=list(rows)):
            stamp = decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec
            rows[channel.topic].append((stamp, msg.log_time))
    return {k: np.array(sorted(v, key=lambda r: r[1]), dtype=np.int64).reshape(-1, 2)
            for k, v in rows.items()}


def observed_metrics(rec: dict[str, np.ndarray], trigger: str) -> dict:
    """Period deviation, age and latency [ms] from (stamp, arrival) rows of the measurement
    and the answer (``/manipulated``), each in order of arrival; the first ``SKIP_S`` left out."""
    y, u = rec['/measurement'], rec['/manipulated']
    y = y[y[:, 0] >= y[:, 0].min() + int(SKIP_S * 1e9)]
    dev = np.abs(np.diff(y[:, 1]) - np.diff(y[:, 0])) / 1e6
    age = (y[:, 1] - y[:, 0]) / 1e6
    if trigger == 'measurement':
        answer = dict(u.tolist())          # stamp → arrival of the answer stamped like it
        lat = np.array([answer[s] - a for s, a in y.tolist() if s in answer]) / 1e6
    else:                                  # the next manipulated after each measurement
        i = np.searchsorted(u[:, 1], y[:, 1])
        ok = i < len(u)
        lat = (u[i[ok], 1] - y[ok, 1]) / 1e6
    return {'dev_p99': float(np.percentile(dev, 99)), 'age_p50': float(np.percentile(age, 50)),
            'age_p99': float(np.percentile(age, 99)), 'lat_p50': float(np.percentile(lat, 50)),
            'lat_p99': float(np.percentile(lat, 99))}


def wall_metrics(out: Path, period: float, trigger: str) -> dict:
    run = json.loads((out / 'metrics.json').read_text())['run']
    return {**observed_metrics(read_recording(out / 'run.mcap'), trigger),
            'missed': run['missed_samples'], 'ticks': run['ticks']}


def wall_run(exe: str, period: float, duration: float, trigger: str | None, out: Path,
             env: dict) -> dict:
    cmd = [exe, 'run', str(SCENARIO), '--out', str(out), '--mode', 'wall', '--quiet',
           '--duration', str(duration), '--set', f'plant.sample_time={period}',
           '--set', f'controller.sample_time={period}']
    if trigger is not None:
        cmd += ['--set', f'controller.trigger={trigger}']
    # from the checkout's own root: node processes started with ``python -m`` import the
    # package from the working directory first
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600,
                          cwd=Path(exe).resolve().parents[2])
    if done.returncode != 0:
        raise RuntimeError(f'{" ".join(cmd)}: {done.stderr[-2000:]}')
    return wall_metrics(out, period, trigger or 'timer')


def _fmt(values: list[float]) -> str:
    return (f'{statistics.median(values):.2f} ({min(values):.2f}–{max(values):.2f})'
            if values else '–')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--duration', type=float, default=20.0, help='[s] per measurement')
    parser.add_argument('--period', type=float, default=0.01, help='[s] timer / sample period')
    parser.add_argument('--baseline', help="another checkout's tank-control executable")
    parser.add_argument('--baseline-trigger', choices=('timer', 'measurement'),
                        help="the baseline's controller.trigger (default: its own default)")
    parser.add_argument('--child', nargs='+', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, *rest = args.child
        if kind == 'timer':
            print(json.dumps(child_timer(float(rest[0]), float(rest[1]))))
        elif kind == 'ping':
            print(json.dumps(child_ping(float(rest[0]), float(rest[1]))))
        elif kind == 'source':
            print(json.dumps(child_source(float(rest[0]), float(rest[1]))))
        elif kind == 'observer':
            print(json.dumps(child_observer(float(rest[0]), float(rest[1]))))
        elif kind == 'relay':
            print(json.dumps(child_relay(float(rest[1]))))
        else:
            print(json.dumps(child_pong(float(rest[1]))))
        return 0
    from tank_control.harness import domains
    domain, lock = domains.claim()          # a free ROS_DOMAIN_ID, held while measuring
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    exe = str(Path(sys.executable).with_name('tank-control'))
    cases = [('trigger timer', exe, 'timer'), ('trigger measurement', exe, 'measurement')]
    if args.baseline:
        cases.insert(0, (f'baseline ({args.baseline_trigger or "its default"})', args.baseline,
                         args.baseline_trigger))
    load_before = os.getloadavg()
    results: dict[str, list[dict]] = {'bare': []}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            b = bare(args.period, args.duration, env)
            results['bare'].append(b)
            o = b['observed']
            print(f'run {run}: bare timer dev p99 {b["dev_p99"]:.3f} ms, ping-pong one-way '
                  f'p50 {b["lat_p50"]:.3f} p99 {b["lat_p99"]:.3f} ms; observed relay: '
                  + ', '.join(f'{k} {v:.3f}' for k, v in o.items()), flush=True)
            for label, program, trigger in cases:
                w = wall_run(program, args.period, args.duration, trigger,
                             Path(tmp) / f'{run}_{label.split()[-1]}', env)
                results.setdefault(label, []).append(w)
                print(f'run {run}: {label}: ' + ', '.join(f'{k} {v:.3f}' if isinstance(v, float)
                                                          else f'{k} {v}' for k, v in w.items()),
                      flush=True)
    load_after = os.getloadavg()
    lock.close()
    bare_runs = results.pop('bare')
    print(f'\nperiod {args.period * 1e3:g} ms, {args.runs} runs of {args.duration:g} s; load '
          f'average before {load_before[0]:.2f} {load_before[1]:.2f}, after {load_after[0]:.2f} '
          f'{load_after[1]:.2f}; medians (min–max), ms\n')
    print('| measured | period deviation p99 | age p50 | age p99 | latency p50 | latency p99 '
          '| missed |')
    print('|---|---|---|---|---|---|---|')
    print(f'| bare timer / ping-pong one-way | {_fmt([b["dev_p99"] for b in bare_runs])} | | '
          f'| {_fmt([b["lat_p50"] for b in bare_runs])} | {_fmt([b["lat_p99"] for b in bare_runs])}'
          ' | |')
    observed = [b['observed'] for b in bare_runs]
    print(f'| bare observed relay | {_fmt([o["dev_p99"] for o in observed])} | '
          f'{_fmt([o["age_p50"] for o in observed])} | {_fmt([o["age_p99"] for o in observed])} | '
          f'{_fmt([o["lat_p50"] for o in observed])} | {_fmt([o["lat_p99"] for o in observed])} '
          '| |')
    for label, runs in results.items():
        print(f'| wall, {label} | {_fmt([r["dev_p99"] for r in runs])} | '
              f'{_fmt([r["age_p50"] for r in runs])} | {_fmt([r["age_p99"] for r in runs])} | '
              f'{_fmt([r["lat_p50"] for r in runs])} | {_fmt([r["lat_p99"] for r in runs])} | '
              f'{", ".join(str(r["missed"]) for r in runs)} |')
    print('\nRatio to the bare observed relay of the same run (the like-for-like floor), median '
          '(min–max) of the runs:\n')
    keys = ('dev_p99', 'age_p50', 'age_p99', 'lat_p50', 'lat_p99')
    print('| measured | ' + ' | '.join(keys) + ' |')
    print('|---|' + '---|' * len(keys))
    for label, runs in results.items():
        print(f'| wall, {label} | ' + ' | '.join(
            _fmt([r[k] / o[k] for r, o in zip(runs, observed)]) for k in keys) + ' |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
