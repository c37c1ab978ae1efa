"""Plant kind ``sopdt``: second order plus dead time K/((T1·s + 1)(T2·s + 1))·e^(−L·s) or
K/(T²·s² + 2ζ·T·s + 1)·e^(−L·s) ([Precup2013] eq. 3.5.8)."""
from __future__ import annotations

from typing import Any

from tank_control.core.analysis.linear import RationalModel
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.sopdt import Sopdt, SopdtConfig
from tank_control.core.tuning.model import ProcessModel


def linear(config: SopdtConfig) -> Any:
    """The model with the gain's magnitude: a process model (``fopdt``/``sopdt``) for real
    lags (form ``time_constants``, or ``damping`` with ζ = 1: two equal lags; a zero time
    constant drops that lag), the transfer function ``|K|/(T²·s² + 2ζ·T·s + 1)`` for ζ ≠ 1;
    None for a zero gain or no lag at all."""
    gain, dead = abs(float(config.gain)), float(config.dead_time)
    if gain == 0.0:
        return None
    if config.form == 'damping':
        t = float(config.time_constant)
        if not t > 0.0:
            return None
        if config.damping != 1.0:
            return RationalModel((gain,), (t * t, 2.0 * config.damping * t, 1.0), dead,
                                 'sopdt')
        lags = [t, t]
    else:
        lags = [float(config.time_constant_1), float(config.time_constant_2)]
    lags = sorted((t for t in lags if t > 0.0), reverse=True)
    if not lags:
        return None
    if len(lags) == 1:
        return ProcessModel('fopdt', gain, dead, lags[0])
    return ProcessModel('sopdt', gain, dead, lags[0], lags[1])


KIND = PlantKind('sopdt', 'second order plus dead time K/((T1·s + 1)(T2·s + 1))·e^(−L·s) or '
                 'K/(T²·s² + 2ζ·T·s + 1)·e^(−L·s) ([Precup2013] eq. 3.5.8)', SopdtConfig, Sopdt,
                 linear=linear)
