"""Kinds from installed distributions: Python entry points (pure Python, no rclpy).

A distribution adds controller kinds with the entry-point group
``tank_control.controller_kinds`` and plant kinds with ``tank_control.plant_kinds``; each entry
point's value names a module attribute holding the kind (``my_pkg.on_off:KIND``, a
``ControllerKind`` or ``PlantKind`` as the built-in kinds define them) and its name is the
kind's name. The registries (``core/control/kinds/registry.py``,
``core/plants/kinds/registry.py``) call :func:`load` when they are imported, so every process
that uses kinds (nodes, harness, in-process loop, sweep workers, dashboard, ``tank-control
list``) has the same table.

A plugin never hides a built-in kind: one that fails to import, is not a kind, or reuses a
name already taken is left out with a one-line error naming the entry point and its
distribution (logged once per process, and kept in ``PluginTable.errors``).
docs/extending.md describes the protocol.
"""
from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

CONTROLLER_GROUP = 'tank_control.controller_kinds'
PLANT_GROUP = 'tank_control.plant_kinds'
BUILT_IN = 'built-in'
"""The origin of the kinds shipped in tank_control."""

_log = logging.getLogger('tank_control.kinds')


@dataclass
class PluginTable:
    """A kind table: ``kinds`` by name (built-ins first), ``origins``: name → ``built-in`` or
    the distribution that provides it, ``errors``: one line per entry point left out."""

    kinds: dict[str, Any]
    origins: dict[str, str] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)


def _distribution(ep: Any) -> str:
    dist = getattr(ep, 'dist', None)
    name = getattr(dist, 'name', None) or getattr(dist, 'metadata', {}).get('Name') if dist else None
    return str(name) if name else 'unknown distribution'


@functools.lru_cache(maxsize=1)
def _installed() -> Any:
    """Every installed entry point, read once per process (both registries use it)."""
    return metadata.entry_points()


def entry_points(group: str) -> list[Any]:
    """The installed entry points of ``group``, in a fixed order (distribution, then name)."""
    found = _installed().select(group=group)
    return sorted(found, key=lambda ep: (_distribution(ep), ep.name, ep.value))


def load(group: str, built_in: Mapping[str, Any], kind_type: type, what: str,
         found: Iterable[Any] | None = None,
         report: Callable[[str], None] | None = None) -> PluginTable:
    """The table of ``built_in`` kinds plus the kinds of ``group``'s entry points (``found``:
    those entry points, default the installed ones). ``what`` names the kind in messages
    ("controller kind"); ``report`` gets each error line (default: logged as an error)."""
    report = report or _log.error
    table = PluginTable(dict(built_in), {name: BUILT_IN for name in built_in})
    for ep in (entry_points(group) if found is None else found):
        dist = _distribution(ep)
        where = f'{what} entry point {ep.name!r} = {ep.value!r} (group {group}, distribution {dist})'
        try:
            kind = ep.load()
        except Exception as exc:       # noqa: BLE001 - a plugin's failure must not stop us
            reason = f'{type(exc).__name__}: {exc}'.splitlines()[0]
            error = f'{where}: cannot be loaded ({reason}); left out'
        else:
            error = _check(kind, ep.name, kind_type, what, table)
            if error:
                error = f'{where}: {error}; left out'
            else:
                table.kinds[kind.name] = kind
                table.origins[kind.name] = dist
        if error:
            table.errors.append(error)
            report(error)
    return table


def _check(kind: Any, name: str, kind_type: type[Any], what: str, table: PluginTable) -> str | None:
    if not isinstance(kind, kind_type):
        return (f'is a {type(kind).__name__}, not a {kind_type.__name__} (the value must name '
                'the module attribute holding the kind, e.g. my_pkg.my_kind:KIND)')
    own: str = kind.name
    if own != name:
        return f'names the {what} {own!r}; the entry point must be named after it'
    if own in table.kinds:
        return f'the name {own!r} is taken by the {table.origins[own]} {what}'
    return None
