"""``plot.png``: outputs with their setpoints, inputs and disturbances against time (matplotlib Agg).

One panel per output channel (setpoint dashed), then one panel per unit for the inputs (with the
controller's limits, grey dotted) and for the disturbances; an input or disturbance that stays
constant gets no flat panel, the title names it and its value. The title names the controller's
gains, the ``--set`` overrides of the run and, once, the input limits beyond the view; a table
beside the legends holds each run's key metrics; the controller's state changes (the relay
auto-tuner's ``settling``, ``relay``, ...) are vertical lines with the state's name, names that
would overlap written on lower rows. An input panel's y-range is the robust range of its signals
(percentiles), so one derivative kick does not flatten the rest; clipped samples are marked at
the edge. Several runs overlaid keep one colour per run in every panel; legends sit outside the
axes. Units: the mixing tank's ([Michalski2021] §1: h in cm, temperatures in °C, flows in cm³/s); the SISO
plants' signals are in the units of the process, shown as "process units".
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend is chosen first)

from tank_control.core.trace import Trace  # noqa: E402

UNITS = {'h': 'cm', 'T_out': '°C', 'T_D': '°C', 'T_H': '°C', 'T_C': '°C',
         'F_H': 'cm³/s', 'F_Cin': 'cm³/s', 'F_C': 'cm³/s', 'F_D': 'cm³/s'}
DEFAULT_UNIT = 'process units'
CLIP_RATIO = 3.0
"""An input panel is clipped to its robust range when the full range is wider than this many
times the 0.5–99.5 percentile span."""
LIMIT_REACH = 0.25
"""A limit further than this fraction of the view's height beyond it is named, not drawn in."""
AXES_RIGHT = 0.70
"""Right edge of the panels (figure fraction); their legends follow, then the metrics table."""
TABLE_GAP = 0.015
"""Space between the widest legend and the metrics table (figure fraction)."""
MARK_ROWS = (0.98, 0.66, 0.34)
"""Heights (axes fraction) of the rows the state names are written in."""
MARK_GAP = 0.025
"""State names closer than this fraction of the time span go to different rows."""


def unit(channel: str) -> str:
    return UNITS.get(channel, DEFAULT_UNIT)


@dataclass(frozen=True)
class RunPlot:
    """One run to plot: its trace and what the figure says about it (all optional).

    ``limits``: input limits {channel: (min, max)}; ``gains``: the controller's final gains;
    ``overrides``: the ``--set`` items; ``table``: (name, value) rows of the side table;
    ``marks``: (time [s], state name) at each change of the controller's state."""

    label: str
    trace: Trace
    limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    gains: Mapping[str, Any] = field(default_factory=dict)
    overrides: Sequence[str] = ()
    table: Sequence[tuple[str, str]] = ()
    marks: Sequence[tuple[float, str]] = ()


def constant_value(traces: Sequence[Trace], column: str) -> float | None:
    """The value of ``column`` if it is the same finite constant in every trace, else None."""
    values: set[float] = set()
    for trace in traces:
        data = trace.columns.get(column)
        if data is None:
            continue
        data = np.asarray(data, dtype=float)
        if data.size == 0 or not np.all(np.isfinite(data)) or data.min() != data.max():
            return None
        values.add(float(data[0]))
    return values.pop() if len(values) == 1 else None


def _panels(traces: Sequence[Trace]) -> tuple[list[tuple[str, str, list[str]]], list[str]]:
    """(kind, unit, channels) per panel — each output alone, inputs and disturbances by unit —
    and the input and disturbance channels that stay constant in every run (``name value
    unit``): those get no flat panel, the title names them."""
    trace = traces[0]
    panels = [('y', unit(name), [name]) for name in trace.channels('y')]
    constant: list[str] = []
    for prefix in ('u', 'd'):
        by_unit: dict[str, list[str]] = {}
        for name in trace.channels(prefix):
            value = constant_value(traces, f'{prefix}.{name}')
            if value is not None:
                shown = unit(name) if unit(name) != DEFAULT_UNIT else ''
                constant.append(f'{name} {_fmt(value)}{" " + shown if shown else ""}')
                continue
            by_unit.setdefault(unit(name), []).append(name)
        panels += [(prefix, u, names) for u, names in by_unit.items()]
    return panels, constant


_TITLES = {'y': 'output', 'u': 'manipulated input', 'd': 'disturbance'}


def _fmt(value: Any) -> str:
    return f'{value:.4g}' if isinstance(value, float) else str(value)


def gains_text(gains: Mapping[str, Any]) -> str:
    """``kp 20, ti 12, ...`` (non-finite values as given: ``ti inf`` is no integral action)."""
    return ', '.join(f'{k} {_fmt(v)}' for k, v in gains.items())


def robust_range(values: np.ndarray) -> tuple[float, float, bool]:
    """(low, high, clipped): the y-range of an input panel. The 0.5–99.5 percentiles widened by
    10 % of their span when rare spikes (derivative kicks) would make the full range more than
    ``CLIP_RATIO`` times wider (clipped); otherwise the full range with a 5 % margin."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return -1.0, 1.0, False
    lo, hi = (float(v) for v in np.percentile(finite, [0.5, 99.5]))
    full_lo, full_hi = float(finite.min()), float(finite.max())
    span = hi - lo if hi > lo else max(abs(hi) * 0.1, 1e-9)
    if full_hi - full_lo <= CLIP_RATIO * span:
        pad = 0.05 * max(full_hi - full_lo, span)
        return full_lo - pad, full_hi + pad, False
    return lo - 0.1 * span, hi + 0.1 * span, True


def side_table(metrics: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Key metrics of a run (``metrics.json``) as (name, value) rows: per output IAE, the
    largest overshoot, the first step's settling time and the last steady-state error; per
    input its range."""
    rows: list[tuple[str, str]] = []
    for name, out in (metrics.get('outputs') or {}).items():
        steps = out.get('steps') or []
        overshoot = max((s['overshoot_pct'] for s in steps if s.get('overshoot_pct') is not None),
                        default=None)
        rows.append((f'{name} IAE', _fmt(out.get('iae'))))
        if steps:
            rows.append((f'{name} overshoot %', _fmt(overshoot) if overshoot is not None else '–'))
            settling = steps[0].get('settling_time')
            rows.append((f'{name} settling s', _fmt(settling) if settling is not None else '–'))
            rows.append((f'{name} ss error', _fmt(steps[-1].get('ss_error'))))
    for name, inp in (metrics.get('inputs') or {}).items():
        if 'min' in inp and 'max' in inp:
            rows.append((f'{name} range', f"{_fmt(inp['min'])} … {_fmt(inp['max'])}"))
    return rows


def run_plot(label: str, trace: Trace, metrics: Mapping[str, Any]) -> RunPlot:
    """A run as the harness wrote it (``metrics.json``): the controller's input limits and
    final gains, the ``--set`` overrides, the side table and the controller's state changes
    (``run.controller_states``: recorded by in-process runs, and from the recorded
    ``/parameter_events`` by ROS runs)."""
    controller = metrics.get('controller') or {}
    limits = {str(name): (-math.inf if low is None else float(low),
                          math.inf if high is None else float(high))
              for name, (low, high) in (controller.get('input_limits') or {}).items()}
    states = (metrics.get('run') or {}).get('controller_states') or ()
    return RunPlot(label, trace, limits=limits, gains=controller.get('final_gains') or {},
                   overrides=tuple(metrics.get('overrides') or ()), table=side_table(metrics),
                   marks=[(float(t), str(s)) for t, s in states])


def _as_runs(runs: Sequence[RunPlot | tuple[str, Trace]]) -> list[RunPlot]:
    return [r if isinstance(r, RunPlot) else RunPlot(r[0], r[1]) for r in runs]


def figure_runs(runs: Sequence[RunPlot | tuple[str, Trace]], title: str = ''):
    """The figure of one run, or several overlaid (same channels): a matplotlib Figure."""
    runs = _as_runs(runs)
    first = runs[0].trace
    panels, constant = _panels([run.trace for run in runs])
    overlay = len(runs) > 1
    fig = plt.figure(figsize=(14, 2.4 * len(panels) + 1.4))
    gs = fig.add_gridspec(len(panels), 1, left=0.06, right=AXES_RIGHT, top=0.88, bottom=0.08,
                          hspace=0.25)
    off_scale: list[str] = []
    axes: list[Any] = []
    for i in range(len(panels)):
        axes.append(fig.add_subplot(gs[i, 0], sharex=axes[0] if axes else None))
    for ax, (kind, panel_unit, names) in zip(axes, panels):
        view: list[np.ndarray] = []
        for i, run in enumerate(runs):
            trace = run.trace
            for j, name in enumerate(names):
                column = trace.columns.get(f'{kind}.{name}')
                if column is None:
                    continue
                # one colour per run in an overlay (channels by line style), per channel alone
                colour = f'C{i % 10}' if overlay else f'C{j % 10}'
                style = ('-', '--', '-.', ':')[j % 4] if overlay else '-'
                series = f'{run.label}: {name}' if overlay else name
                ax.plot(trace.t, column, color=colour, linestyle=style, label=series,
                        drawstyle='steps-post' if kind == 'u' else None)
                view.append(np.asarray(column, dtype=float))
                if kind == 'y' and f'r.{name}' in trace.columns and (not overlay or i == 0):
                    ax.plot(trace.t, trace.columns[f'r.{name}'], 'k--', linewidth=1,
                            label=f'setpoint {name}', drawstyle='steps-post')
        if kind == 'u' and view:
            off_scale += _input_view(ax, runs, names, np.concatenate(view))
        span = float(np.ptp(np.asarray(first.t, dtype=float))) if len(first.t) else 0.0
        for i, run in enumerate(runs):
            if run.marks:
                _mark_states(ax, run.marks, label_them=ax is axes[0] and i == 0, span=span)
        ax.set_ylabel(f'{_TITLES[kind]} [{panel_unit}]')
        ax.grid(True, alpha=0.3)
        ax.legend(loc='upper left', bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
                  fontsize='small')
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    axes[-1].set_xlabel('time [s]')
    _side_table(fig, gs, runs)
    notes = []
    if constant:
        notes.append('constant: ' + ', '.join(constant))
    if off_scale:
        notes.append('limits off scale: ' + ', '.join(dict.fromkeys(off_scale)))
    fig.suptitle(_title(title, runs, '; '.join(notes)), fontsize='medium')
    return fig


def _title(title: str, runs: Sequence[RunPlot], notes: str = '') -> str:
    lines = [title] if title else []
    if len(runs) == 1:
        run = runs[0]
        if run.gains:
            lines.append('gains: ' + gains_text(run.gains))
        if run.overrides:
            lines.append('--set ' + ' '.join(run.overrides))
    else:
        for run in runs:
            extra = [gains_text(run.gains)] if run.gains else []
            extra += ['--set ' + ' '.join(run.overrides)] if run.overrides else []
            if extra:
                lines.append(f'{run.label}: ' + '; '.join(extra))
    if notes:
        lines.append(notes)
    return '\n'.join(lines)


def _input_view(ax, runs: Sequence[RunPlot], names: Sequence[str], values: np.ndarray) -> list[str]:
    """Limits in view drawn, the y-range robust to spikes, clipped samples marked at the edge;
    returns the limits off scale (``u ≤ 1e+04``), for the title to name once."""
    lo, hi, clipped = robust_range(values)
    limits = sorted({v for run in runs for n in names
                     for v in run.limits.get(n, ()) if math.isfinite(v)})
    reach = LIMIT_REACH * (hi - lo)
    for value in limits:
        if lo - reach <= value <= hi + reach:        # near the data (e.g. saturation): in view
            lo, hi = min(lo, value - 0.02 * (hi - lo)), max(hi, value + 0.02 * (hi - lo))
    off_scale: dict[float, list[str]] = {}
    for value in limits:
        if lo <= value <= hi:
            ax.axhline(value, color='0.5', linestyle=':', linewidth=1.2,
                       label=f'limit {_fmt(float(value))}')
        else:
            off_scale[value] = [n for n in names
                                if any(v == value for run in runs for v in run.limits.get(n, ()))]
    if clipped:
        for run in runs:
            for name in names:
                column = run.trace.columns.get(f'u.{name}')
                if column is None:
                    continue
                column = np.asarray(column, dtype=float)
                for side, edge, marker in (('above', hi, '^'), ('below', lo, 'v')):
                    out = column > hi if side == 'above' else column < lo
                    if out.any():
                        extreme = column[out].max() if side == 'above' else column[out].min()
                        ax.plot(np.asarray(run.trace.t)[out], np.full(int(out.sum()), edge),
                                linestyle='none', marker=marker, color='red', markersize=5,
                                clip_on=False,
                                label=f'{name}: {int(out.sum())} samples clipped '
                                      f'(to {_fmt(float(extreme))})')
    ax.set_ylim(lo, hi)
    return [f'{", ".join(chans)} {"≥" if value < lo else "≤"} {_fmt(float(value))}'
            for value, chans in off_scale.items()]


def _mark_states(ax, marks: Sequence[tuple[float, str]], label_them: bool,
                 span: float = 0.0) -> None:
    """A vertical line at each change of the controller's state, its name on the top panel.
    A name closer than ``MARK_GAP`` of the time ``span`` to the previous one on its row moves
    down to the next free row (``MARK_ROWS``), so names do not overlap."""
    last: list[float] = [-math.inf] * len(MARK_ROWS)
    for t, label in marks:
        ax.axvline(t, color='0.35', linestyle=(0, (1, 2)), linewidth=0.9)
        if label_them:
            free = [k for k, x in enumerate(last) if t - x >= MARK_GAP * span]
            row = free[0] if free else int(np.argmin(last))
            last[row] = t
            ax.text(t, MARK_ROWS[row], f' {label}', transform=ax.get_xaxis_transform(),
                    rotation=90, va='top', ha='left', fontsize='x-small', color='0.25')


def _side_table(fig, gs, runs: Sequence[RunPlot]) -> None:
    """The runs' key metrics as a text table beside the legends. The panels narrow (their
    legends move with them) when the table would not fit between the widest legend and the
    figure's edge."""
    lines: list[str] = []
    for run in runs:
        if not run.table:
            continue
        lines.append(run.label)
        width = max(len(name) for name, _ in run.table)
        lines += [f'  {name:<{width}}  {value}' for name, value in run.table]
        lines.append('')
    if not lines:
        return
    text = fig.text(0.0, 0.88, '\n'.join(lines).rstrip(), va='top', ha='left',
                    family='monospace', fontsize='small')
    renderer = fig.canvas.get_renderer()
    fig_width = fig.get_window_extent(renderer).width

    def legends_right() -> float:
        return max((ax.get_legend().get_window_extent(renderer).x1 / fig_width
                    for ax in fig.axes if ax.get_legend() is not None), default=AXES_RIGHT)

    table = text.get_window_extent(renderer).width / fig_width
    overflow = legends_right() + TABLE_GAP + table - 0.995
    if overflow > 0:
        gs.update(right=max(AXES_RIGHT - overflow, 0.3))
    text.set_x(legends_right() + TABLE_GAP)


def plot_runs(runs: Sequence[RunPlot | tuple[str, Trace]], path: str | Path,
              title: str = '') -> Path:
    """Plot one run, or several overlaid (same channels), to a PNG file."""
    fig = figure_runs(runs, title)
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def save_figure(fig, path: Path, title: str = '', dpi: int = 100,
                margins: Mapping[str, float] | None = None) -> Path:
    """Give ``fig`` its title, lay it out, write it to ``path`` and close it. ``margins``
    (``subplots_adjust``'s, fractions of the figure) fix the layout of a figure whose
    labels are known to fit; else ``tight_layout``, which renders the figure once more to
    measure them (half the time of analysis.png)."""
    if title:
        fig.suptitle(title)
    if margins is not None:
        fig.subplots_adjust(**margins)
    else:
        fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
