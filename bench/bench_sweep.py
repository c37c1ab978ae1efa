"""Sweep executors: 200 in-process IPDT runs on one worker, on local processes and on a Dask
LocalCluster (same machine), and the per-run overhead of each executor.

    .venv/bin/python bench/bench_sweep.py [--runs 200] [--repeats 3] [--workers 2]

Each repeat runs the same sweep (config/ipdt_pid.yaml, 300 s per run, a grid over
plant.dead_time and plant.gain) into a fresh directory with: one worker (in this process),
``--workers`` local processes, and a ``dask.distributed`` LocalCluster with ``--workers``
worker processes of one thread (cluster start-up not timed). Reported (medians): the wall time
of ``run_sweep`` (cases, runs, table, summary and plots) and of its runs phase (first
submission to last result), the speedups against one worker, the mean time a run took inside
its worker (``wall_s``) and the executor overhead per run: ``runs phase · workers / runs``
minus that mean. Results: bench/RESULTS.md.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def spec(runs: int):
    from tank_control.harness import sweep
    n_gain = 10
    n_dead = max(runs // n_gain, 1)
    return sweep.SweepSpec(scenarios=(REPO / 'config' / 'ipdt_pid.yaml',), grid=(
        sweep.GridAxis.parse(f'plant.dead_time=±20%:{n_dead}'),
        sweep.GridAxis.parse(f'plant.gain=±30%:{n_gain}')))


def timed(the_spec, executor) -> tuple[float, float, float, int]:
    from tank_control.harness import sweep
    with tempfile.TemporaryDirectory(prefix='bench_sweep_') as tmp:
        start = time.perf_counter()
        result = sweep.run_sweep(the_spec, tmp, executor)
        wall = time.perf_counter() - start
    ok = [r for r in result.rows if r['status'] == 'ok']
    assert len(ok) == len(result.rows), [r['reason'] for r in result.rows if r['status'] != 'ok']
    return wall, result.run_wall, statistics.fmean(r['wall_s'] for r in ok), len(ok)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=200)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--workers', type=int, default=2)
    args = parser.parse_args()
    from distributed import LocalCluster

    from tank_control.harness import sweep
    the_spec = spec(args.runs)
    sweep.run_case(sweep.cases(the_spec)[0].payload())        # imports and first-call set-up
    print(f'machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'load {os.getloadavg()[0]:.2f}; {len(sweep.cases(the_spec))} runs per sweep, '
          f'{args.repeats} repeats')
    results: dict[str, list[tuple[float, float, float, int]]] = {'one worker': [], 'local': [],
                                                                 'dask': []}
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        dask_executor, close = sweep.dask_executor(cluster.scheduler_address)
        try:                                   # the workers import and set up once, untimed
            payload = sweep.cases(the_spec)[0].payload()
            for future in [dask_executor.submit(sweep.run_case, payload)
                           for _ in range(4 * args.workers)]:
                future.result()
            for _ in range(args.repeats):
                results['one worker'].append(timed(the_spec, sweep.InlineExecutor()))
                with sweep.local_executor(args.workers) as pool:
                    results['local'].append(timed(the_spec, pool))
                results['dask'].append(timed(the_spec, dask_executor))
        finally:
            close()
    base = statistics.median(v[0] for v in results['one worker'])
    base_runs = statistics.median(v[1] for v in results['one worker'])
    print('| executor | workers | sweep wall s | runs phase s | runs/s | speedup (sweep) | '
          'speedup (runs phase) | mean run s | overhead per run ms |')
    print('|---|---|---|---|---|---|---|---|---|')
    for name, values in results.items():
        workers = 1 if name == 'one worker' else args.workers
        wall = statistics.median(v[0] for v in values)
        runs_phase = statistics.median(v[1] for v in values)
        run_s = statistics.median(v[2] for v in values)
        runs = values[0][3]
        overhead = (runs_phase * workers / runs - run_s) * 1e3
        print(f'| {name} | {workers} | {wall:.2f} | {runs_phase:.2f} | {runs / runs_phase:.1f} | '
              f'{base / wall:.2f} | {base_runs / runs_phase:.2f} | {run_s:.4f} | '
              f'{overhead:.1f} |')
    print(f'load after: {os.getloadavg()[0]:.2f}')


if __name__ == '__main__':
    main()
