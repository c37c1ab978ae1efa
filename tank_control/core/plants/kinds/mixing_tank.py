"""Plant kind ``mixing_tank``: the nonlinear mixing tank with its two delays ([Michalski2021] §1)."""
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig, tick_reason

#: The channels' units ([Michalski2021] §1): level in cm, temperatures in °C, flows in cm³/s.
UNITS = {'h': 'cm', 'T_out': '°C', 'F_H': 'cm³/s', 'F_Cin': 'cm³/s', 'F_D': 'cm³/s',
         'T_D': '°C', 'T_H': '°C', 'T_C': '°C'}

KIND = PlantKind('mixing_tank', 'nonlinear mixing tank with delays on F_Cin and T_out ([Michalski2021] §1)',
                 MixingTankConfig, MixingTank, tick_reason, units=UNITS)
