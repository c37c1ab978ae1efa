"""The cost of the controller's mode log in an in-process run (core/loop.py ``modes=``, what
``tank-control run --in-process`` passes; core/monitoring/modes.py): ticks per CPU second of
``iter_loop`` over a shipped file without and with it, alternating, median of ``--runs``.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_mode_log.py [--runs 15] [--file YAML]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

from tank_control.core import loop as core_loop
from tank_control.core.monitoring.modes import ModeLog
from tank_control.harness.runner import _build
from tank_control.harness.scenario_file import load_scenario


def ticks_per_cpu_second(scenario, with_modes: bool) -> float:
    built = _build(scenario)
    log = ModeLog()
    start = time.process_time()
    ticks = sum(1 for _ in core_loop.iter_loop(
        built.plant, built.controller, built.reference, sample_time=built.sample_time,
        duration=scenario.harness.duration, noise=built.noise.sample_floats,
        guards=built.guards(), modes=log.add if with_modes else None))
    return ticks / (time.process_time() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=15)
    parser.add_argument('--file', default='config/scenarios/monitor_well_tuned.yaml')
    args = parser.parse_args()
    scenario = load_scenario(args.file)
    ticks_per_cpu_second(scenario, True)                       # warm-up
    results: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.runs):
        for with_modes in (False, True):
            results[with_modes].append(ticks_per_cpu_second(scenario, with_modes))
    without, with_ = (statistics.median(results[k]) for k in (False, True))
    print(f'{args.file}: without the mode log {without:.0f} ticks per CPU second, with it '
          f'{with_:.0f} ({100 * (without / with_ - 1):.0f} % more CPU per tick); '
          f'load {os.getloadavg()[0]:.1f}')


if __name__ == '__main__':
    main()
