"""Plant kind ``foupdt``: first-order unstable plus dead time K/(T·s − 1)·e^(−L·s) ([Precup2013] §3.6.2)."""
from tank_control.core.plants.foupdt import Foupdt, FoupdtConfig
from tank_control.core.plants.kinds.base import PlantKind

KIND = PlantKind('foupdt', 'first-order unstable plus dead time K/(T·s − 1)·e^(−L·s) '
                 '([Precup2013] §3.6.2)', FoupdtConfig, Foupdt)
