"""Wall time of a short ROS run from the command to its exit, against another checkout.

``tank-control run config/ipdt_pid.yaml --mode lockstep --duration 20`` (0.2 s of ticks; the
rest is start-up, discovery, stopping and writing the results) as a user runs it, once with
this checkout and once with the ``--baseline`` checkout (each imported through PYTHONPATH,
with this interpreter), in turn, ``--runs`` times, on one ROS_DOMAIN_ID claimed for the bench
(``harness/domains.py``: no participant on it). ``--range LOCALHOST`` (default) or
``SUBNET`` (``ROS_AUTOMATIC_DISCOVERY_RANGE``; with SUBNET a graph on another host could be
there, so the harness looks for ``harness.discovery_time``). Also the in-process run of the
same file with this checkout, for reference. Reported: wall seconds per run, medians, the
ratio this/baseline pair by pair (the pairs see the same machine), the run's own phases
from metrics.json (``wall_time``: from un-pausing the plant to the last tick;
``wall_time_total``: from the recorder joining the domain to the end).

    .venv/bin/python bench/bench_startup.py --baseline /path/to/other/checkout [--runs 5]
                                            [--range LOCALHOST|SUBNET] [--file FILE]
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

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))

from tank_control.harness import domains  # noqa: E402


def one_run(tree: Path, config: str, env: dict[str, str], in_process: bool = False
            ) -> dict[str, float]:
    """Wall seconds of one ``tank-control run`` of ``tree`` and its metrics' wall times."""
    with tempfile.TemporaryDirectory(prefix='bench_startup_') as out:
        argv = [sys.executable, '-m', 'tank_control.harness.cli', 'run', config, '--mode',
                'lockstep', '--duration', '20', '--out', out, '--quiet']
        if in_process:
            argv.append('--in-process')
        start = time.monotonic()
        proc = subprocess.run(argv, env={**env, 'PYTHONPATH': str(tree)}, cwd=tree,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wall = time.monotonic() - start
        if proc.returncode != 0:
            raise SystemExit(f'{tree}: exit {proc.returncode}\n{proc.stderr[-2000:]}')
        run = json.loads((Path(out) / 'metrics.json').read_text())['run']
    return {'wall': wall, 'ticks': run.get('wall_time', 0.0),
            'total': run.get('wall_time_total', run.get('wall_time', 0.0))}


def _median_range(values: list[float], fmt: str = '.2f') -> str:
    return (f'{statistics.median(values):{fmt}} ({min(values):{fmt}}–{max(values):{fmt}})'
            if values else '–')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--baseline', type=Path, required=True,
                        help='another checkout (its root directory) to run in turn')
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--range', dest='range_', choices=('LOCALHOST', 'SUBNET'),
                        default='LOCALHOST')
    parser.add_argument('--file', default='config/ipdt_pid.yaml')
    args = parser.parse_args()
    baseline = args.baseline.resolve()
    domain_id, lock = domains.claim()
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', domains.EXCLUSIVE_ENV, 'ROS_STATIC_PEERS')}
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE=args.range_,
               CI='1')
    load_before = os.getloadavg()
    rows: dict[str, list[dict[str, float]]] = {'this': [], 'baseline': [], 'in-process': []}
    try:
        for run in range(args.runs):
            for label, tree in (('this', HERE), ('baseline', baseline)):
                r = one_run(tree, args.file, env)
                rows[label].append(r)
                print(f'run {run + 1} {label}: {r["wall"]:.2f} s wall (run total '
                      f'{r["total"]:.2f} s, ticks {r["ticks"]:.2f} s)', flush=True)
            r = one_run(HERE, args.file, env, in_process=True)
            rows['in-process'].append(r)
            print(f'run {run + 1} in-process: {r["wall"]:.2f} s wall', flush=True)
    finally:
        lock.close()
    load_after = os.getloadavg()
    ratios = [a['wall'] / b['wall'] for a, b in zip(rows['this'], rows['baseline'])]
    print(f'\n{args.file}, --mode lockstep --duration 20, ROS_AUTOMATIC_DISCOVERY_RANGE='
          f'{args.range_}; load average (1 min) before {load_before[0]:.2f}, after '
          f'{load_after[0]:.2f}; {args.runs} runs, medians (min–max)\n')
    print('| tree | wall s (command) | run total s (metrics) | ratio to baseline |')
    print('|---|---|---|---|')
    for label, name in (('this', str(HERE)), ('baseline', str(baseline)),
                        ('in-process', f'{HERE} --in-process')):
        rs = rows[label]
        ratio = _median_range(ratios) if label == 'this' else ''
        total = _median_range([r['total'] for r in rs]) if label != 'in-process' else ''
        print(f'| {name} | {_median_range([r["wall"] for r in rs])} | {total} | {ratio} |')


if __name__ == '__main__':
    main()
