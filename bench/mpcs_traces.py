"""Per-controller summary of a ``tank-control compare`` run of the tank_mpcs_*.yaml files
(docs/mpcs.md, "Comparison"), read from each run's ``trace.csv``:

    .venv/bin/python bench/mpcs_traces.py runs/mpcs

Whole-run IAE (trapezoidal) [cm·s], [°C·s]; the worst |e_h| [cm] and |e_T| [°C] over the
last 300 s before each change and before the end ("settled"); the range of both inputs
[cm³/s] and the largest |Δu| per sample [cm³/s]. Prints a Markdown table.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tank_control.harness.trace import read_csv

WINDOW = 300.0      # [s] before each change that must be settled


def summary(trace_csv: Path) -> str:
    c = read_csv(trace_csv).columns
    t = c['t']
    times = sorted({float(x) for name in ('r.h', 'r.T_out', 'd.F_D')
                    for x in t[1:][np.diff(c[name]) != 0]})
    ends = times[1:] + [float(t[-1]) + 1.0]
    iae = {o: float(np.trapezoid(np.abs(c[f'r.{o}'] - c[f'y.{o}']), t)) for o in ('h', 'T_out')}
    settled = {o: max(float(np.max(np.abs(c[f'r.{o}'] - c[f'y.{o}'])[(t >= e - WINDOW) & (t < e)]))
                      for e in ends) for o in ('h', 'T_out')}
    u = np.column_stack([c['u.F_H'], c['u.F_Cin']])
    return (f'| {trace_csv.parent.name} | {iae["h"]:.0f} | {iae["T_out"]:.0f} | '
            f'{settled["h"]:.4f} | {settled["T_out"]:.4f} | {u.min():.2f} … {u.max():.2f} | '
            f'{np.max(np.abs(np.diff(u, axis=0))):.3f} |')


def main(argv: list[str]) -> int:
    root = Path(argv[1] if len(argv) > 1 else 'runs/mpcs')
    print('| run | IAE h [cm·s] | IAE T_out [°C·s] | max \\|e_h\\| settled | '
          'max \\|e_T\\| settled | u range [cm³/s] | max \\|Δu\\| per sample |')
    print('|---|---|---|---|---|---|---|')
    for trace in sorted(root.glob('*/trace.csv')):
        print(summary(trace))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv))
