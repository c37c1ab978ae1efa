"""Parameter specifications: the user interface of every node, kept free of rclpy.

A core module describes its parameters as ``ParamSpec`` records; the nodes
turn them into ROS 2 parameter descriptors, and the in-process loop validates
scenario files with the same records, so both reject the same values with the
same one-line reason.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

ParamValue = bool | int | float | str | list[float] | list[str] | list[int] | list[bool]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default, description (with units) and allowed values.

    ``min``/``max`` bound numbers (inclusive), ``choices`` restricts strings,
    ``read_only`` parameters can be set at start-up only. Integer defaults make
    an integer parameter; float defaults a float one (integers are accepted).
    """

    name: str
    default: ParamValue
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False

    def allowed(self) -> str:
        """Human-readable allowed range, used in rejection messages."""
        if self.choices is not None:
            return 'one of ' + ', '.join(self.choices)
        if self.min is not None or self.max is not None:
            lo = '-inf' if self.min is None else f'{self.min:g}'
            hi = 'inf' if self.max is None else f'{self.max:g}'
            return f'[{lo}, {hi}]'
        return f'any {type(self.default).__name__}'

    def check(self, value: Any) -> str | None:
        """Return ``None`` if ``value`` is acceptable, else a one-line reason."""
        reason = _type_reason(self.default, value)
        if reason is None:
            items = value if isinstance(value, list) else [value]
            for item in items:
                reason = self._range_reason(item)
                if reason:
                    break
        return None if reason is None else f'{self.name}: {reason}; allowed {self.allowed()}'

    def _range_reason(self, item: Any) -> str | None:
        if self.choices is not None and item not in self.choices:
            return f'{item!r} is not a choice'
        if isinstance(item, (int, float)) and not isinstance(item, bool):
            if not math.isfinite(item):
                return f'{item} is not finite'
            if self.min is not None and item < self.min:
                return f'{item:g} is below the minimum'
            if self.max is not None and item > self.max:
                return f'{item:g} is above the maximum'
        return None


def _type_reason(default: Any, value: Any) -> str | None:
    """Type compatibility: ints are accepted where floats are expected."""
    if isinstance(default, list):
        if not isinstance(value, list):
            return f'{value!r} is not a list'
        if default and not all(_scalar_ok(default[0], v) for v in value):
            return f'{value!r} has items of the wrong type'
        return None
    if _scalar_ok(default, value):
        return None
    return f'{value!r} is a {type(value).__name__}, expected {type(default).__name__}'


def _scalar_ok(default: Any, value: Any) -> bool:
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float))
    return type(value) is type(default)


def defaults(specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """Name → default for a list of specs."""
    return {spec.name: spec.default for spec in specs}


def check_all(specs: Iterable[ParamSpec], values: Mapping[str, Any]) -> list[str]:
    """Reasons for every value in ``values`` that its spec rejects (unknown names too)."""
    by_name = {spec.name: spec for spec in specs}
    reasons = []
    for name, value in values.items():
        spec = by_name.get(name)
        if spec is None:
            reasons.append(f'{name}: unknown parameter')
            continue
        reason = spec.check(value)
        if reason:
            reasons.append(reason)
    return reasons
