"""Plant kind ``mixing_tank_linear``: the mixing tank linearised at its operating point, with
its delays on F_Cin and T_out ([Michalski2021] eqs. 4–6, §2.3)."""
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.kinds.mixing_tank import UNITS
from tank_control.core.plants.linear_tank import LinearTank, LinearTankConfig

KIND = PlantKind('mixing_tank_linear', 'mixing tank linearised at its operating point, with the '
                 'delays on F_Cin and T_out; nothing clipped ([Michalski2021] eqs. 4–6, §2.3)',
                 LinearTankConfig, LinearTank, units=UNITS)
