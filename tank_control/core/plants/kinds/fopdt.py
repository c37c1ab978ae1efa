"""Plant kind ``fopdt``: first order plus dead time K/(T·s + 1)·e^(−L·s) ([DeadTimeNotes] eq. 6.14)."""
from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
from tank_control.core.plants.kinds.base import PlantKind

KIND = PlantKind('fopdt', 'first order plus dead time K/(T·s + 1)·e^(−L·s) ([DeadTimeNotes] eq. 6.14)',
                 FopdtConfig, Fopdt)
