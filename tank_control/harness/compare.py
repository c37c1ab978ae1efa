"""Compare runs: a markdown table of their metrics and an overlay plot (as [Michalski2021] compares
controllers on the same tank)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tank_control.harness.runner import RunResult


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return '–'
    if isinstance(value, float):
        return f'{value:.{digits}g}'
    return str(value)


def metrics_rows(result: RunResult) -> list[dict[str, str]]:
    """One row per output channel of a run (first setpoint change for the step columns;
    ``coupling peak``: the largest |r − y| of this output within the window of another
    output's setpoint step)."""
    rows = []
    metrics = result.metrics
    for name, out in metrics['outputs'].items():
        coupling = [s['interaction'][name]['peak_error']
                    for other in metrics['outputs'].values() for s in other['steps']
                    if s.get('interaction', {}).get(name, {}).get('peak_error') is not None]
        steps = out['steps']
        worst = max((s['overshoot_pct'] for s in steps if s['overshoot_pct'] is not None),
                    default=None)
        first = steps[0] if steps else {}
        rows.append({
            'scenario': result.name, 'output': name,
            'IAE': _fmt(out['iae']), 'ISE': _fmt(out['ise']),
            'steps': str(len(steps)),
            'max overshoot %': _fmt(worst, 3),
            'rise time s (1st)': _fmt(first.get('rise_time'), 3),
            'settling 2 % s (1st)': _settling(first),
            'ss error (last)': _fmt(steps[-1]['ss_error'], 3) if steps else '–',
            'coupling peak': _fmt(max(coupling), 3) if coupling else '–',
        })
    run = metrics['run']
    for row in rows:
        row['ticks/s'] = _fmt(run.get('ticks_per_s'), 4)
    return rows


def _settling(step: dict) -> str:
    """The settling time, with its band when measurement noise widened it beyond 2 %
    (docs/harness.md, "Measurement noise")."""
    text = _fmt(step.get('settling_time'), 3)
    band = step.get('settling_band_pct')
    if step.get('settling_time') is not None and band is not None and band > 2.0 + 1e-9:
        text += f' (±{band:.2g} %)'
    return text


def markdown_table(results: Sequence[RunResult]) -> str:
    """Metrics of several runs as one markdown table."""
    rows = [row for result in results for row in metrics_rows(result)]
    if not rows:
        return '(no outputs with setpoints)\n'
    header = list(rows[0])
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    lines += ['| ' + ' | '.join(row[h] for h in header) + ' |' for row in rows]
    return '\n'.join(lines) + '\n'


def write_comparison(results: Sequence[RunResult], out_dir: str | Path,
                     plots: bool = True) -> dict[str, Path]:
    """``comparison.md`` (table, and where each run's files are) and ``overlay.png`` (not with
    ``plots`` False)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = markdown_table(results)
    runs = '\n'.join(f'- `{r.name}`: {r.out_dir}' for r in results)
    md = out / 'comparison.md'
    md.write_text(f'# Comparison\n\n{table}\nRuns:\n\n{runs}\n')
    if not plots:
        return {'table': md}
    from tank_control.harness.plotting import plot_runs, run_plot   # matplotlib: when plotting
    plot = plot_runs([run_plot(r.name, r.trace, r.metrics) for r in results], out / 'overlay.png',
                     title='comparison: ' + ', '.join(r.name for r in results))
    return {'table': md, 'plot': plot}
