"""Late samples at 10 Hz across a relay test's completion, design on / off the sampling path.

The relay tuner (rule ms: the time-domain fit plus the Ms-constrained design, the heaviest
case) runs a noise-free FOPDT (K 0.05, T 2 s, L 0.6 s) paced by the wall clock at
h = 0.1 s, as a node's timer would call it. A sample is late when its ``step`` ends after the
next sample instant. ``autotune.design_time`` 0 (the work inside the sample) is the baseline;
2 s moves it to the worker thread. Each configuration runs ``--runs`` times; medians printed.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_autotune_offload.py --runs 3
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from tank_control.core.control.kinds.registry import make_controller
from tank_control.core.tuning.model import ProcessModel

H = 0.1
SETTINGS = {'kp': 20.0, 'ti': 3.0, 'u_min': 0.0, 'u_max': 10000.0, 'sample_time': H,
            'autotune.relay_amplitude': 200.0, 'autotune.settle_time': 1.0,
            'autotune.settle_band': 0.5, 'autotune.max_amplitude': 50.0,
            'autotune.rule': 'ms', 'autotune.kind': 'pid'}


def one_run(design_time: float, seconds: float) -> tuple[int, float, str]:
    """(late samples, longest step [s], final state) of one wall-paced run."""
    controller = make_controller('relay_autotune', {**SETTINGS,
                                                    'autotune.design_time': design_time})
    plant = ProcessModel('fopdt', 0.05, 0.6, 2.0).plant()
    r = np.array([100.0])
    controller.start()
    start = time.monotonic()
    late, longest = 0, 0.0
    for k in range(int(seconds / H)):
        instant = start + k * H
        wait = instant - time.monotonic()
        if wait > 0:
            time.sleep(wait)               # pacing, as a wall timer
        t0 = time.monotonic()
        u = controller.step(k * H, plant.outputs(), r, np.array([]))
        end = time.monotonic()
        longest = max(longest, end - t0)
        late += end > instant + H
        plant.step(u, np.array([0.0]), H)
    return late, longest, controller.state


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--seconds', type=float, default=40.0, help='wall time of one run')
    args = parser.parse_args()
    for design_time in (0.0, 2.0):
        results = [one_run(design_time, args.seconds) for _ in range(args.runs)]
        lates = [r[0] for r in results]
        longest = [r[1] for r in results]
        states = {r[2] for r in results}
        print(f'design_time {design_time:g} s: late samples median {statistics.median(lates):g} '
              f'{lates}, longest step median {statistics.median(longest) * 1e3:.1f} ms '
              f'{[round(x * 1e3, 1) for x in longest]}, final states {sorted(states)}')


if __name__ == '__main__':
    main()
