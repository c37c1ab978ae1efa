"""The plant kinds by name: a plain table."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tank_control.core.interfaces import Plant
from tank_control.core.params import by_name, lookup
from tank_control.core.plants.kinds import fopdt, ipdt, mixing_tank, sopdt
from tank_control.core.plants.kinds.base import PlantKind

KINDS: dict[str, PlantKind] = by_name(
    ipdt.KIND,
    fopdt.KIND,
    mixing_tank.KIND,
    sopdt.KIND,
)


def get_kind(name: str) -> PlantKind:
    """The kind ``name``; ``ConfigError`` with the nearest known name if unknown."""
    return lookup(KINDS, name, 'plant kind')


def make_plant(name: str, values: Mapping[str, Any] | None = None) -> Plant:
    """The plant of kind ``name`` from parameter values (missing ones take defaults)."""
    return get_kind(name).make(values or {})
