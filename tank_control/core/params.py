"""Settings declared once: dataclass fields that are also ROS 2 parameters (no rclpy here).

A configuration dataclass declares each setting with :func:`param` (default, description, unit,
range, read-only, the ROS encoding of ``inf``/``None``, source equation). From it follow the
``ParamSpec`` records the nodes declare (:func:`specs_of`), the validated configuration built from
parameter values (:func:`config_from`, errors named by parameter) and the parameter values of a
configuration (:func:`values_of`). ROS parameters cannot hold ``inf``: a field declared with
``zero=math.inf`` (or ``zero=None``) is written as 0 and read back as ``inf`` (``None``).
"""
from __future__ import annotations

import array
import dataclasses
import difflib
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any, TypeGuard

ParamValue = bool | int | float | str | list[float] | list[str] | list[int] | list[bool]

_META = 'tank_control.param'
_UNSET: Any = object()


TIME_TINY = 1e-6
"""Smallest non-zero time [s] of the parameters where 0 means "none" (``ti``, ``td``, the
tuning model's times): far below any sample time (>= 1e-4 s), and far above the 1e-154 below
which a product of two times underflows to 0 (a division by it would fail)."""


class ConfigError(ValueError):
    """Parameter values that cannot make a configuration; the message names the parameter."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default (ROS value), description (with units) and allowed values.

    ``min``/``max`` bound numbers (inclusive), ``tiny`` is the smallest magnitude of a non-zero
    number (a time or factor whose quotients and products must stay finite: 0 < |x| < tiny is
    refused), ``choices`` restricts strings, ``read_only`` parameters are set at start-up only.
    The type is the default's (ints are accepted for floats).
    """

    name: str
    default: ParamValue
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    tiny: float | None = None

    def allowed(self) -> str:
        """Human-readable allowed values, used in rejection messages."""
        if self.choices is not None:
            return 'one of ' + ', '.join(self.choices)
        if self.min is not None or self.max is not None:
            lo = '-inf' if self.min is None else f'{self.min:g}'
            hi = 'inf' if self.max is None else f'{self.max:g}'
            if self.tiny is not None and self.min is not None and self.min >= 0:
                return f'0 or [{self.tiny:g}, {hi}]'
            if self.tiny is not None:
                return f'[{lo}, {hi}], 0 or at least {self.tiny:g} in magnitude'
            return f'[{lo}, {hi}]'
        return f'any {type(self.default).__name__}'

    def check(self, value: Any) -> str | None:
        """``None`` if ``value`` is acceptable, else a one-line reason naming the parameter."""
        reason = _type_reason(self.default, value)
        if reason is None:
            for item in value if isinstance(value, list) else [value]:
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
            if self.tiny is not None and 0 < abs(item) < self.tiny:
                return f'{item:g} is non-zero and below the smallest magnitude {self.tiny:g}'
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


def _is_int(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def coerce(spec: ParamSpec, value: Any) -> Any:
    """``value`` converted as a ROS user expects, else unchanged: integers become doubles where
    the parameter is a double (``kp 2`` → ``2.0``), also in lists; a scalar given for a list of
    doubles becomes a one-item list; rclpy's ``array.array``/tuples become lists."""
    if isinstance(value, (array.array, tuple)):
        value = list(value)
    default = spec.default
    if isinstance(default, float) and _is_int(value):
        return float(value)
    if isinstance(default, list) and default and isinstance(default[0], float):
        if _is_int(value) or isinstance(value, float):
            return [float(value)]
        if isinstance(value, list) and all(_is_int(v) or isinstance(v, float) for v in value):
            return [float(v) for v in value]
    return value


def nearest(name: str, known: Iterable[str]) -> str | None:
    """The known name closest to a misspelt ``name`` (None if nothing is close); a name
    differing only in case (``Kp``) gets its known spelling (``kp``)."""
    known = list(known)
    same = [k for k in known if k.lower() == name.lower()]
    if len(same) == 1:
        return same[0]
    matches = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    return matches[0] if matches else None


def unknown_reason(name: str, known: Iterable[str], what: str = 'parameter') -> str:
    """``'kpp: unknown parameter; did you mean kp?'`` (or the list of known names)."""
    known = sorted(known)
    guess = nearest(name, known)
    hint = f'did you mean {guess}?' if guess else 'known: ' + ', '.join(known)
    return f'{name}: unknown {what}; {hint}'


def lookup(table: Mapping[str, Any], name: str, what: str) -> Any:
    """``table[name]``; else :class:`ConfigError` ``'<what>: <name>: unknown ...; did you mean
    ...?'`` (e.g. a plant kind in the parameter ``plant``)."""
    try:
        return table[name]
    except (KeyError, TypeError):
        raise ConfigError(f'{what.split()[0]}: ' + unknown_reason(str(name), table, what)) from None


def by_name(*items: Any) -> dict[str, Any]:
    """A table of ``items`` keyed by their ``name`` (a kind registry)."""
    return {item.name: item for item in items}


def finder(table: Mapping[str, Any], what: str) -> Callable[[str], Any]:
    """``find(name)``: :func:`lookup` of ``name`` in ``table`` (e.g. ``get_kind``)."""
    def find(name: str) -> Any:
        return lookup(table, name, what)
    find.__doc__ = f"The {what} ``name``; ConfigError with the nearest known name if unknown."
    return find


# ----------------------------------------------------------------------------------- fields
@dataclass(frozen=True)
class _Meta:
    description: str
    unit: str
    min: float | None
    max: float | None
    choices: tuple[str, ...] | None
    read_only: bool
    zero: Any
    name: str | None
    source: str
    tiny: float | None


def param(default: Any, description: str, *, unit: str = '', min: float | None = None,
          max: float | None = None, choices: Iterable[str] | None = None,
          read_only: bool = False, zero: Any = _UNSET, name: str | None = None,
          source: str = '', tiny: float | None = None) -> Any:
    """A dataclass field that is also a ROS 2 parameter.

    ``default`` is the field's value (a tuple for a list parameter); ``name`` the parameter name
    when it differs from the field's (``'two_loop.kp_h'``); ``zero`` the field value written as
    0 because ROS cannot hold it (``math.inf``: "0 = none"; ``None``: "0 = default");
    ``min``/``max`` bound the parameter value; ``tiny`` is the smallest magnitude of a non-zero
    value (e.g. a time whose products and quotients must stay finite: 0 = none, or at least
    ``tiny``); ``source`` cites the document ("[Viteckova] eq. 19").
    """
    meta = _Meta(description, unit, min, max, tuple(choices) if choices else None, read_only,
                 zero, name, source, tiny)
    return dataclasses.field(default=default, metadata={_META: meta})


@dataclass(frozen=True)
class _Param:
    field: str
    spec: ParamSpec
    zero: Any


def _encode(p: _Param, value: Any) -> Any:
    if p.zero is not _UNSET and (value is p.zero or value == p.zero):
        return 0 if _is_int(p.spec.default) else 0.0
    if isinstance(value, tuple):
        return list(value)
    return value


def _decode(p: _Param, value: Any) -> Any:
    if p.zero is not _UNSET and value == 0:
        return p.zero
    if isinstance(value, list):
        return tuple(value)
    return value


@cache
def _params(cls: type) -> dict[str, _Param]:
    out: dict[str, _Param] = {}
    for f in dataclasses.fields(cls):
        meta = f.metadata.get(_META)
        if meta is None:
            continue
        name = meta.name or f.name
        text = meta.description + (f' [{meta.unit}]' if meta.unit else '') + (
            f' ({meta.source})' if meta.source else '')
        probe = _Param(f.name, ParamSpec(name, 0.0, ''), meta.zero)
        spec = ParamSpec(name, _encode(probe, f.default), text, meta.min, meta.max,
                         meta.choices, meta.read_only, meta.tiny)
        out[name] = _Param(f.name, spec, meta.zero)
    return out


def specs_of(cls: type, **defaults: Any) -> tuple[ParamSpec, ...]:
    """The parameters declared on dataclass ``cls``; ``defaults`` (by field name) replace the
    declared defaults (e.g. a kind's channel names)."""
    out = []
    for p in _params(cls).values():
        spec = p.spec
        if p.field in defaults:
            spec = dataclasses.replace(spec, default=_encode(p, defaults[p.field]))
        out.append(spec)
    return tuple(out)


def defaults_of(cls: type) -> dict[str, ParamValue]:
    """Parameter name → default (ROS value) of every parameter declared on ``cls``."""
    return {name: p.spec.default for name, p in _params(cls).items()}


def names_of(cls: type) -> tuple[str, ...]:
    """Parameter names declared on ``cls``."""
    return tuple(_params(cls))


def param_name(cls: type, field_name: str) -> str:
    """The parameter name of field ``field_name`` of ``cls``."""
    return next(name for name, p in _params(cls).items() if p.field == field_name)


def config_from(cls: type, values: Mapping[str, Any], base: Any = None, *, live: bool = False,
                **defaults: Any) -> Any:
    """``cls`` from parameter values by parameter name; missing ones keep ``base``'s values (or
    ``defaults``, by field name, or the declared defaults). Checks every value against its spec
    and the relations in ``cls.reason()``; ``live`` (a change of a running object) refuses
    read-only parameters. Raises :class:`ConfigError` naming the parameter (an unknown name with
    the nearest known one)."""
    params = _params(cls)
    changes: dict[str, Any] = dict(defaults) if base is None else {}
    for name, value in values.items():
        p = params.get(name)
        if p is None:
            raise ConfigError(unknown_reason(name, params))
        if live and p.spec.read_only:
            raise ConfigError(f'{name}: read-only, set at start-up only')
        spec = p.spec
        if p.field in defaults:   # a kind's own default may change the type (float → list)
            spec = dataclasses.replace(spec, default=_encode(p, defaults[p.field]))
        value = coerce(spec, value)
        reason = spec.check(value)
        if reason:
            raise ConfigError(reason)
        changes[p.field] = _decode(p, value)
    config = dataclasses.replace(base, **changes) if base is not None else cls(**changes)
    reason = relations_reason(config)
    if reason:
        raise ConfigError(reason)
    return config


def check_config(config: Any) -> Any:
    """``config`` if every parameter field is within its declared range and the relations hold,
    else :class:`ConfigError` naming the parameter (for configurations built in Python)."""
    config_from(type(config), values_of(config))
    return config


def relations_reason(config: Any) -> str | None:
    """``config.reason()`` if the class defines relations between its fields, else None."""
    check = getattr(config, 'reason', None)
    return check() if callable(check) else None


def values_of(config: Any) -> dict[str, ParamValue]:
    """Parameter name → ROS value of every parameter field of ``config``."""
    cls: type = type(config)
    fields = _params(cls)
    return {name: _encode(p, getattr(config, p.field)) for name, p in fields.items()}
