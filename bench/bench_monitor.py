"""Cost of the live loop monitor (core/monitoring LoopMonitor): µs per update, ms per recompute
of a 600 s window at 0.1 s (6000 samples), on white noise and on an oscillating loop (the
cross-correlation path). Median of 5 recomputes. And controller_node's lookup of the loop's dead
time after a parameter change (nodes/loop_performance.py ``dead_times``; median of 50).

    .venv/bin/python bench/bench_monitor.py
"""
from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from tank_control.core.monitoring import LoopMonitor, MonitorConfig


def main() -> None:
    rng = np.random.default_rng(0)
    ts, n = 0.1, 6000
    t = np.arange(n) * ts
    cases = {'white noise': (rng.standard_normal(n), rng.standard_normal(n)),
             'oscillating (50 s)': (np.sign(np.sin(2 * np.pi * t / 50)) + 0.05 * rng.standard_normal(n),
                                    -np.cumsum(np.sign(np.sin(2 * np.pi * t / 50))) * ts)}
    for name, (y, u) in cases.items():
        monitor = LoopMonitor(ts, MonitorConfig(window=600.0, period=1e6))
        start = time.perf_counter()
        for k in range(n):
            monitor.update(t[k], y[k], 0.0, u[k])
        update_us = (time.perf_counter() - start) / n * 1e6
        costs = []
        for _ in range(5):
            start = time.perf_counter()
            body = monitor.recompute()
            costs.append(time.perf_counter() - start)
        print(f'{name}: update {update_us:.1f} µs/sample; recompute {np.median(costs) * 1e3:.1f} ms '
              f'(median of 5); verdict {body["verdict"]}')
    dead_time_lookup()


def dead_time_lookup() -> None:
    from tank_control.core import scenario
    from tank_control.core.control.kinds import registry
    from tank_control.nodes.loop_performance import LoopPerformance
    path = Path(__file__).resolve().parents[1] / 'config' / 'scenarios' / 'monitor_well_tuned.yaml'
    values = scenario.node_values(scenario.sections_of(path), 'controller')
    node = SimpleNamespace(create_publisher=lambda *a, **k: SimpleNamespace(publish=print))
    perf = LoopPerformance(node, lambda: values, registry.get_kind('pid'), 0.5, ['y'], ['u'])
    costs = []
    for i in range(50):
        values['kp'] = 5.0 + i * 1e-3          # a change: the lookup is done anew
        start = time.perf_counter()
        found = perf.dead_times()['y']
        costs.append(time.perf_counter() - start)
    print(f'dead-time lookup after a change: {np.median(costs) * 1e3:.2f} ms (median of 50); '
          f'{found.seconds:g} s from {found.source}')


if __name__ == '__main__':
    main()
