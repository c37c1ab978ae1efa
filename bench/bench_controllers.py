"""Per-sample compute time of the core controllers (median of several runs).

Run: .venv/bin/python bench/bench_controllers.py
Prints one line per controller: median microseconds per step over 5 runs of N steps.
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from tank_control.core.control.multiloop import TwoLoopPi, document_config
from tank_control.core.control.pid import Pid2Dof, PidConfig, PidController
from tank_control.core.control.smith import SmithModel, SmithPredictor

N, RUNS = 20000, 5


def per_step_us(make, step) -> float:
    times = []
    for _ in range(RUNS):
        obj = make()
        t0 = time.perf_counter()
        for k in range(N):
            step(obj, k)
        times.append((time.perf_counter() - t0) / N * 1e6)
    return statistics.median(times)


def main() -> None:
    empty = np.array([])
    y1, r1 = np.array([0.3]), np.array([1.0])
    y2, r2 = np.array([80.0, 33.0]), np.array([81.0, 33.57])
    cases = {
        'Pid2Dof.update (PID, limits, back-calculation)': (
            lambda: Pid2Dof(PidConfig(kp=3.1, ti=18.7, td=1.3, b=0.42, c=0.63, sample_time=0.1,
                                      u_min=-10, u_max=10)),
            lambda c, k: c.update(1.0, 0.3)),
        'PidController.step (protocol, numpy in/out)': (
            lambda: PidController(PidConfig(kp=3.1, ti=18.7, td=1.3, sample_time=0.1)),
            lambda c, k: c.step(k * 0.1, y1, r1, empty)),
        'TwoLoopPi.step (dynamic decoupling, guard)': (
            lambda: TwoLoopPi(document_config('dynamic')),
            lambda c, k: c.step(float(k), y2, r2, empty)),
        'SmithPredictor.step (FOPDT model, L = 30 samples)': (
            lambda: SmithPredictor(SmithModel(model='fopdt', gain=0.05, time_constant=10.0,
                                              dead_time=3.0),
                                   PidConfig(kp=50.0, ti=10.0, sample_time=0.1)),
            lambda c, k: c.step(k * 0.1, y1, r1, empty)),
    }
    for name, (make, step) in cases.items():
        print(f'{name}: {per_step_us(make, step):.1f} us/step')


if __name__ == '__main__':
    main()
