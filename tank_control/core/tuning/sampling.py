"""[DeadTimeNotes]'s sampling-time advice for a sampled PID on a dead-time process ([DeadTimeNotes] §1.2).

* Oppelt ([DeadTimeNotes] §1.2.1): choose the sample time T ≈ 0.3·L (L the model's dead time, τ in [DeadTimeNotes]).
* Ziegler–Nichols ([DeadTimeNotes] §1.2.2): T ≅ (0.1 … 0.3)·Tu (Tu the ultimate period, T_krit in [DeadTimeNotes]).

Both are upper bounds: a zero-order hold adds about ω·T/2 of phase lag, 54° at the ultimate
frequency for T = 0.3·Tu. :func:`sampling_advice` names every bound a sample time exceeds.
Units: s.
"""
from __future__ import annotations

import math

from tank_control.core.tuning.model import ProcessModel

#: T ≤ OPPELT_FACTOR·L ([DeadTimeNotes] §1.2.1) and T ≤ ZN_FACTOR·Tu ([DeadTimeNotes] §1.2.2, the upper end)
OPPELT_FACTOR = 0.3
ZN_FACTOR = 0.3


def ultimate_period(model: ProcessModel) -> float:
    """Tu [s] of the continuous ``model`` (inf when its phase never reaches −180°)."""
    try:
        tu = model.ultimate_point().tu
    except (ValueError, ArithmeticError):
        return math.inf
    return tu if math.isfinite(tu) and tu > 0 else math.inf


def sampling_advice(sample_time: float, model: ProcessModel | None) -> str:
    """'' when ``sample_time`` [s] is within [DeadTimeNotes]'s advice for ``model`` (or there is no
    model), else one line naming each bound it exceeds, with the numbers."""
    if model is None or not (math.isfinite(sample_time) and sample_time > 0):
        return ''
    over = []
    if model.dead_time > 0 and sample_time > OPPELT_FACTOR * model.dead_time * (1 + 1e-9):
        over.append(f'{OPPELT_FACTOR:g}·L = {OPPELT_FACTOR * model.dead_time:.4g} s ([DeadTimeNotes] Oppelt: '
                    f'T ≈ 0.3·L)')
    tu = ultimate_period(model)
    if math.isfinite(tu) and sample_time > ZN_FACTOR * tu * (1 + 1e-9):
        over.append(f'{ZN_FACTOR:g}·Tu = {ZN_FACTOR * tu:.4g} s ([DeadTimeNotes] Ziegler–Nichols: '
                    f'T ≈ (0.1…0.3)·Tu)')
    if not over:
        return ''
    return (f'sample_time {sample_time:g} s is above ' + ' and '.join(over)
            + f' of the model {model.describe()}: the hold costs about ω·T/2 of phase margin')
