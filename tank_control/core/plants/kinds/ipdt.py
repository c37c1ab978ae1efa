"""Plant kind ``ipdt``: integrator plus dead time k1/s·e^(−To·s) ([Viteckova] eq. 1)."""
from tank_control.core.plants.ipdt import Ipdt, IpdtConfig
from tank_control.core.plants.kinds.base import PlantKind

KIND = PlantKind('ipdt', 'integrator plus dead time k1/s·e^(−To·s) ([Viteckova] eq. 1)', IpdtConfig, Ipdt)
