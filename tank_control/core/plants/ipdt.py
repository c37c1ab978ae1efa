"""IPDT plant: integrator plus dead time, ``G(s) = k1/s · e^(−To·s)`` ([Viteckova] eq. 1, [Viteckova] eq. 1).

Load disturbance ``v`` at the plant input ([Viteckova] Fig. 1): ``y = y0 + G(s)·(u + v)``.
Worked example of [Viteckova]: ``k1 = 0.05 s⁻¹``, ``To = 5 s`` (the defaults).
Exact discretisation: over a piece of constant delayed input ``w`` lasting
``τ`` seconds, ``x ← x + k1·w·τ``.
"""
from __future__ import annotations

from dataclasses import dataclass

from tank_control.core.params import param
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)


@dataclass(frozen=True)
class IpdtConfig:
    """Parameters of ``Ipdt`` (defaults: [Viteckova]'s example k1 = 0.05 s⁻¹, To = 5 s)."""

    gain: float = param(0.05, 'integrating gain k1', unit='output units/(input unit·s)',
                        min=-1e6, max=1e6, source='[Viteckova] eq. 1')
    dead_time: float = dead_time_param(5.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        return dead_time_reason(self)


class Ipdt(DeadTimePlant):
    """``k1/s · e^(−To·s)`` with input load disturbance ([Viteckova] eq. 1, Fig. 1)."""

    def __init__(self, config: IpdtConfig | None = None) -> None:
        super().__init__(config if config is not None else IpdtConfig())

    def _advance(self, x: float, w: float, duration: float) -> float:
        return x + self._config.gain * w * duration
