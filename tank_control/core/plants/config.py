"""Validation of plant configurations against their ``ParamSpec`` records.

Every plant keeps its parameters in a dataclass whose field names are the
parameter names of ``plant_params(kind)``. Changes arrive as a mapping (from a
ROS 2 parameter callback or a scenario file) and are applied all-or-nothing:
the first reason found is raised as a one-line ``ValueError`` that names the
parameter and the allowed range, and the running plant is left untouched.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

from tank_control.core.params import ParamSpec, check_all

C = TypeVar('C')

CrossCheck = Callable[[Any], 'str | None']


def changed_config(specs: Iterable[ParamSpec], config: C, changes: Mapping[str, Any], *,
                   live: bool, cross_check: CrossCheck | None = None) -> C:
    """Return a copy of ``config`` with ``changes`` applied, or raise ``ValueError``.

    ``live`` changes (on a running plant) may not touch read-only parameters.
    ``cross_check`` validates relations between parameters on the result.
    """
    specs = tuple(specs)
    reasons = check_all(specs, changes)
    if live:
        read_only = {s.name for s in specs if s.read_only}
        reasons += [f'{name}: read-only, set at start-up only'
                    for name in changes if name in read_only]
    if reasons:
        raise ValueError(reasons[0])
    kinds = {s.name: type(s.default) for s in specs}
    typed = {name: (float(v) if kinds[name] is float else v) for name, v in changes.items()}
    result = dataclasses.replace(config, **typed)
    if cross_check is not None:
        reason = cross_check(result)
        if reason:
            raise ValueError(reason)
    return result


def checked_config(specs: Iterable[ParamSpec], config: C,
                   cross_check: CrossCheck | None = None) -> C:
    """Validate every field of a freshly built configuration (raises ``ValueError``)."""
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    return changed_config(specs, config, values, live=False, cross_check=cross_check)
