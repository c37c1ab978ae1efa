"""First-order unstable plus dead time plant, ``G(s) = K/(T·s − 1) · e^(−L·s)`` ([Precup2013] §3.6.2).

The process for which [Precup2013] §3.6.2 recommends the FSA controller (a Smith predictor gives an
unstable loop). Load disturbance ``v`` at the plant input: ``y = y0 + G(s)·(u + v)``; the
delay-free state obeys ``T·ẋ = x + K·w``, so its open-loop pole is ``+1/T`` and its
equilibrium for a constant ``w`` is ``x = −K·w`` (unstable). Units: ``T``, ``L`` in s, ``K`` in
output units per input unit.

Exact discretisation: over a piece of constant delayed input ``w`` lasting ``τ`` seconds,
``x ← −K·w + (x + K·w)·e^(τ/T)``. The state is bounded at ``±STATE_LIMIT`` like every
SISO plant (an unstable plant left open-loop saturates there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from tank_control.core.params import param
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)


_EXP_MAX = 709.0
"""Largest τ/T whose e^(τ/T) is a float (ln of the largest float is 709.78)."""


@dataclass(frozen=True)
class FoupdtConfig:
    """Parameters of ``Foupdt`` (defaults: K = 1, T = 10 s, L = 3 s: a dead time of 0.3·T)."""

    gain: float = param(1.0, 'gain K of K/(T·s − 1) (the static gain is −K)',
                        unit='output units/input unit', min=-1e6, max=1e6,
                        source='[Precup2013] §3.6.2')
    time_constant: float = param(10.0, 'time constant T of the unstable pole +1/T', unit='s',
                                 min=1e-6, max=1e6)
    dead_time: float = dead_time_param(3.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        return dead_time_reason(self)


class Foupdt(DeadTimePlant):
    """``K/(T·s − 1) · e^(−L·s)`` with input load disturbance ([Precup2013] §3.6.2)."""

    def __init__(self, config: FoupdtConfig | None = None) -> None:
        super().__init__(config if config is not None else FoupdtConfig())

    def _advance(self, x: float, w: float, duration: float) -> float:
        target = -self._config.gain * w
        ratio = duration / self._config.time_constant
        if ratio > _EXP_MAX:      # e^(τ/T) is beyond a float (T = 1e-6 s, τ = 1 s): the state
            # runs off to ±inf, which the step clips to ±STATE_LIMIT (counted)
            return target if x == target else math.copysign(math.inf, x - target)
        # x + (x − target)·(e^(τ/T) − 1), with expm1 for accuracy on short pieces.
        return x + (x - target) * math.expm1(ratio)
