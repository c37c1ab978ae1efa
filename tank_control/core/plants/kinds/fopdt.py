"""Plant kind ``fopdt``: first order plus dead time K/(T·s + 1)·e^(−L·s) ([DeadTimeNotes] eq. 6.14)."""
from __future__ import annotations

from typing import Any

from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.tuning.model import ProcessModel


def linear(config: FopdtConfig) -> Any:
    """The process model ``|K|/(T·s + 1)·e^(−L·s)``; None for a zero gain or T = 0 (a pure
    gain with delay is not strictly proper)."""
    gain = abs(float(config.gain))
    if gain == 0.0 or not config.time_constant > 0.0:
        return None
    return ProcessModel('fopdt', gain, float(config.dead_time), float(config.time_constant))


KIND = PlantKind('fopdt', 'first order plus dead time K/(T·s + 1)·e^(−L·s) ([DeadTimeNotes] eq. 6.14)',
                 FopdtConfig, Fopdt, linear=linear)
