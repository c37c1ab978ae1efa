"""Sim-mode response against lockstep on ``config/ipdt_pid.yaml``: late answers and their effect.

Runs the scenario over ROS 2 once in lockstep and ``--runs`` times in sim per real-time factor,
and prints per run the overshoot of the setpoint step [%], the IAE and ``late_by_signal`` of
``metrics.json``. Then it checks what the plant really integrated: for the IPDT ([Viteckova]:
k1 = 0.05 1/s, To = 5 s, ts = 0.1 s, no noise) ``y_k+1 − y_k = k1·ts·u(t_k − To)``, so the
input of each tick follows from the recorded response. For the ticks whose ``u`` answer was on
time it must equal that answer; for the late ones (no answer recorded, or reported on
``/plant/late_inputs``) where ``u`` changed, the age j of the answer the plant used instead
(j = 1: held a tick) is tallied. Ticks before the first answer are left out. ``r_step_acts``
is the number of ticks after the setpoint step (the trace's ``r`` by its stamp) at which ``u``
first moved (0: at the step's own tick, as in lockstep); ``load`` the 1-min load average at
the run's end.

Usage: .venv/bin/python bench/sim_lateness.py [--rtf 2 5 20] [--runs 3] [--duration 60]
       [--keep DIR]   (set ROS_DOMAIN_ID to a domain nobody else uses; --keep: the runs'
       directories are kept in DIR instead of a temporary directory)
"""
from __future__ import annotations

import argparse
import collections
import os
import tempfile
from pathlib import Path

import numpy as np

from tank_control.harness.runner import run
from tank_control.core.trace import Trace

SCENARIO = Path(__file__).resolve().parents[1] / 'config' / 'ipdt_pid.yaml'
K1, TS, DEAD_TICKS = 0.05, 0.1, 50
NS_PER_TICK = 100_000_000


def answer_stamps(mcap_path: Path) -> tuple[set[int], set[int]]:
    """Ticks with a recorded ``u`` answer, and ticks whose answer the plant reported late."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    answered, late = set(), set()
    with open(mcap_path, 'rb') as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(
                topics=['/manipulated', '/plant/late_inputs']):
            if 'u' not in msg.name:
                continue
            tick = round((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) / NS_PER_TICK)
            (answered if channel.topic == '/manipulated' else late).add(tick)
    return answered, late


def applied_inputs(out: Path) -> dict[str, object]:
    """On-time ticks where the integrated input equals the answer, and the ages at late ones."""
    trace = Trace.read_csv(out / 'trace.csv')
    y, u = trace.columns['y.y'], trace.columns['u.u']
    n = len(y)
    applied = np.full(n, np.nan)
    applied[:n - 1 - DEAD_TICKS] = np.diff(y)[DEAD_TICKS:] / (K1 * TS)
    answered, late = answer_stamps(out / 'run.mcap')
    first = min(answered)
    ticks = range(first + 1, n - 1 - DEAD_TICKS)
    on_time = [k for k in ticks if k in answered and k not in late]
    equal = sum(abs(applied[k] - u[k]) < 1e-6 for k in on_time)
    ages: collections.Counter = collections.Counter()
    for k in ticks:
        if (k in answered and k not in late) or abs(u[k] - u[k - 1]) < 1e-12:
            continue
        ages[next((j for j in range(1, 8) if k - j >= first
                   and abs(applied[k] - u[k - j]) < 1e-6), 'other')] += 1
    r = trace.columns['r.y']
    step = int(np.flatnonzero(np.diff(r))[0]) + 1 if np.any(np.diff(r)) else None
    acts = (None if step is None else
            next((k - step for k in range(step, n) if u[k] != u[k - 1]), None))
    return {'on_time': len(on_time), 'equal': int(equal), 'late_ages': dict(ages),
            'r_step_acts': acts}


def one_run(out: Path, **settings: object) -> None:
    result = run(SCENARIO, out, **settings)
    metrics = result.metrics
    steps = metrics['outputs']['y']['steps']
    overshoot = f"{steps[0]['overshoot_pct']:.3f}" if steps else '-'
    print(f"  overshoot {overshoot} %, IAE {metrics['outputs']['y']['iae']:.2f}, "
          f"late {metrics['run']['late_by_signal']}, {applied_inputs(out)}, "
          f"load {os.getloadavg()[0]:.2f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rtf', type=float, nargs='+', default=[2.0, 5.0, 20.0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--duration', type=float, default=60.0)
    parser.add_argument('--keep', type=Path, default=None,
                        help='keep the runs in this directory (default: a temporary one)')
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        tmp = scratch if args.keep is None else args.keep
        print('lockstep', flush=True)
        one_run(Path(tmp) / 'lockstep', duration=args.duration)
        for rtf in args.rtf:
            print(f'sim, rtf {rtf:g}', flush=True)
            for i in range(args.runs):
                one_run(Path(tmp) / f'sim{rtf:g}_{i}', mode='sim', rtf=rtf,
                        duration=args.duration)


if __name__ == '__main__':
    main()
