"""FOPDT plant, ``G(s) = K/(T·s + 1) · e^(−L·s)`` (001 eq. 6.14, 004 eq. 3.3.11, SPEC §1.2).

Load disturbance ``v`` at the plant input: ``y = y0 + G(s)·(u + v)``.
Worked example of 001 §1.2.2: ``K = 0.05``, ``T = 10 s``, ``L = 3 s`` (the defaults).
Exact discretisation: over a piece of constant delayed input ``w`` lasting ``τ``
seconds, ``x ← K·w + (x − K·w)·e^(−τ/T)``; ``T = 0`` is a pure gain with delay.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from tank_control.core.params import ParamSpec
from tank_control.core.plants.ipdt import dead_time_specs
from tank_control.core.plants.siso import DeadTimePlant

FOPDT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('gain', 0.05, 'static gain K [output units/input unit] (001 eq. 6.14)',
              min=-1e6, max=1e6),
    ParamSpec('time_constant', 10.0, 'time constant T [s] (0 = pure gain with delay)',
              min=0.0, max=1e6),
) + dead_time_specs(3.0)


@dataclass(frozen=True)
class FopdtConfig:
    """Parameters of ``Fopdt`` (defaults: 001's example K = 0.05, T = 10 s, L = 3 s)."""

    gain: float = 0.05
    time_constant: float = 10.0
    dead_time: float = 3.0
    initial_output: float = 0.0
    max_dead_time: float = 100.0


class Fopdt(DeadTimePlant):
    """``K/(T·s + 1) · e^(−L·s)`` with input load disturbance (001 eq. 6.14)."""

    PARAMS = FOPDT_PARAMS

    def __init__(self, config: FopdtConfig | None = None) -> None:
        super().__init__(config if config is not None else FopdtConfig())

    def _advance(self, x: float, w: float, duration: float) -> float:
        target = self._config.gain * w
        if self._config.time_constant == 0.0:
            return target
        # x + (target − x)·(1 − e^(−τ/T)), with expm1 for accuracy on short pieces.
        return x + (target - x) * -math.expm1(-duration / self._config.time_constant)
