"""Plant kind ``foupdt``: first-order unstable plus dead time K/(T·s − 1)·e^(−L·s) ([Precup2013] §3.6.2)."""
from __future__ import annotations

from typing import Any

from tank_control.core.analysis.linear import RationalModel
from tank_control.core.plants.foupdt import Foupdt, FoupdtConfig
from tank_control.core.plants.kinds.base import PlantKind


def linear(config: FoupdtConfig) -> Any:
    """``|K|/(T·s − 1)·e^(−L·s)`` (one unstable pole; None for a zero gain)."""
    gain = abs(float(config.gain))
    if gain == 0.0:
        return None
    return RationalModel((gain,), (float(config.time_constant), -1.0), float(config.dead_time),
                         'foupdt')


KIND = PlantKind('foupdt', 'first-order unstable plus dead time K/(T·s − 1)·e^(−L·s) '
                 '([Precup2013] §3.6.2)', FoupdtConfig, Foupdt, linear=linear)
