"""The dead time a loop's Harris index is computed with, and where it came from.

``monitor.dead_time`` > 0 is taken as given. At 0 (the default) the loop's dead time is what is
known of its process: in a run, the plant kind's linear model (``PlantKind.linear``); live and
in a run, the models the controller kind carries in its linear description
(``ControllerKind.linear(settings).models``: a ``tuning.*`` model, the model a relay test
identified, a Smith predictor's or FSA's internal model). A kind with several loops answers
per loop (``ControllerKind.loop_dead_times``, e.g. MPCS's prediction model). Each kind answers
for itself; no kind is named here. When nothing is known the Harris index is not computed (a one-sample guess would
report a loop with dead time as sluggish) and the reason says what to set.
docs/monitoring.md, "The indices".
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class DeadTime:
    """``seconds`` the loop's dead time [s] (None: not known) and ``source``: where it came
    from, or why it is not known (one line)."""

    seconds: float | None
    source: str


UNKNOWN_HINT = ('set monitor.dead_time, or give the controller its process model '
                '(e.g. tuning.gain, tuning.time_constant, tuning.dead_time)')


def _model_dead_time(source: str, model: Any) -> DeadTime | None:
    dead_time = getattr(model, 'dead_time', None)
    if dead_time is None or not math.isfinite(float(dead_time)) or float(dead_time) < 0:
        return None
    return DeadTime(float(dead_time), f'{source} model ({model.describe()})')


def controller_dead_times(kind: Any, settings: Any, outputs: Sequence[str]
                          ) -> dict[str, DeadTime]:
    """Per output channel, the dead time of the first model the controller kind's linear
    description carries (a SISO controller), else None with the reason."""
    name = getattr(kind, 'name', '?')
    own = getattr(kind, 'loop_dead_times', None)
    if own is not None:
        try:
            found = own(settings)
        except (ValueError, ArithmeticError) as exc:
            found, error = {}, f' ({exc})'
        else:
            error = ''
        return {y: (DeadTime(float(found[y][0]), found[y][1]) if y in found else
                    DeadTime(None, f'dead time not known (controller {name}: no model of loop '
                                   f'{y}{error}): set monitor.dead_time')) for y in outputs}
    linear = None
    if getattr(kind, 'linear', None) is not None:
        try:
            linear = kind.linear(settings)
        except (ValueError, ArithmeticError):
            linear = None
    if len(outputs) != 1:
        return {y: DeadTime(None, f'dead time not known (controller {name}: not a SISO loop '
                                  'and no model per loop): set monitor.dead_time')
                for y in outputs}
    if linear is None:
        why = f'controller {name} carries no linear description of its process'
    else:
        for source, model in linear.models:
            found = _model_dead_time(f"controller's {source}", model)
            if found is not None:
                return {outputs[0]: found}
        why = f'controller {name} carries no process model'
    return {y: DeadTime(None, f'dead time not known ({why}): {UNKNOWN_HINT}') for y in outputs}


def given_or(config: Any, known: DeadTime) -> DeadTime:
    """``monitor.dead_time`` of ``config`` (a ``MonitorConfig``) when set (> 0), else ``known``."""
    if config.dead_time > 0.0:
        return DeadTime(config.dead_time, 'monitor.dead_time')
    return known
