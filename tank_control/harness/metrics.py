"""Metrics of a run, computed from its trace: the body of ``metrics.json``.

Events (setpoint and disturbance changes) and their windows; per output IAE, ISE, per-step and
deviation metrics; per input range, total variation and constraint violations; the run's
sampling figures. Every field and its definition: docs/harness.md ("metrics.json").
Units: the channels' units, times in s of plant time; e = r − y.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.analysis import step_metrics as sm
from tank_control.core.trace import Trace

SS_WINDOW = 0.05
#: A change smaller than this fraction of the channel's magnitude is not an event.
STEP_TOL = 1e-3
#: Sample-to-sample differences below this fraction of the magnitude (at least of 1
#: unit) are floating-point rounding, not movement.
MOVE_TOL = 1e-9
#: The run starts with a setpoint change only if |r(0) − y(0)| exceeds this many σ̂ of the
#: output's measurement noise (besides STEP_TOL): noise on y(0) is no setpoint change.
INITIAL_NOISE_K = 5.0


@dataclass(frozen=True)
class Event:
    """One change of a setpoint or disturbance channel: samples ``start`` (first moved)
    to ``settled`` (new value reached), ``value_from`` → ``value_to``; ``stop`` is the
    window's end (exclusive sample index)."""

    kind: str            # 'setpoint' | 'disturbance'
    channel: str
    start: int
    settled: int
    value_from: float
    value_to: float
    stop: int = -1


def column_changes(v: np.ndarray, initial: float | None = None,
                   step_tol: float = STEP_TOL, initial_tol: float = 0.0
                   ) -> list[tuple[int, int, float, float]]:
    """``(start, settled, from, to)`` of each change of the column ``v``: consecutive
    samples moving in one direction are one change (a ramp); a change smaller than
    ``step_tol`` × max(|v|, |initial|) is dropped. ``initial``: the value before the
    first sample (a setpoint's output y(0)); if it differs from v[0] by more than that and
    than ``initial_tol`` (the noise on y(0)), sample 0 is a change from it."""
    v = np.asarray(v, dtype=float)
    n = len(v)
    if n == 0:
        return []
    magnitudes = [float(np.nanmax(np.abs(v)))] if np.isfinite(v).any() else [0.0]
    if initial is not None and math.isfinite(initial):
        magnitudes.append(abs(initial))
    scale = max(magnitudes)
    tol_move = MOVE_TOL * max(1.0, scale)
    tol_step = max(tol_move, step_tol * scale)
    diff = np.zeros(n)
    diff[1:] = np.diff(v)
    direction = np.where(np.abs(diff) > tol_move, np.sign(diff), 0.0)   # NaN → 0
    changes: list[tuple[int, int, float, float]] = []
    if (initial is not None and math.isfinite(initial) and math.isfinite(v[0])
            and abs(v[0] - initial) > max(tol_step, initial_tol)):
        changes.append((0, 0, float(initial), float(v[0])))
    i = 1
    while i < n:
        if direction[i] != 0.0:
            j = i
            while j + 1 < n and direction[j + 1] == direction[i]:
                j += 1
            if abs(v[j] - v[i - 1]) > tol_step:
                changes.append((i, j, float(v[i - 1]), float(v[j])))
            i = j + 1
        else:
            i += 1
    return changes


def setpoint_changes(t: np.ndarray, y: np.ndarray, r: np.ndarray, step_tol: float = STEP_TOL
                     ) -> list[tuple[int, int, int, float, float]]:
    """``(start, settled, stop, r_from, r_to)`` of each setpoint change of one output;
    ``stop`` is the next change of this setpoint (or the end), not of other events."""
    y0 = float(y[0]) if len(y) else None
    changes = column_changes(r, y0, step_tol, INITIAL_NOISE_K * sm.noise_std(y))
    stops = [c[0] for c in changes[1:]] + [len(r)]
    return [(start, settled, stop, r_from, r_to)
            for (start, settled, r_from, r_to), stop in zip(changes, stops)]


def find_events(outputs: Mapping[str, tuple[np.ndarray, np.ndarray]],
                disturbances: Mapping[str, np.ndarray], n: int,
                step_tol: float = STEP_TOL) -> list[Event]:
    """Every setpoint change of ``outputs`` (name → (y, r)) and every change of
    ``disturbances`` (name → d), in time order, each with its window end ``stop``:
    the first sample of the next event of any kind, or ``n``."""
    found = [Event('setpoint', name, *c)
             for name, (y, r) in outputs.items()
             for c in column_changes(r, float(y[0]) if len(y) else None, step_tol,
                                     INITIAL_NOISE_K * sm.noise_std(y))]
    found += [Event('disturbance', name, *c)
              for name, d in disturbances.items() for c in column_changes(d, None, step_tol)]
    starts = sorted({e.start for e in found})
    return [replace(e, stop=next((s for s in starts if s > e.start), n))
            for e in sorted(found, key=lambda e: (e.start, e.kind != 'setpoint'))]


def _clean(entry: dict[str, Any]) -> dict[str, Any]:
    """NaN/inf → None (JSON has no NaN)."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in entry.items()}


def change_metrics(t: np.ndarray, y: np.ndarray, r_from: float, r_to: float,
                   noise: float = 0.0) -> dict[str, Any]:
    """Metrics of one setpoint change over its window (``core.analysis.step_metrics`` with the
    response normalised by the setpoint change r_from → r_to, read through measurement
    noise of σ ``noise`` [unit])."""
    entry: dict[str, Any] = {'t': float(t[0]), 'r_from': r_from, 'r_to': r_to,
                             'overshoot_pct': None, 'rise_time': None, 'settling_time': None,
                             'ss_error': None}
    finite = np.isfinite(y)
    if finite.sum() < 2 or r_to == r_from:
        return entry
    m = sm.step_metrics(t[finite], y[finite], r_final=r_to, y0=r_from, final_window=SS_WINDOW,
                        noise=noise)
    entry.update(overshoot_pct=m.overshoot, rise_time=m.rise_time,
                 settling_time=m.settling_time, ss_error=m.steady_state_error,
                 peak=m.peak, peak_time=m.peak_time, settling_band_pct=m.band * 100.0,
                 smoothing=m.smoothing)
    return _clean(entry)


def load_metrics(t: np.ndarray, e: np.ndarray, noise: float = 0.0) -> dict[str, Any]:
    """Deviation metrics (docs/harness.md) of the error ``e`` over a window starting at t[0];
    ``noise``: σ of the measurement noise on e [unit]."""
    finite = np.isfinite(e)
    if finite.sum() < 2:
        return {'peak_error': None, 'peak_signed': None, 'peak_time': None, 'iae': None,
                'integral_error': None, 'recovery_time': None, 'final_error': None,
                'initial_error': None}
    m = sm.deviation_metrics(t[finite], e[finite], final_window=SS_WINDOW, noise=noise)
    return _clean(m.as_dict())


def signal_metrics(t: np.ndarray, outputs: Mapping[str, tuple[np.ndarray, np.ndarray]],
                   disturbances: Mapping[str, np.ndarray] | None = None,
                   step_tol: float = STEP_TOL) -> dict[str, Any]:
    """``events`` and ``outputs`` sections (docs/harness.md) for outputs name → (y, r) and
    disturbances name → d sampled at ``t``."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    events = find_events(outputs, disturbances or {}, n, step_tol)
    errors = {name: r - y for name, (y, r) in outputs.items()}
    noise = {name: sm.noise_std(y) for name, (y, r) in outputs.items()}
    t_end = [float(t[min(ev.stop, n - 1)]) if n else None for ev in events]

    def label(ev: Event) -> str:
        return ('r.' if ev.kind == 'setpoint' else 'd.') + ev.channel

    def coincident(ev: Event) -> list[str]:
        return [label(o) for o in events if o.start == ev.start and o is not ev]

    result: dict[str, Any] = {}
    for name, (y, r) in outputs.items():
        e = errors[name]
        finite = np.isfinite(e)
        enough = int(finite.sum()) >= 2
        result[name] = {'iae': sm.iae(t[finite], e[finite]) if enough else 0.0,
                        'ise': sm.ise(t[finite], e[finite]) if enough else 0.0,
                        'noise_std': noise[name],
                        'steps': [], 'disturbance_steps': []}
    load_instants: dict[int, list[int]] = {}
    for k, ev in enumerate(events):
        window = slice(ev.start, ev.stop)
        if ev.kind == 'disturbance':
            load_instants.setdefault(ev.start, []).append(k)
            continue
        y = outputs[ev.channel][0]
        entry = change_metrics(t[window], y[window], ev.value_from, ev.value_to, noise[ev.channel])
        own_steps = {o.channel for o in events if o.start == ev.start and o.kind == 'setpoint'}
        entry = {'t': entry.pop('t'), 't_end': t_end[k], **entry,
                 'interaction': {other: load_metrics(t[window], errors[other][window], noise[other])
                                 for other in outputs if other not in own_steps},
                 'coincident': coincident(ev)}
        result[ev.channel]['steps'].append(entry)
    for start, ks in load_instants.items():
        first = events[ks[0]]
        window = slice(start, first.stop)
        changes = {events[k].channel: [events[k].value_from, events[k].value_to] for k in ks}
        others = [label(o) for o in events if o.start == start and o.kind == 'setpoint']
        for name in outputs:
            result[name]['disturbance_steps'].append(
                {'t': float(t[start]), 't_end': t_end[ks[0]], 'changes': changes,
                 'coincident': others,
                 **load_metrics(t[window], errors[name][window], noise[name])})
    return {'events': [{'t': float(t[ev.start]), 't_end': t_end[k], 'kind': ev.kind,
                        'channel': ev.channel, 'from': ev.value_from, 'to': ev.value_to}
                       for k, ev in enumerate(events)],
            'outputs': result}


def output_metrics(t: np.ndarray, y: np.ndarray, r: np.ndarray,
                   step_tol: float = STEP_TOL) -> dict[str, Any]:
    """IAE, ISE and per-setpoint-change metrics of a single output without disturbances."""
    return signal_metrics(t, {'y': (y, r)}, {}, step_tol)['outputs']['y']


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


def trace_metrics(trace: Trace,
                  input_limits: Mapping[str, tuple[float, float]] | None = None,
                  step_tol: float = STEP_TOL) -> dict[str, Any]:
    """``events``, ``outputs`` and ``inputs`` sections of ``metrics.json`` for a trace."""
    limits = input_limits or {}
    outputs = {name: (trace.columns[f'y.{name}'], trace.columns[f'r.{name}'])
               for name in trace.channels('y') if f'r.{name}' in trace.columns}
    disturbances = {name: trace.columns[f'd.{name}'] for name in trace.channels('d')}
    body = signal_metrics(trace.t, outputs, disturbances, step_tol)
    inputs = {name: input_metrics(trace.columns[f'u.{name}'], *limits.get(name, (-math.inf, math.inf)))
              for name in trace.channels('u')}
    return {'outputs': body['outputs'], 'inputs': inputs, 'events': body['events']}


def sampling_metrics(stamps_ns: np.ndarray, sample_time: float | None,
                     start_ns: int | None = None) -> dict[str, Any]:
    """Ticks that should have been there but are not (gaps in the measurement stamps, and
    before the first one when the clock starts at ``start_ns``), and the largest deviation
    of the measurement stamp spacing from the plant sample time [s]."""
    stats = SamplingStats(sample_time, start_ns)
    for stamp in np.asarray(stamps_ns, dtype=np.int64).tolist():
        stats.add(stamp)
    return stats.result()


class SamplingStats:
    """``sampling_metrics`` fed one stamp [ns] at a time, in order (a run's rows as they are
    written)."""

    def __init__(self, sample_time: float | None, start_ns: int | None = None) -> None:
        self.ts_ns = int(round(sample_time * 1e9)) if sample_time else 0
        self.start_ns = start_ns
        self.count = 0
        self.first: int | None = None
        self.last: int | None = None
        self.missed = 0
        self.jitter_ns = 0

    def add(self, stamp_ns: int) -> None:
        self.count += 1
        if self.last is None:
            self.first = stamp_ns
        elif self.ts_ns:
            gap = stamp_ns - self.last
            self.missed += max(round(gap / self.ts_ns) - 1, 0)
            self.jitter_ns = max(self.jitter_ns, abs(gap - self.ts_ns))
        self.last = stamp_ns

    def result(self) -> dict[str, Any]:
        if self.count < 2 or not self.ts_ns:
            return {'missed_samples': 0, 'max_jitter': 0.0}
        missed = self.missed
        if self.start_ns is not None and self.first is not None:
            missed += int(round((self.first - self.start_ns) / self.ts_ns))
        return {'missed_samples': int(missed), 'max_jitter': self.jitter_ns / 1e9}
