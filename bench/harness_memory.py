"""Memory of the harness process against the length of a run.

Runs ``tank-control run`` (lockstep over ROS, and ``--in-process``) on one scenario for
several durations, each in a child Python process, and reports that process's peak resident
set size (``ru_maxrss`` of the harness itself, not of the node processes) and the growth per
plant tick between the shortest and the longest run. Each run gets its own output directory
under ``--out``. ``--tree`` runs another checkout's harness (e.g. an older commit exported
with ``git archive``) for a before/after comparison. The ROS runs use a ROS_DOMAIN_ID held
free by the same claim as the tests (``harness/domains.py``).

    .venv/bin/python bench/harness_memory.py --durations 500 2500 --runs 3
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from tank_control.harness import domains

REPO = Path(__file__).resolve().parents[1]

CHILD = """
import json, resource, sys
from tank_control.harness import cli
code = cli.main(sys.argv[1:])
peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
metrics = json.load(open(sys.argv[sys.argv.index('--out') + 1] + '/metrics.json'))
print(json.dumps({'code': code, 'peak_kib': peak_kib, 'ticks': metrics['run']['ticks']}))
"""


def one_run(scenario: str, duration: float, out: Path, in_process: bool, tree: Path,
            env: dict[str, str]) -> dict:
    argv = [sys.executable, '-c', CHILD, 'run', scenario, '--out', str(out),
            '--duration', str(duration), '--quiet']
    if in_process:
        argv.append('--in-process')
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tree, env=env)
    if done.returncode != 0:
        raise SystemExit(f'run failed ({done.returncode}):\n{done.stderr[-2000:]}')
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scenario', default='config/ipdt_pid.yaml')
    parser.add_argument('--durations', type=float, nargs='+', default=[500.0, 2500.0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--modes', nargs='+', default=['lockstep', 'in_process'],
                        choices=['lockstep', 'in_process'])
    parser.add_argument('--out', type=Path, default=None)
    parser.add_argument('--tree', type=Path, default=REPO,
                        help='checkout whose tank_control runs (default: this one)')
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix='harness_memory_'))
    tree = args.tree.resolve()
    domain, _lock = domains.claim()    # held while this runs
    env = {**os.environ, 'PYTHONPATH': str(tree), 'ROS_DOMAIN_ID': str(domain),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    scenario = str((REPO / args.scenario) if not Path(args.scenario).is_absolute()
                   else args.scenario)
    print(f'tree {tree}, ROS_DOMAIN_ID {domain}')
    for mode in args.modes:
        peaks: dict[float, list[int]] = {}
        ticks: dict[float, int] = {}
        for duration in args.durations:
            for i in range(args.runs):
                result = one_run(scenario, duration, out / f'{mode}_{duration:g}_{i}',
                                 mode == 'in_process', tree, env)
                peaks.setdefault(duration, []).append(result['peak_kib'])
                ticks[duration] = result['ticks']
        print(f'{mode}:')
        for duration in args.durations:
            print(f'  duration {duration:g} s, {ticks[duration]} ticks: peak RSS median '
                  f'{statistics.median(peaks[duration]) / 1024:.1f} MiB '
                  f'(runs: {", ".join(f"{p / 1024:.1f}" for p in peaks[duration])})')
        short, long = min(args.durations), max(args.durations)
        growth = ((statistics.median(peaks[long]) - statistics.median(peaks[short])) * 1024
                  / max(ticks[long] - ticks[short], 1))
        print(f'  growth: {growth:.0f} bytes per tick (medians, {short:g} s → {long:g} s)')


if __name__ == '__main__':
    main()
