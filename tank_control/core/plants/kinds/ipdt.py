"""Plant kind ``ipdt``: integrator plus dead time k1/s·e^(−To·s) ([Viteckova] eq. 1)."""
from __future__ import annotations

from typing import Any

from tank_control.core.plants.ipdt import Ipdt, IpdtConfig
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.tuning.model import ProcessModel


def linear(config: IpdtConfig) -> Any:
    """The process model ``|k1|/s·e^(−To·s)`` (None for a zero gain)."""
    gain = abs(float(config.gain))
    return ProcessModel('ipdt', gain, float(config.dead_time)) if gain > 0.0 else None


KIND = PlantKind('ipdt', 'integrator plus dead time k1/s·e^(−To·s) ([Viteckova] eq. 1)', IpdtConfig, Ipdt,
                 linear=linear)
