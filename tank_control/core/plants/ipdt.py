"""IPDT plant: integrator plus dead time, ``G(s) = k1/s · e^(−To·s)`` (000 eq. 1, SPEC §1.1).

Load disturbance ``v`` at the plant input (000 Fig. 1): ``y = y0 + G(s)·(u + v)``.
Worked example of 000: ``k1 = 0.05 s⁻¹``, ``To = 5 s`` (the defaults).
Exact discretisation: over a piece of constant delayed input ``w`` lasting
``τ`` seconds, ``x ← x + k1·w·τ``.
"""
from __future__ import annotations

from dataclasses import dataclass

from tank_control.core.params import ParamSpec
from tank_control.core.plants.siso import DeadTimePlant

MAX_DEAD_TIME_LIMIT = 1e4
"""Largest ``max_dead_time`` [s] a plant may be built with."""


def dead_time_specs(default_dead_time: float) -> tuple[ParamSpec, ...]:
    """Specs shared by IPDT and FOPDT: dead_time, initial_output, max_dead_time."""
    return (
        ParamSpec('dead_time', default_dead_time,
                  'transport delay L (To in 000) [s]; changes live, history is kept up to '
                  'max_dead_time', min=0.0, max=MAX_DEAD_TIME_LIMIT),
        ParamSpec('initial_output', 0.0,
                  'output y0 at rest with u + v = 0 [output units]; a live change shifts y'),
        ParamSpec('max_dead_time', 100.0,
                  'input history kept by the delay line [s]; the largest dead_time allowed',
                  min=0.0, max=MAX_DEAD_TIME_LIMIT, read_only=True),
    )


IPDT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('gain', 0.05, 'integrating gain k1 [output units/(input unit·s)] (000 eq. 1)',
              min=-1e6, max=1e6),
) + dead_time_specs(5.0)


@dataclass(frozen=True)
class IpdtConfig:
    """Parameters of ``Ipdt`` (defaults: 000's example k1 = 0.05 s⁻¹, To = 5 s)."""

    gain: float = 0.05
    dead_time: float = 5.0
    initial_output: float = 0.0
    max_dead_time: float = 100.0


class Ipdt(DeadTimePlant):
    """``k1/s · e^(−To·s)`` with input load disturbance (000 eq. 1, Fig. 1)."""

    PARAMS = IPDT_PARAMS

    def __init__(self, config: IpdtConfig | None = None) -> None:
        super().__init__(config if config is not None else IpdtConfig())

    def _advance(self, x: float, w: float, duration: float) -> float:
        return x + self._config.gain * w * duration
