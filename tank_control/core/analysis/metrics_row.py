"""One flat row of numbers per run from its ``metrics.json`` (for tables of many runs: a
sweep's results, the dashboard's runs page)."""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np


def _worst(values: Iterable[Any]) -> float | None:
    """The largest of the values given (None ignored; None if there are none)."""
    numbers = [float(v) for v in values if v is not None]
    if not numbers:
        return None
    return max(numbers)


def flat_metrics(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """One row of numbers per run from ``metrics.json``'s measured sections: per output the
    IAE and ISE, the worst setpoint step (overshoot, rise, settling, steady-state error) and
    the worst disturbance step (peak error, recovery); per input min, max, total variation
    and constraint violations; the loop's robustness on the plant when it can be analysed; per
    loop its performance indices (Harris index, oscillating 0/1, stiction index, saturation %).
    A step that does not settle in its window has settling time ``inf``."""
    row: dict[str, Any] = {}
    for name, out in (metrics.get('outputs') or {}).items():
        row[f'{name}.iae'] = out.get('iae')
        row[f'{name}.ise'] = out.get('ise')
        steps = out.get('steps') or []
        if steps:
            row[f'{name}.overshoot_pct'] = _worst(s.get('overshoot_pct') for s in steps)
            row[f'{name}.rise_time'] = _worst(
                math.inf if s.get('rise_time') is None else s['rise_time'] for s in steps)
            row[f'{name}.settling_time'] = _worst(
                math.inf if s.get('settling_time') is None else s['settling_time'] for s in steps)
            row[f'{name}.ss_error'] = _worst(abs(s['ss_error']) for s in steps
                                             if s.get('ss_error') is not None)
        loads = out.get('disturbance_steps') or []
        if loads:
            row[f'{name}.peak_error'] = _worst(s.get('peak_error') for s in loads)
            row[f'{name}.recovery_time'] = _worst(
                math.inf if s.get('recovery_time') is None else s['recovery_time'] for s in loads)
    for name, inp in (metrics.get('inputs') or {}).items():
        for key in ('min', 'max', 'total_variation', 'constraint_violations'):
            row[f'{name}.{key}'] = inp.get(key)
    analysis = metrics.get('loop_analysis')
    if isinstance(analysis, dict):
        plant = next((v for k, v in analysis.items() if k.startswith('plant')), None)
        if plant:
            for key in ('stable', 'gain_margin', 'phase_margin', 'delay_margin', 'ms', 'mt'):
                value = plant.get(key)
                row[f'loop.{key}'] = float(value) if value is not None else None
    for name, perf in (metrics.get('loop_performance') or {}).items():   # docs/monitoring.md
        row[f'{name}.harris_index'] = perf.get('harris_index')
        row[f'{name}.oscillating'] = float(bool((perf.get('oscillation') or {}).get('detected')))
        row[f'{name}.stiction_index'] = (perf.get('stiction') or {}).get('index')
        row[f'{name}.saturation_pct'] = perf.get('saturation_pct')
    return {k: (float(v) if isinstance(v, (int, float, np.number)) and not isinstance(v, bool)
                else v) for k, v in row.items()}
