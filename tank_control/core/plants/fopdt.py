"""FOPDT plant, ``G(s) = K/(T·s + 1) · e^(−L·s)`` ([DeadTimeNotes] eq. 6.14, [Precup2013] eq. 3.3.11, [Checks] §1).

Load disturbance ``v`` at the plant input: ``y = y0 + G(s)·(u + v)``.
Worked example of [DeadTimeNotes] §1.2.2: ``K = 0.05``, ``T = 10 s``, ``L = 3 s`` (the defaults).
Exact discretisation: over a piece of constant delayed input ``w`` lasting ``τ``
seconds, ``x ← K·w + (x − K·w)·e^(−τ/T)``; ``T = 0`` is a pure gain with delay.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from tank_control.core.params import param
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)


@dataclass(frozen=True)
class FopdtConfig:
    """Parameters of ``Fopdt`` (defaults: [DeadTimeNotes]'s example K = 0.05, T = 10 s, L = 3 s)."""

    gain: float = param(0.05, 'static gain K', unit='output units/input unit', min=-1e6,
                        max=1e6, source='[DeadTimeNotes] eq. 6.14')
    time_constant: float = param(10.0, 'time constant T (0 = pure gain with delay)', unit='s',
                                 min=0.0, max=1e6)
    dead_time: float = dead_time_param(3.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        return dead_time_reason(self)


class Fopdt(DeadTimePlant):
    """``K/(T·s + 1) · e^(−L·s)`` with input load disturbance ([DeadTimeNotes] eq. 6.14)."""

    def __init__(self, config: FopdtConfig | None = None) -> None:
        super().__init__(config if config is not None else FopdtConfig())

    def _advance(self, x: float, w: float, duration: float) -> float:
        target = self._config.gain * w
        if self._config.time_constant == 0.0:
            return target
        # x + (target − x)·(1 − e^(−τ/T)), with expm1 for accuracy on short pieces.
        return x + (target - x) * -math.expm1(-duration / self._config.time_constant)
