"""One loop's performance assessment and its one-line verdict, over a whole record or live.

:func:`assess` is the one code path: ``metrics.json`` ``loop_performance.<output>`` (harness),
``tank-control assess FILE.csv`` (offline, any historian's data) and :class:`LoopMonitor` (live,
a sliding window; controller_node publishes its :meth:`LoopMonitor.summary`) all call it.
Settings: :class:`MonitorConfig` (parameters ``monitor.*``, declared once). Indices:
``core/monitoring/indices.py``. Documentation: docs/monitoring.md.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.monitoring import indices as ix
from tank_control.core.monitoring.dead_time import DeadTime
from tank_control.core.params import param


PREFIX = 'monitor.'
"""The parameters' prefix (controller_node's; not the controller kind's)."""


@dataclass(frozen=True)
class MonitorConfig:
    """Control performance monitoring of a loop (docs/monitoring.md)."""

    window: float = param(600.0, 'live: the sliding window assessed', unit='s', min=1e-3,
                          max=1e7, name='monitor.window')
    period: float = param(10.0, 'live: the assessment is recomputed every period', unit='s',
                          min=1e-3, max=1e6, name='monitor.period')
    dead_time: float = param(0.0, 'the loop\'s dead time L for the Harris index (b = floor(L/Ts)'
                             ' + 1 samples); 0 = from the process model the controller (in a run: '
                             'the plant) carries; none known: no Harris index', unit='s',
                             min=0.0, max=1e6, name='monitor.dead_time')
    ar_order: int = param(20, 'order of the AR model of the control error (Harris index)',
                          min=1, max=200, name='monitor.ar_order')
    harris_limit: float = param(0.5, 'Harris index below this: "retune (sluggish …)"', min=0.0,
                                max=1.0, name='monitor.harris_limit')
    settle_time: float = param(60.0, 'after a setpoint change this long is left out of the '
                               'regulation indices (Harris, oscillation, stiction); the change '
                               'has its own IAE', unit='s', min=0.0, max=1e7,
                               name='monitor.settle_time')
    regularity_limit: float = param(1.0, 'ACF zero-crossing regularity above this: oscillation '
                                    '[Thornhill2003]', min=0.0, max=1e3,
                                    name='monitor.regularity_limit')
    acf_peak_limit: float = param(0.2, 'and the autocorrelation\'s first peak above this '
                                  '(an oscillation, not filtered noise)', min=0.0, max=1.0,
                                  name='monitor.acf_peak_limit')
    load_amplitude: float = param(0.0, 'Hägglund\'s acceptable error amplitude a: a half-wave '
                                  'of the error with IAE above 2a/ω_u (ω_u = 2π/Ti) is a load '
                                  'disturbance, more than 10 per 50·Ti an oscillation '
                                  '[Hagglund1995]; 0 = not used', unit='output units', min=0.0,
                                  max=1e12, name='monitor.load_amplitude')
    load_ti: float = param(0.0, 'the integral time Ti of Hägglund\'s detector; 0 = the '
                           'controller\'s ti where known (runs), else not used', unit='s',
                           min=0.0, max=1e7, name='monitor.load_ti')
    min_amplitude: float = param(0.0, 'an oscillation smaller than this is not reported',
                                 unit='output units', min=0.0, max=1e12,
                                 name='monitor.min_amplitude')
    stiction_limit: float = param(0.6, 'Horch cross-correlation index above this with an '
                                  'oscillation: stiction suspected [Horch1999]', min=0.0,
                                  max=1.0, name='monitor.stiction_limit')
    saturation_limit: float = param(20.0, 'time at an output limit above this: "saturated"',
                                    unit='%', min=0.0, max=100.0,
                                    name='monitor.saturation_limit')
    manual_limit: float = param(50.0, 'time in manual above this: "in manual"', unit='%',
                                min=0.0, max=100.0, name='monitor.manual_limit')
    fail_safe_limit: float = param(5.0, 'time on the fail-safe output above this: "fail-safe"',
                                   unit='%', min=0.0, max=100.0,
                                   name='monitor.fail_safe_limit')


DEFAULT = MonitorConfig()
"""The declared defaults."""


def _pct(flags: np.ndarray | None) -> float | None:
    if flags is None or flags.size == 0:
        return None
    return 100.0 * float(np.mean(np.asarray(flags, dtype=bool)))


def assess(t: np.ndarray, y: np.ndarray, r: np.ndarray, u: np.ndarray, sample_time: float,
           config: MonitorConfig = DEFAULT, *, u_limits: tuple[float, float] = (
               -math.inf, math.inf), manual: np.ndarray | None = None,
           fail_safe: np.ndarray | None = None, ms: float | None = None,
           start_is_change: bool = False, dead_time: DeadTime | None = None
           ) -> dict[str, Any]:
    """The indices and verdict of one loop: process output ``y``, setpoint ``r``, controller
    output ``u`` at times ``t`` [s] sampled every ``sample_time`` [s]; ``u_limits`` the
    controller's output limits, ``manual``/``fail_safe`` per-sample flags if known, ``ms`` the
    loop's maximum sensitivity if known (named in a "retune" verdict). Rows with a non-finite
    value are dropped; ``start_is_change``: the record starts with the loop (its first
    ``monitor.settle_time`` is a start-up response, not regulation). JSON-ready (None where an
    index cannot be computed). ``dead_time``: the loop's dead time and its source
    (``core/monitoring/dead_time.py``; ``seconds`` None: not known, no Harris index); default
    ``config.dead_time`` as given."""
    manual_pct, fail_safe_pct = _pct(manual), _pct(fail_safe)
    if dead_time is None:
        dead_time = DeadTime(config.dead_time, 'monitor.dead_time')
    t, y, r, u = ix.finite_rows(t, y, r, u)
    e = r - y
    b = (ix.dead_time_samples(dead_time.seconds, sample_time)
         if dead_time.seconds is not None else None)
    segments = ix.regulatory_segments(t, r, config.settle_time,
                                      start_is_change=start_is_change)
    # regulation: the stretches of constant setpoint joined, each about its own mean
    e_reg = [e[s] for s in segments]

    def joined(v: np.ndarray) -> np.ndarray:
        return (np.concatenate([v[s] - np.mean(v[s]) for s in segments]) if segments
                else np.zeros(0))

    osc = ix.oscillation(joined(e), sample_time, config.regularity_limit,
                         config.acf_peak_limit)
    if osc['detected'] and osc['amplitude'] < config.min_amplitude:
        osc['detected'] = False
    loads = ix.load_disturbances(joined(e), sample_time, config.load_amplitude, config.load_ti)
    osc['load_disturbances'] = loads
    if loads['detected']:                   # Hägglund's alarm (when configured)
        osc['detected'] = True
    stiction_index = (ix.stiction(joined(u), joined(y), osc['period'] / sample_time)
                      if osc['detected'] and osc['period'] else None)
    body: dict[str, Any] = {
        'samples': int(t.size),
        'duration': float(t[-1] - t[0]) if t.size else 0.0,
        'regulation_samples': int(sum(s.stop - s.start for s in segments)),
        'harris_index': (ix.harris_index(e_reg, b, config.ar_order)
                         if b is not None and e_reg and b < sum(len(x) for x in e_reg) // 4
                         else None),
        'dead_time_samples': b,
        'dead_time': dead_time.seconds,
        'dead_time_source': dead_time.source,
        'oscillation': osc,
        'stiction': {'detected': bool(stiction_index is not None
                                      and stiction_index > config.stiction_limit),
                     'index': stiction_index},
        'saturation_pct': ix.saturation_pct(u, *u_limits),
        'manual_pct': manual_pct,
        'fail_safe_pct': fail_safe_pct,
        'setpoint_changes': ix.setpoint_iae(t, r, y),
        'ms': ms if ms is not None and math.isfinite(ms) else None,
    }
    body['harris_reason'] = (None if body['harris_index'] is not None else _no_harris(
        dead_time, b, sum(len(x) for x in e_reg), config.ar_order))
    body['verdict'] = verdict(body, config)
    return body


def _no_harris(dead_time: DeadTime, b: int | None, n: int, order: int) -> str:
    """Why there is no Harris index (one line)."""
    if b is None:
        return dead_time.source
    if n < max(10 * order, 50):
        return f'{n} regulation samples; at least {max(10 * order, 50)} are needed'
    if b >= n // 4:
        return f'the dead time ({b} samples) is a quarter of the regulation data or more'
    return ('the control error is constant or predictable a sample ahead (no random '
            'disturbance in the data): no variance benchmark applies')


def verdict(body: dict[str, Any], config: MonitorConfig = DEFAULT) -> str:
    """The one line: the first that applies of manual, fail-safe, saturated, stiction,
    oscillating, sluggish (Harris index), else "good"; "no data" with too few samples."""
    if (body.get('manual_pct') or 0.0) > config.manual_limit:
        return f'in manual {body["manual_pct"]:.0f} % of the time'
    if (body.get('fail_safe_pct') or 0.0) > config.fail_safe_limit:
        return f'fail-safe output {body["fail_safe_pct"]:.0f} % of the time'
    if (body.get('saturation_pct') or 0.0) > config.saturation_limit:
        return f'saturated {body["saturation_pct"]:.0f} % of the time'
    if body['stiction']['detected']:
        return 'valve: stiction suspected — do not retune'
    osc = body['oscillation']
    if osc['detected']:
        ms = f'Ms {body["ms"]:.1f}, ' if body.get('ms') else ''
        stiction = ('no stiction' if body['stiction']['index'] is not None
                    else 'stiction not assessed')
        what = (f'period {osc["period"]:.3g} s' if osc.get('period')
                else f'{osc["load_disturbances"]["count"]} load disturbances')
        return f'retune (oscillating, {what}, {ms}{stiction})'
    harris = body.get('harris_index')
    if harris is None:
        return ('no data' if body.get('samples', 0) < 50 or not body.get('regulation_samples')
                else 'good')
    if harris < config.harris_limit:
        return f'retune (sluggish: Harris index {harris:.2f}, no oscillation)'
    return 'good'


def _number(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return math.nan


class LoopMonitor:
    """Live assessment of one loop over a sliding window: :meth:`update` once per controller
    sample; every ``monitor.period`` it recomputes :meth:`summary` (JSON-ready, with ``time``
    [s] of its last sample) with :func:`assess`. A sample with a non-finite or non-numeric
    value (a measurement fault) still counts for the manual and fail-safe times but is left
    out of the indices (counted in ``nonfinite_samples``); nothing raises."""

    def __init__(self, sample_time: float, config: MonitorConfig = DEFAULT, *,
                 u_limits: tuple[float, float] = (-math.inf, math.inf), ms: float | None = None,
                 dead_time: Callable[[], DeadTime] | None = None) -> None:
        self.sample_time = float(sample_time)
        #: asked at each recompute: the loop's dead time and its source (None: ``config``'s)
        self.dead_time = dead_time
        self.config = config
        self.u_limits = u_limits
        self.ms = ms
        size = max(int(round(config.window / self.sample_time)), 2)
        self._data = np.zeros((size, 4))             # ring buffer of t, y, r, u
        self._flags = np.zeros((size, 2), dtype=bool)  # manual, fail-safe
        self._head = 0                                # next row written
        self._filled = 0
        self._every = max(int(round(config.period / self.sample_time)), 1)
        self._count = 0
        self.nonfinite_samples = 0
        self._summary: dict[str, Any] = {'verdict': 'no data', 'samples': 0}

    def update(self, t: float, y: float, r: float, u: float, manual: bool = False,
               fail_safe: bool = False) -> dict[str, Any] | None:
        """Add one sample; the new summary when it was recomputed, else None."""
        values = tuple(_number(v) for v in (t, y, r, u))
        if not all(math.isfinite(v) for v in values):
            self.nonfinite_samples += 1
        self._data[self._head] = values
        self._flags[self._head] = (bool(manual), bool(fail_safe))
        self._head = (self._head + 1) % len(self._data)
        self._filled = min(self._filled + 1, len(self._data))
        self._count += 1
        if self._count % self._every:
            return None
        return self.recompute()

    def recompute(self) -> dict[str, Any]:
        """Assess the window now."""
        size = len(self._data)
        order = (np.arange(self._head - self._filled, self._head) % size)
        data, flags = self._data[order], self._flags[order]
        body = assess(data[:, 0], data[:, 1], data[:, 2], data[:, 3], self.sample_time,
                      self.config, u_limits=self.u_limits, manual=flags[:, 0],
                      fail_safe=flags[:, 1], ms=self.ms,
                      start_is_change=self._count <= size,   # the window holds the start
                      dead_time=self.dead_time() if self.dead_time is not None else None)
        times = data[:, 0][np.isfinite(data[:, 0])]
        body['time'] = float(times[-1]) if times.size else None
        body['nonfinite_samples'] = self.nonfinite_samples
        self._summary = body
        return body

    def summary(self) -> dict[str, Any]:
        """The latest assessment (``verdict`` "no data" before the first)."""
        return self._summary

    def level(self) -> int:
        """The /diagnostics level of the latest verdict: 0 OK ("good", "no data"), 1 WARN."""
        return 0 if self._summary.get('verdict') in ('good', 'no data') else 1


def loop_monitors(config: MonitorConfig, sample_time: float, outputs: Sequence[str],
                  inputs: Sequence[str],
                  limits: Mapping[str, tuple[float, float]] | None = None,
                  dead_times: Mapping[str, Callable[[], DeadTime]] | None = None
                  ) -> dict[str, tuple[str, LoopMonitor]]:
    """A controller's loops as monitors: output channel → (its input, monitor), pairing
    ``outputs[i]`` with ``inputs[i]`` (none when the counts differ); ``limits`` the output
    limits by input channel; ``dead_times`` each loop's dead-time provider by output
    (:class:`LoopMonitor`; none: ``config.dead_time``)."""
    if len(outputs) != len(inputs):
        return {}
    out = {}
    for y, u in zip(outputs, inputs):
        lo, hi = (limits or {}).get(u, (-math.inf, math.inf))
        out[y] = (u, LoopMonitor(sample_time, config, u_limits=(float(lo), float(hi)),
                                 dead_time=(dead_times or {}).get(y)))
    return out


def diagnostics_line(monitors: Mapping[str, tuple[str, LoopMonitor]]) -> tuple[int, str]:
    """/diagnostics level (0 OK, 1 WARN) and message of a controller's loops:
    ``'loop y: good'``, ``'loop y: valve: stiction suspected — do not retune'``."""
    level = max((m.level() for _, m in monitors.values()), default=0)
    text = '; '.join(f'loop {y}: {m.summary()["verdict"]}' for y, (_, m) in monitors.items())
    return level, text
