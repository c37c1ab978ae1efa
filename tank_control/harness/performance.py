"""``metrics.json`` ``loop_performance.<output>`` of a run, and ``tank-control assess`` of any CSV.

Both call ``core/monitoring.assess`` (the code path controller_node's live monitor uses).
A run's loops: each output channel the controller reads with its setpoint, paired with the
input at the same position of the controller's ``input_names`` (a controller with as many
inputs as outputs); its dead time ``monitor.dead_time``, or at 0 the plant kind's linear model's
(a SISO plant), else the model the controller carries (``core/monitoring/dead_time.py``), else
none (no Harris index, the reason in ``dead_time_source``); its output limits from the
controller's, ``ms`` from the loop analysis on the plant's model when there is one.
docs/monitoring.md.
"""
from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tank_control.core.monitoring import MonitorConfig, assess
from tank_control.core.monitoring.assess import DEFAULT, PREFIX
from tank_control.core.monitoring.dead_time import DeadTime, controller_dead_times, given_or
from tank_control.core.monitoring.modes import flags_at
from tank_control.core.params import ConfigError, config_from
from tank_control.core.trace import Trace


def _loops(trace: Trace, controller: Mapping[str, Any]) -> list[tuple[str, str]]:
    outputs = list(controller.get('output_names') or trace.channels('y'))
    inputs = list(controller.get('input_names') or trace.channels('u'))
    if len(outputs) != len(inputs):
        return []
    return [(y, u) for y, u in zip(outputs, inputs)
            if f'y.{y}' in trace.columns and f'r.{y}' in trace.columns
            and f'u.{u}' in trace.columns]


def _number(value: Any, default: float) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return default
    return out if math.isfinite(out) else default


def trace_performance(trace: Trace, sections: Mapping[str, Mapping[str, Any]],
                      controller_params: Mapping[str, Any] | None = None,
                      input_limits: Mapping[str, tuple[float, float]] | None = None,
                      ms: float | None = None, config: MonitorConfig | None = None,
                      modes: Sequence[Sequence[Any]] | None = None) -> dict[str, Any]:
    """``loop_performance``: output channel → :func:`core.monitoring.assess` body; settings
    ``config``, default the controller's ``monitor.*`` (with ``monitor.dead_time`` 0: the
    process model's dead time, :func:`run_dead_times`); ``modes``: the controller's
    ``[t, manual, fail_safe]`` changes (core/monitoring/modes.py; none: the manual and
    fail-safe times are not known, null)."""
    controller = dict(sections.get('controller', {}))
    controller.update(controller_params or {})
    if config is None:
        try:
            config = config_from(MonitorConfig, {k: v for k, v in controller.items()
                                                 if k.startswith(PREFIX)})
        except ConfigError:
            config = DEFAULT
    plant = sections.get('plant', {})
    ts_values = [controller.get('sample_time'), plant.get('sample_time')]
    sample_time = next((v for v in (_number(x, 0.0) for x in ts_values) if v > 0), 0.0)
    if sample_time <= 0.0 and len(trace) > 1:
        sample_time = float(np.median(np.diff(trace.t)))
    if sample_time <= 0.0:
        return {}
    limits = dict(input_limits or {})
    loops = _loops(trace, controller)
    known = run_dead_times(sections, controller, [y for y, _ in loops])
    out = {}
    for y, u in loops:
        lo, hi = limits.get(u, (_number(controller.get('u_min'), -math.inf),
                                _number(controller.get('u_max'), math.inf)))
        cfg = config
        if cfg.load_ti == 0.0 and _number(controller.get('ti'), 0.0) > 0.0:
            cfg = replace(cfg, load_ti=_number(controller.get('ti'), 0.0))
        t, yy, rr, uu = trace.t, trace[f'y.{y}'], trace[f'r.{y}'], trace[f'u.{u}']
        # the controller samples every controller sample time: assess at its instants
        step = max(int(round(sample_time / _plant_ts(trace, plant, sample_time))), 1)
        # a run starts its loop: the first monitor.settle_time is a start-up response
        flags = flags_at(modes, t[::step]) if modes else None
        out[y] = assess(t[::step], yy[::step], rr[::step], uu[::step], sample_time, cfg,
                        u_limits=(lo, hi), ms=ms, start_is_change=True,
                        dead_time=given_or(config, known[y]),
                        manual=flags[0] if flags else None,
                        fail_safe=flags[1] if flags else None)
    return out


def run_dead_times(sections: Mapping[str, Mapping[str, Any]], controller: Mapping[str, Any],
                   outputs: Sequence[str]) -> dict[str, DeadTime]:
    """Each loop's dead time as known of its process: the plant kind's linear model (one
    loop), else the controller's models, else None with the reason."""
    from tank_control.core import scenario as core_scenario
    try:
        setup = core_scenario.controller_setup(controller, given=())
        known = controller_dead_times(setup.kind, setup.settings, outputs)
    except (ConfigError, ValueError, ArithmeticError) as exc:
        known = {y: DeadTime(None, f'dead time not known ({exc})') for y in outputs}
    if len(outputs) == 1:
        try:
            plant = core_scenario.plant_setup(sections.get('plant', {}))
            model = plant.kind.linear(plant.model) if plant.kind.linear is not None else None
        except (ConfigError, ValueError, ArithmeticError):
            model = None
        if model is not None and math.isfinite(model.dead_time):
            known[outputs[0]] = DeadTime(float(model.dead_time),
                                         f"plant's model ({model.describe()})")
    return known


def _plant_ts(trace: Trace, plant: Mapping[str, Any], default: float) -> float:
    ts = _number(plant.get('sample_time'), 0.0)
    if ts <= 0.0 and len(trace) > 1:
        ts = float(np.median(np.diff(trace.t)))
    return ts if ts > 0.0 else default


# ------------------------------------------------------------------------------ assess CSV
class AssessError(ValueError):
    """A CSV or column that cannot be assessed; the message names it."""


def read_columns(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    """The named columns of a CSV with a header row, as floats (an empty or non-numeric cell is
    NaN: that row is left out of the indices)."""
    try:
        with open(path, newline='') as f:
            reader = csv.reader(f)
            header = [h.strip() for h in next(reader)]
            missing = [n for n in names if n not in header]
            if missing:
                raise AssessError(f'{path}: no column {missing[0]!r}; columns: '
                                  + ', '.join(header))
            where = [header.index(n) for n in names]
            rows = []
            for row in reader:
                if not row:
                    continue
                rows.append([_cell(row, i) for i in where])
    except OSError as exc:
        raise AssessError(f'{path}: {exc.strerror or exc}') from None
    except StopIteration:
        raise AssessError(f'{path}: empty file (a header row is needed)') from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise AssessError(f'{path}: not a CSV file ({exc})') from None
    data = np.asarray(rows, dtype=float).reshape(-1, len(names))
    return {n: data[:, i] for i, n in enumerate(names)}


def _cell(row: list[str], i: int) -> float:
    try:
        return float(row[i])
    except (IndexError, ValueError):
        return math.nan


def assess_csv(path: Path, pv: str, sp: str, op: str, sample_time: float,
               dead_time: float = 0.0, time_column: str | None = None,
               op_limits: tuple[float, float] = (-math.inf, math.inf),
               manual: str | None = None, config: MonitorConfig = DEFAULT
               ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The assessment of one loop recorded in a CSV, and the columns read (``t`` made from the
    row number and ``sample_time`` without a time column)."""
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise AssessError(f'--sample-time: {sample_time:g}; allowed a positive number of seconds')
    if not (math.isfinite(dead_time) and dead_time >= 0):
        raise AssessError(f'--dead-time: {dead_time:g}; allowed a number of seconds >= 0')
    lo, hi = op_limits
    if math.isnan(lo) or math.isnan(hi) or lo >= hi:
        raise AssessError(f'--op-limits: {lo:g} {hi:g}; allowed LO < HI')
    names = [pv, sp, op] + ([time_column] if time_column else []) + ([manual] if manual else [])
    cols = read_columns(path, names)
    n = cols[pv].size
    if n < 2:
        raise AssessError(f'{path}: {n} data rows; at least 2 are needed')
    t = cols[time_column] if time_column else np.arange(n) * sample_time
    flags = (np.isfinite(cols[manual]) & (cols[manual] != 0)) if manual else None   # empty: auto
    body = assess(t, cols[pv], cols[sp], cols[op], sample_time,
                  replace(config, dead_time=dead_time), u_limits=op_limits, manual=flags)
    return body, {'t': t, 'pv': cols[pv], 'sp': cols[sp], 'op': cols[op]}


def plot_assessment(columns: Mapping[str, np.ndarray], body: Mapping[str, Any], path: Path,
                    title: str = '') -> Path:
    """PV and SP, OP and the OP–PV phase plot (a stiction limit cycle is a parallelogram),
    with the verdict as the title."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig = plt.figure(figsize=(11, 6))
    grid = fig.add_gridspec(2, 2, width_ratios=(2.2, 1))
    ax_y = fig.add_subplot(grid[0, 0])
    ax_u = fig.add_subplot(grid[1, 0], sharex=ax_y)
    ax_p = fig.add_subplot(grid[:, 1])
    t = columns['t']
    ax_y.plot(t, columns['pv'], lw=0.8, label='PV')
    ax_y.plot(t, columns['sp'], lw=1.0, ls='--', label='SP')
    ax_y.legend(loc='upper right')
    ax_y.set_ylabel('PV, SP')
    ax_u.plot(t, columns['op'], lw=0.8, color='C2')
    ax_u.set_ylabel('OP')
    ax_u.set_xlabel('t [s]')
    ax_p.plot(columns['op'], columns['pv'], lw=0.5, color='C3')
    ax_p.set_xlabel('OP')
    ax_p.set_ylabel('PV')
    osc = body['oscillation']
    harris = body['harris_index']
    lines = [f'Harris {harris:.2f}' if harris is not None else 'Harris –',
             f'oscillation: period {osc["period"]:.3g} s, amplitude {osc["amplitude"]:.3g}'
             if osc['detected'] else 'no oscillation',
             f'stiction index {body["stiction"]["index"]:.2f}'
             if body['stiction']['index'] is not None else '']
    ax_p.set_title('\n'.join(x for x in lines if x), fontsize=9)
    fig.suptitle(f'{title}: {body["verdict"]}' if title else body['verdict'])
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path
