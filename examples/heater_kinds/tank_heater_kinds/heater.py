"""Plant kind ``heater``: a heated vessel whose heating valve has a deadband.

``T_d·dy/dt = −(y − y0) + K·q(t − L)`` with the valve's flow ``q = u − b`` for ``u > b``,
``u + b`` for ``u < −b`` and 0 in between (deadband ``b`` [%]); ``y`` in °C, ``u`` in % open,
the load ``v`` adds to the flow (channels ``y``, ``u``, ``v`` as tank_control's SISO plants).
Built on tank_control's ``DeadTimePlant`` (delay line, live changes, clipping counters).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.params import param
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)


@dataclass(frozen=True)
class HeaterConfig:
    gain: float = param(0.5, 'temperature rise per % of valve flow at steady state',
                        unit='°C per %', min=-1e6, max=1e6)
    time_constant: float = param(60.0, 'thermal time constant', unit='s', min=1e-3, max=1e6)
    deadband: float = param(5.0, 'valve deadband: no flow for |u| up to this opening',
                            unit='%', min=0.0, max=100.0)
    dead_time: float = dead_time_param(5.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        return dead_time_reason(self)


def valve_flow(u: float, deadband: float) -> float:
    """Flow through the valve at opening ``u`` [%]: the deadband removed."""
    if u > deadband:
        return u - deadband
    if u < -deadband:
        return u + deadband
    return 0.0


class Heater(DeadTimePlant):
    def __init__(self, config: HeaterConfig | None = None) -> None:
        super().__init__(config if config is not None else HeaterConfig())

    def step(self, u: Any, d: Any, dt: float) -> None:
        opening = np.asarray(u, dtype=float).reshape(-1)
        flow = opening.copy()
        if opening.size == 1 and math.isfinite(opening[0]):
            flow[0] = valve_flow(float(opening[0]), self._config.deadband)
        super().step(flow, d, dt)       # the base checks sizes and values

    def _advance(self, x: float, w: float, duration: float) -> float:
        target = self._config.gain * w
        return target + (x - target) * math.exp(-duration / self._config.time_constant)


KIND = PlantKind('heater', 'heated vessel with a valve deadband (example package '
                 'tank-heater-kinds)', HeaterConfig, Heater)
