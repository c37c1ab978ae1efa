"""Plant models (pure numpy/scipy): IPDT, FOPDT, the nonlinear mixing tank; delay lines; noise.

``make_plant(kind, values)`` builds a plant from parameter values (validated
with the ``ParamSpec`` records of ``plant_params(kind)``); every plant changes
parameters live with ``configure(**changes)`` (all-or-nothing, ``ValueError``
with a one-line reason).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tank_control.core.params import ParamSpec, check_all, defaults
from tank_control.core.plants.delay_line import DelayLine, HermiteDelayLine
from tank_control.core.plants.fopdt import FOPDT_PARAMS, Fopdt, FopdtConfig
from tank_control.core.plants.ipdt import IPDT_PARAMS, Ipdt, IpdtConfig
from tank_control.core.plants.mixing_tank import TANK_PARAMS, MixingTank, MixingTankConfig
from tank_control.core.plants.noise import NOISE_PARAMS, MeasurementNoise

PLANT_KINDS: tuple[str, ...] = ('ipdt', 'fopdt', 'mixing_tank')

PLANT_KIND_SPEC = ParamSpec('plant', 'fopdt', 'plant model: ipdt (000 eq. 1), fopdt '
                            '(001 eq. 6.14) or mixing_tank (003 §1)',
                            choices=PLANT_KINDS, read_only=True)

_MODELS: dict[str, tuple[type, type, tuple[ParamSpec, ...]]] = {
    'ipdt': (Ipdt, IpdtConfig, IPDT_PARAMS),
    'fopdt': (Fopdt, FopdtConfig, FOPDT_PARAMS),
    'mixing_tank': (MixingTank, MixingTankConfig, TANK_PARAMS),
}


def _model(kind: str) -> tuple[type, type, tuple[ParamSpec, ...]]:
    try:
        return _MODELS[kind]
    except (KeyError, TypeError):
        raise ValueError(f'plant: {kind!r} is not a plant kind; allowed one of '
                         f'{", ".join(PLANT_KINDS)}') from None


def plant_params(kind: str) -> tuple[ParamSpec, ...]:
    """Every model parameter of ``kind`` with description, units, range and default."""
    return _model(kind)[2]


def make_plant(kind: str, values: Mapping[str, Any] | None = None) -> Ipdt | Fopdt | MixingTank:
    """Build a plant of ``kind`` from parameter ``values`` (missing ones take defaults).

    Raises ``ValueError`` naming the kind (with the choices) or the first bad
    parameter (with the reason and allowed range); unknown names are rejected.
    """
    plant_cls, config_cls, specs = _model(kind)
    values = dict(values or {})
    reasons = check_all(specs, values)
    if reasons:
        raise ValueError(reasons[0])
    return plant_cls(config_cls(**{**defaults(specs), **values}))


__all__ = [
    'PLANT_KINDS', 'PLANT_KIND_SPEC', 'NOISE_PARAMS', 'DelayLine', 'HermiteDelayLine',
    'Ipdt', 'IpdtConfig', 'Fopdt', 'FopdtConfig', 'MixingTank', 'MixingTankConfig',
    'MeasurementNoise', 'make_plant', 'plant_params',
]
