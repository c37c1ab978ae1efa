"""Plant kind ``sopdt``: second order plus dead time K/((T1·s + 1)(T2·s + 1))·e^(−L·s) or
K/(T²·s² + 2ζ·T·s + 1)·e^(−L·s) ([Precup2013] eq. 3.5.8)."""
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.sopdt import Sopdt, SopdtConfig

KIND = PlantKind('sopdt', 'second order plus dead time K/((T1·s + 1)(T2·s + 1))·e^(−L·s) or '
                 'K/(T²·s² + 2ζ·T·s + 1)·e^(−L·s) ([Precup2013] eq. 3.5.8)', SopdtConfig, Sopdt)
