"""Plant kind ``mixing_tank``: the nonlinear mixing tank with its two delays ([Michalski2021] §1)."""
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig, tick_reason

KIND = PlantKind('mixing_tank', 'nonlinear mixing tank with delays on F_Cin and T_out ([Michalski2021] §1)',
                 MixingTankConfig, MixingTank, tick_reason)
