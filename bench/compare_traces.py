"""In-process traces of every shipped scenario, compared with another source tree's.

Runs each file of ``config/*.yaml`` and ``config/scenarios/*.yaml`` through
``core.scenario.run_in_process`` (its ``harness.duration``) with this tree's ``tank_control``
and with the one found under ``--baseline-path`` (a subprocess with that ``PYTHONPATH``), and
prints per scenario the largest absolute difference over all columns (rows aligned by index;
NaN equal to NaN). Exit status 1 if any difference exceeds ``--tol`` or the columns differ.

    .venv/bin/python bench/compare_traces.py --baseline-path /path/to/other/checkout [--tol 1e-12]
    .venv/bin/python bench/compare_traces.py --dump DIR      # write DIR/<name>.npz only
    .venv/bin/python bench/compare_traces.py --against DIR   # compare with such a dump

A baseline checkout of ``main``: ``git archive main | tar -x -C /tmp/main_tree``.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def scenario_files() -> list[Path]:
    return sorted((REPO / 'config').glob('*.yaml')) + sorted(
        (REPO / 'config' / 'scenarios').glob('*.yaml'))


def key(path: Path) -> str:
    return str(path.relative_to(REPO / 'config')).replace('/', '__').removesuffix('.yaml')


def dump(directory: Path) -> None:
    """Run every scenario with the ``tank_control`` this interpreter imports; one .npz each."""
    from tank_control.core.scenario import run_in_process
    directory.mkdir(parents=True, exist_ok=True)
    for path in scenario_files():
        trace = run_in_process(path)
        np.savez(directory / f'{key(path)}.npz', names=np.array(trace.names),
                 **{f'c{i}': trace[n] for i, n in enumerate(trace.names)})


def load(file: Path) -> dict[str, np.ndarray]:
    with np.load(file) as data:
        names = [str(n) for n in data['names']]
        return {n: data[f'c{i}'] for i, n in enumerate(names)}


def difference(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    if list(a) != list(b):
        return float('inf')
    worst = 0.0
    for name in a:
        x, y = a[name], b[name]
        if x.shape != y.shape:
            return float('inf')
        diff = np.abs(x - y)
        diff[np.isnan(x) & np.isnan(y)] = 0.0
        if np.isnan(diff).any():
            return float('inf')
        worst = max(worst, float(diff.max()) if diff.size else 0.0)
    return worst


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--baseline-path', type=Path, help='source tree of the reference run')
    parser.add_argument('--dump', type=Path, help='only write this tree\'s traces to DIR')
    parser.add_argument('--against', type=Path, help='compare with a --dump directory')
    parser.add_argument('--tol', type=float, default=1e-12)
    args = parser.parse_args()
    if args.dump:
        dump(args.dump)
        return 0
    if not (args.baseline_path or args.against):
        parser.error('give --baseline-path, --against or --dump')
    with tempfile.TemporaryDirectory() as tmp:
        mine, theirs = Path(tmp) / 'new', args.against or Path(tmp) / 'baseline'
        if not args.against:
            env = dict(os.environ, PYTHONPATH=str(args.baseline_path.resolve()))
            script = Path(__file__).resolve()
            subprocess.run([sys.executable, str(script), '--dump', str(theirs)], env=env,
                           check=True, cwd=tmp)
        dump(mine)
        failed = 0
        for path in scenario_files():
            d = difference(load(mine / f'{key(path)}.npz'), load(theirs / f'{key(path)}.npz'))
            ok = d <= args.tol
            failed += not ok
            print(f'{"ok  " if ok else "FAIL"} {d:9.3g}  {path.relative_to(REPO)}')
    print(f'{len(scenario_files()) - failed} of {len(scenario_files())} within {args.tol:g}')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
