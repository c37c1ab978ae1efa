"""Plots of a sweep (matplotlib Agg): response envelopes, metrics against swept parameters,
heat maps over two grid parameters.

``envelope.png``: per scenario (row) and per output and input channel (column) the band from
the smallest to the largest value over all runs at each time, the median, and the setpoint.
``metrics.png``: each key metric against each swept parameter (a point per run).
``heatmap.png`` (two or more grid parameters): the worst value of a metric over the other
parameters, on the grid of the first two.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tank_control.harness.plotting import plt, unit

MAX_METRICS = 6
MAX_PARAMS = 4


def _load(out: Path, key: str) -> tuple[list[str], np.ndarray] | None:
    path = out / 'traces' / f'{key}.npz'
    if not path.exists():
        return None
    with np.load(path) as data:
        return [str(n) for n in data['names']], data['data'].astype(float)


def _envelope(out: Path, rows: Sequence[Mapping[str, Any]]) -> Path | None:
    scenarios = list(dict.fromkeys(r['scenario'] for r in rows if r['status'] == 'ok'))
    if not scenarios:
        return None
    traces = {name: [t for t in (_load(out, r['key']) for r in rows
                                 if r['scenario'] == name and r['status'] == 'ok') if t]
              for name in scenarios}
    channels = []
    for name in scenarios:
        for names, _ in traces[name][:1]:
            channels += [n for n in names if n[:2] in ('y.', 'u.') and n not in channels]
    if not channels:
        return None
    fig, axes = plt.subplots(len(scenarios), len(channels), squeeze=False, sharex='row',
                             figsize=(4.2 * len(channels), 2.8 * len(scenarios)))
    for i, name in enumerate(scenarios):
        runs = traces[name]
        longest = max(runs, key=lambda tr: tr[1].shape[0])
        t = longest[1][:, longest[0].index('t')]
        for j, channel in enumerate(channels):
            ax = axes[i][j]
            stack = [np.interp(t, d[:, n.index('t')], d[:, n.index(channel)], right=np.nan)
                     for n, d in runs if channel in n]
            if not stack:
                ax.set_visible(False)
                continue
            values = np.vstack(stack)
            with np.errstate(invalid='ignore'):
                lo, hi = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
                mid = np.nanmedian(values, axis=0)
            ax.fill_between(t, lo, hi, alpha=0.3, label=f'all {len(stack)} runs')
            ax.plot(t, mid, lw=1.0, label='median')
            setpoint = 'r.' + channel[2:]
            if channel.startswith('y.') and setpoint in longest[0]:
                ax.plot(t, longest[1][:, longest[0].index(setpoint)], 'k--', lw=0.8,
                        label='setpoint')
            ax.set_title(f'{name}: {channel[2:]}', fontsize=9)
            ax.set_ylabel(unit(channel[2:]), fontsize=8)
            ax.grid(alpha=0.3)
            if i == len(scenarios) - 1:
                ax.set_xlabel('t [s]')
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / 'envelope.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values) and bool(
        values)


def _metrics_plot(out: Path, rows: Sequence[Mapping[str, Any]], swept: Sequence[str],
                  metrics: Sequence[str]) -> Path | None:
    ok = [r for r in rows if r['status'] == 'ok']
    params = [p for p in swept if _numeric([r.get(p) for r in ok])][:MAX_PARAMS]
    shown = [m for m in metrics if any(isinstance(r.get(m), float) and math.isfinite(r[m])
                                       for r in ok)][:MAX_METRICS]
    if not params or not shown or not ok:
        return None
    scenarios = list(dict.fromkeys(r['scenario'] for r in ok))
    fig, axes = plt.subplots(len(shown), len(params), squeeze=False,
                             figsize=(3.6 * len(params), 2.4 * len(shown)))
    for i, metric in enumerate(shown):
        for j, param in enumerate(params):
            ax = axes[i][j]
            for name in scenarios:
                pts = [(r[param], r.get(metric)) for r in ok if r['scenario'] == name
                       and isinstance(r.get(metric), float) and math.isfinite(r[metric])]
                if pts:
                    x, y = zip(*pts)
                    ax.plot(x, y, '.', ms=4, label=name)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(metric, fontsize=8)
            if i == len(shown) - 1:
                ax.set_xlabel(param, fontsize=8)
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    path = out / 'metrics.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _heatmap(out: Path, rows: Sequence[Mapping[str, Any]], grid: Sequence[str],
             metrics: Sequence[str]) -> Path | None:
    from tank_control.harness.sweep import SMALLER_IS_WORSE
    ok = [r for r in rows if r['status'] == 'ok']
    if len(grid) < 2 or not ok:
        return None
    px, py = grid[0], grid[1]
    if not (_numeric([r.get(px) for r in ok]) and _numeric([r.get(py) for r in ok])):
        return None
    shown = [m for m in metrics if any(isinstance(r.get(m), float) for r in ok)][:2]
    scenarios = list(dict.fromkeys(r['scenario'] for r in ok))
    if not shown:
        return None
    xs = sorted({r[px] for r in ok})
    ys = sorted({r[py] for r in ok})
    fig, axes = plt.subplots(len(scenarios), len(shown), squeeze=False,
                             figsize=(4.6 * len(shown), 3.4 * len(scenarios)))
    for i, name in enumerate(scenarios):
        for j, metric in enumerate(shown):
            smaller = metric.split('.')[-1] in SMALLER_IS_WORSE
            grid_values = np.full((len(ys), len(xs)), np.nan)
            for r in ok:
                v = r.get(metric)
                if r['scenario'] != name or not isinstance(v, float) or math.isnan(v):
                    continue
                iy, ix = ys.index(r[py]), xs.index(r[px])
                old = grid_values[iy, ix]
                worse = (v < old) if smaller else (v > old)
                if math.isnan(old) or worse:
                    grid_values[iy, ix] = v
            ax = axes[i][j]
            image = ax.imshow(np.where(np.isfinite(grid_values), grid_values, np.nan),
                              origin='lower', aspect='auto', cmap='viridis',
                              extent=(-0.5, len(xs) - 0.5, -0.5, len(ys) - 0.5))
            ax.set_xticks(range(len(xs)), [f'{x:.3g}' for x in xs], fontsize=7, rotation=45)
            ax.set_yticks(range(len(ys)), [f'{y:.3g}' for y in ys], fontsize=7)
            ax.set_xlabel(px, fontsize=8)
            ax.set_ylabel(py, fontsize=8)
            ax.set_title(f'{name}: {metric}' + (' (worst over the rest)' if len(grid) > 2
                                                else ''), fontsize=8)
            fig.colorbar(image, ax=ax)
    fig.tight_layout()
    path = out / 'heatmap.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_sweep(spec: Any, cases: Sequence[Any], rows: Sequence[Mapping[str, Any]], out: Path
               ) -> dict[str, Path]:
    """Write the sweep's plots; returns those written (none when no run succeeded)."""
    from tank_control.harness.sweep import KEY_METRICS, metric_columns
    metrics = metric_columns(rows)
    key = [m for k in KEY_METRICS for m in metrics if m.split('.')[-1] == k]
    swept = [a.target.label for a in (*spec.grid, *spec.random)]
    files = {}
    for name, path in (('envelope', _envelope(out, rows)),
                       ('metrics_plot', _metrics_plot(out, rows, swept, key)),
                       ('heatmap', _heatmap(out, rows, [a.target.label for a in spec.grid],
                                            key))):
        if path is not None:
            files[name] = path
    return files
