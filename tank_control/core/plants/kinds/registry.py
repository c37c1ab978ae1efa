"""The plant kinds by name: the built-in table plus installed plugins."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from tank_control.core import kind_plugins
from tank_control.core.interfaces import Plant
from tank_control.core.params import by_name, finder
from tank_control.core.plants.kinds import (fopdt, foupdt, ipdt, mixing_tank, mixing_tank_linear,
                                            sopdt, transfer_function)
from tank_control.core.plants.kinds.base import PlantKind

BUILT_IN: dict[str, PlantKind] = by_name(
    ipdt.KIND,
    fopdt.KIND,
    foupdt.KIND,
    mixing_tank.KIND,
    mixing_tank_linear.KIND,
    sopdt.KIND,
    transfer_function.KIND,
)
"""The kinds shipped in tank_control."""

PLUGINS = kind_plugins.load(kind_plugins.PLANT_GROUP, BUILT_IN, PlantKind, 'plant kind')
KINDS: dict[str, PlantKind] = PLUGINS.kinds
"""Every plant kind by name: the built-in ones, then those of installed distributions (entry
points of ``tank_control.plant_kinds``, :mod:`tank_control.core.kind_plugins`)."""


get_kind: Callable[[str], PlantKind] = finder(KINDS, 'plant kind')


def make_plant(name: str, values: Mapping[str, Any] | None = None) -> Plant:
    """The plant of kind ``name`` from parameter values (missing ones take defaults)."""
    return get_kind(name).make(values or {})
