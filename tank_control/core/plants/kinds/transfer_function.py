"""Plant kind ``transfer_function``: B(s)/A(s)·e^(−L·s), strictly proper, any stable or
unstable denominator ([Checks] §5: [Ikonen]'s process 4/((s + 1)(s + 2)))."""
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.transfer_function import TransferFunction, TransferFunctionConfig

KIND = PlantKind('transfer_function', 'transfer function with dead time B(s)/A(s)·e^(−L·s) '
                 '(num, den in descending powers of s; strictly proper)',
                 TransferFunctionConfig, TransferFunction)
