"""Plant kind ``transfer_function``: B(s)/A(s)·e^(−L·s), strictly proper, any stable or
unstable denominator ([Checks] §5: [Ikonen]'s process 4/((s + 1)(s + 2)))."""
from __future__ import annotations

from tank_control.core.analysis.linear import RationalModel
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.transfer_function import TransferFunction, TransferFunctionConfig


def linear(config: TransferFunctionConfig) -> RationalModel:
    """``num(s)/den(s)·e^(−L·s)`` as given (its sign included)."""
    return RationalModel(tuple(float(c) for c in config.num),
                         tuple(float(c) for c in config.den), float(config.dead_time),
                         'transfer_function')


KIND = PlantKind('transfer_function', 'transfer function with dead time B(s)/A(s)·e^(−L·s) '
                 '(num, den in descending powers of s; strictly proper)',
                 TransferFunctionConfig, TransferFunction, linear=linear)
