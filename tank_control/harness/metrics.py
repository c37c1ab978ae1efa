"""Metrics of a run, computed from its trace (``metrics.json``).

Per output channel (one with a setpoint column ``r.<name>``):

* ``iae`` = ∫|e| dt and ``ise`` = ∫e² dt with e = r − y (trapezoidal rule,
  ``core.analysis.step_metrics``). Units: channel unit·s and unit²·s.
* ``steps``: one entry per setpoint change. A change is a run of consecutive
  samples where r moves (a step is one sample, a ramp several); it goes from
  ``r_from`` (the value before) to ``r_to`` (the value once r is constant) and
  its window lasts until the next change or the end of the run. When the run
  starts away from its setpoint (|r(0) − y(0)| > 0), t = 0 counts as a change
  from y(0). Per change (Δ = r_to − r_from, t from the change's start):

  - ``overshoot_pct``: max(0, max sign(Δ)·(y − r_to)) / |Δ| · 100;
  - ``rise_time``: time from 10 % to 90 % of Δ, None if 90 % is never reached;
  - ``settling_time``: time after which |y − r_to| stays within 2 % of |Δ|,
    None if it never does within the window;
  - ``ss_error``: r_to − mean(y) over the last 5 % of the window;
  - ``peak``, ``peak_time`` (computed by ``core.analysis.step_metrics``).

  A disturbance change also ends the window of a setpoint change. Per
  disturbance change (``disturbance_steps``): ``peak_error`` |r − y| and
  ``peak_signed``, ``peak_time`` after the change, ``iae`` and signed
  ``integral_error`` over its window, and ``final_error`` (mean over the last 5 %).

Per input channel ``u.<name>``: ``min``, ``max``, ``total_variation`` Σ|Δu|,
and ``constraint_violations`` (samples outside the controller's
``[u_min, u_max]``, 1e-9 tolerance, when limits are known).

Run (``sampling_metrics``): ``missed_samples`` — plant ticks without a recorded
measurement (gaps, and before the first one when the clock starts at 0);
``max_jitter`` [s] — largest deviation of the spacing of successive
measurements from the plant sample time: of their stamps in sim/lockstep (0 on
the exact tick grid), of their arrival times at the recorder in wall mode;
``late_samples`` — the sum of ``late_by_signal`` (``TraceTable.late``: per
answer signal the due instants whose answer was not recorded or was reported
late by its consumer; ``harness/trace.py``), by the same rule in every clock mode.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from tank_control.core.analysis import step_metrics as sm
from tank_control.harness.trace import TraceTable

SS_WINDOW = 0.05


def output_metrics(t: np.ndarray, y: np.ndarray, r: np.ndarray,
                   disturbance_changes: Sequence[int] = ()) -> dict[str, Any]:
    """IAE, ISE, per-setpoint-change and per-disturbance-change metrics of one output.

    ``disturbance_changes``: sample indices where a disturbance changes; they also
    end the window of a setpoint change (its response is not mixed with a load
    response)."""
    e = r - y
    finite = np.isfinite(e)
    enough = int(finite.sum()) >= 2
    result: dict[str, Any] = {
        'iae': sm.iae(t[finite], e[finite]) if enough else 0.0,
        'ise': sm.ise(t[finite], e[finite]) if enough else 0.0,
        'steps': [],
        'disturbance_steps': [],
    }
    changes = setpoint_changes(t, y, r)
    starts = sorted({c[0] for c in changes} | set(disturbance_changes))
    for start, _, stop, r_from, r_to in changes:
        stop = min([stop] + [i for i in starts if i > start])
        result['steps'].append(change_metrics(t[start:stop], y[start:stop], r_from, r_to))
    for start in disturbance_changes:
        stop = min([len(t)] + [i for i in starts if i > start])
        result['disturbance_steps'].append(load_metrics(t[start:stop], e[start:stop]))
    return result


def load_metrics(t: np.ndarray, e: np.ndarray) -> dict[str, Any]:
    """Response of an output to a disturbance change over its window: the largest error
    |r − y| (``peak_error``, signed ``peak_signed``) and when (``peak_time`` after the
    change), IAE and the signed ∫e dt (``integral_error``, trapezoidal; 000 eq. 10 gives it
    in closed form for integrating plants) over the window, and the mean error over its
    last 5 % (``final_error``)."""
    finite = np.isfinite(e)
    if finite.sum() < 2:
        return {'t': float(t[0]) if len(t) else None, 'peak_error': None, 'peak_signed': None,
                'peak_time': None, 'iae': None, 'integral_error': None, 'final_error': None}
    t, e = t[finite], e[finite]
    i = int(np.argmax(np.abs(e)))
    tail = max(1, int(math.ceil(SS_WINDOW * len(e))))
    integral = float(np.sum(0.5 * (e[1:] + e[:-1]) * np.diff(t)))
    return {'t': float(t[0]), 'peak_error': float(abs(e[i])), 'peak_signed': float(e[i]),
            'peak_time': float(t[i] - t[0]), 'iae': sm.iae(t, e), 'integral_error': integral,
            'final_error': float(np.mean(e[-tail:]))}


def disturbance_change_indices(trace: TraceTable, rel_tol: float = 1e-9) -> list[int]:
    """Sample indices where any disturbance column changes (first sample of a ramp)."""
    indices: set[int] = set()
    for name in trace.channels('d'):
        d = trace.columns[f'd.{name}']
        scale = max(1.0, float(np.nanmax(np.abs(d)))) if np.isfinite(d).any() else 1.0
        moving = np.zeros(len(d), dtype=bool)
        moving[1:] = np.abs(np.diff(d)) > rel_tol * scale
        indices |= {int(i) for i in np.nonzero(moving & ~np.roll(moving, 1))[0]}
    return sorted(indices)


def change_metrics(t: np.ndarray, y: np.ndarray, r_from: float, r_to: float) -> dict[str, Any]:
    """Metrics of one setpoint change over its window (``core.analysis.step_metrics`` with the
    response normalised by the setpoint change r_from → r_to)."""
    entry: dict[str, Any] = {'t': float(t[0]), 'r_from': r_from, 'r_to': r_to,
                             'overshoot_pct': None, 'rise_time': None, 'settling_time': None,
                             'ss_error': None}
    finite = np.isfinite(y)
    if finite.sum() < 2 or r_to == r_from:
        return entry
    m = sm.step_metrics(t[finite], y[finite], r_final=r_to, y0=r_from, final_window=SS_WINDOW)
    entry.update(overshoot_pct=m.overshoot, rise_time=m.rise_time,
                 settling_time=m.settling_time, ss_error=m.steady_state_error,
                 peak=m.peak, peak_time=m.peak_time)
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in entry.items()}


def setpoint_changes(t: np.ndarray, y: np.ndarray, r: np.ndarray,
                     rel_tol: float = 1e-9) -> list[tuple[int, int, int, float, float]]:
    """``(start, constant_from, stop, r_from, r_to)`` index ranges of each setpoint change."""
    n = len(r)
    if n == 0:
        return []
    scale = max(1.0, float(np.nanmax(np.abs(r))) if np.isfinite(r).any() else 1.0)
    tol = rel_tol * scale
    moving = np.zeros(n, dtype=bool)
    moving[1:] = np.abs(np.diff(r)) > tol
    changes: list[list[Any]] = []
    if math.isfinite(y[0]) and math.isfinite(r[0]) and abs(r[0] - y[0]) > tol:
        changes.append([0, 0, float(y[0])])
    i = 1
    while i < n:
        if moving[i]:
            j = i
            while j + 1 < n and moving[j + 1]:
                j += 1
            changes.append([i, j, float(r[i - 1])])
            i = j + 1
        else:
            i += 1
    out = []
    for k, (start, last_move, r_from) in enumerate(changes):
        stop = changes[k + 1][0] if k + 1 < len(changes) else n
        out.append((start, last_move, stop, r_from, float(r[last_move])))
    return out


def input_metrics(u: np.ndarray, u_min: float = -math.inf,
                  u_max: float = math.inf) -> dict[str, Any]:
    """Min, max, total variation and the number of samples outside [u_min, u_max]."""
    finite = u[np.isfinite(u)]
    if finite.size == 0:
        return {'min': None, 'max': None, 'total_variation': None, 'constraint_violations': 0}
    return {
        'min': float(finite.min()),
        'max': float(finite.max()),
        'total_variation': float(np.sum(np.abs(np.diff(finite)))),
        'constraint_violations': int(np.sum((finite < u_min - 1e-9) | (finite > u_max + 1e-9))),
    }


def trace_metrics(trace: TraceTable,
                  input_limits: Mapping[str, tuple[float, float]] | None = None) -> dict[str, Any]:
    """``outputs`` and ``inputs`` sections of ``metrics.json`` for a trace."""
    limits = input_limits or {}
    loads = disturbance_change_indices(trace)
    outputs = {name: output_metrics(trace.t, trace.columns[f'y.{name}'], trace.columns[f'r.{name}'],
                                    loads)
               for name in trace.channels('y') if f'r.{name}' in trace.columns}
    inputs = {name: input_metrics(trace.columns[f'u.{name}'], *limits.get(name, (-math.inf, math.inf)))
              for name in trace.channels('u')}
    return {'outputs': outputs, 'inputs': inputs}


def sampling_metrics(stamps_ns: np.ndarray, sample_time: float | None,
                     start_ns: int | None = None) -> dict[str, Any]:
    """Ticks that should have been there but are not (gaps in the measurement stamps, and
    before the first one when the clock starts at ``start_ns``), and the largest deviation
    of the measurement stamp spacing from the plant sample time [s]."""
    if len(stamps_ns) < 2 or not sample_time:
        return {'missed_samples': 0, 'max_jitter': 0.0}
    ts_ns = int(round(sample_time * 1e9))
    gaps = np.diff(np.asarray(stamps_ns, dtype=np.int64))
    missed = int(np.sum(np.maximum(np.round(gaps / ts_ns) - 1, 0)))
    if start_ns is not None:
        missed += int(round((int(stamps_ns[0]) - start_ns) / ts_ns))
    jitter = float(np.max(np.abs(gaps - ts_ns)) / 1e9)
    return {'missed_samples': missed, 'max_jitter': jitter}
