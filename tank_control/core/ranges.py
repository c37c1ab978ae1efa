"""Physically plausible ranges of the signal channels: what a node accepts on its inputs.

A value outside its channel's range is treated like a non-finite one by controller_node,
plant_node and the in-process loop (``core/loop.py``): refused, counted, the last good value kept
(a measurement: the controller holds or sends its fail-safe output). Each channel a node receives
has one parameter ``range.<channel>`` = ``[min, max]`` (both bounds in one list, so a change is
atomic), in the channel's units. Defaults come from the mixing tank model ([Michalski2021] §1,
``core/plants/mixing_tank.py``) and, for the SISO channels, from how far a SISO loop can go:

* ``h`` [cm]: ``[-h_max, 10·h_max]`` with the tank's default brim ``h_max`` = 200 cm (the linear
  model has no brim and may leave ``[0, h_max]``; noise may take h below 0);
* ``T_out``, ``T_D``, ``T_H``, ``T_C`` [°C]: the liquid-water range ``[T_MIN, T_MAX]`` widened by
  100 °C on each side (linearised models leave it);
* ``F_H``, ``F_Cin``, ``F_D`` [cm³/s]: ``±FLOW_MAX``, the largest flow the tank's parameters allow;
* ``y`` (SISO output): ``±SISO_OUTPUT``; ``u``, ``v`` and any other channel: ``±SISO_INPUT``.

A plant's manipulated inputs default to the actuator the controller drives them with, when the
plant is started with its controller's parameters (the same scenario or ``--params-file``): the
controller kind's output limits (``input_limits``: ``u_min``/``u_max``, ``mpcs.u_min``/``u_max``)
widened by ``ACTUATOR_MARGIN`` of their span on each side, and within the channel's model
range above (:func:`actuator_ranges`). An output the controller cannot send is then refused.

Units: those of each channel (docs/nodes.md, "Plausible ranges").
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from tank_control.core.params import ConfigError, ParamSpec, coerce
from tank_control.core.plants.mixing_tank import FLOW_MAX, T_MAX, T_MIN, MixingTankConfig

PREFIX = 'range.'
H_MAX = MixingTankConfig().h_max
"""The tank's default brim [cm]."""
T_MARGIN = 100.0
"""[°C] beyond the liquid-water range for the temperatures."""
SISO_OUTPUT = 1e5
"""Bound of a SISO output ``y``: far beyond any setpoint of the shipped scenarios."""
SISO_INPUT = 1e6
"""Bound of a SISO input ``u``/``v`` and of any channel the models do not name."""
ACTUATOR_MARGIN = 0.1
"""A plant input accepts its controller's output limits widened by this fraction of their span
on each side (rounding, a hand-set value near a limit); further out it is no controller's."""

_T = (T_MIN - T_MARGIN, T_MAX + T_MARGIN)
_F = (-FLOW_MAX, FLOW_MAX)
DEFAULTS: Mapping[str, tuple[float, float]] = MappingProxyType({
    'h': (-H_MAX, 10.0 * H_MAX), 'T_out': _T, 'T_D': _T, 'T_H': _T, 'T_C': _T,
    'F_H': _F, 'F_Cin': _F, 'F_D': _F,
    'y': (-SISO_OUTPUT, SISO_OUTPUT), 'u': (-SISO_INPUT, SISO_INPUT),
    'v': (-SISO_INPUT, SISO_INPUT)})


_CHANNEL = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')


def channel_names(values: Mapping[str, Any], direction: str) -> list[str]:
    """``<direction>.channels`` of ``values`` ([''] = none), checked: a bridge node's
    measurement and manipulated channels (opcua_bridge_node, signal_bridge_node)."""
    names = values.get(f'{direction}.channels', [''])
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
        raise ConfigError(f'{direction}.channels: {names!r} is not a list of channel names')
    names = [n for n in names if n != '']
    for name in names:
        if not _CHANNEL.match(name):
            raise ConfigError(f'{direction}.channels: {name!r} is not a channel name; allowed '
                              'letters, digits and _ (quote names such as y, n in YAML)')
    if len(set(names)) != len(names):
        raise ConfigError(f'{direction}.channels: repeated name in {names}')
    return names


def default_range(channel: str) -> tuple[float, float]:
    """The declared default ``(min, max)`` of ``channel`` (see the module docstring)."""
    return DEFAULTS.get(channel, (-SISO_INPUT, SISO_INPUT))


def name_of(channel: str) -> str:
    """The parameter of ``channel``'s range: ``range.<channel>``."""
    return PREFIX + channel


def actuator_ranges(limits: Mapping[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """Default ranges of plant inputs from the output limits ``{channel: (min, max)}`` of the
    controller driving them: widened by ``ACTUATOR_MARGIN`` of the span on each side, within
    the channel's model range (:func:`default_range`)."""
    out = {}
    for channel, (lo, hi) in limits.items():
        model_lo, model_hi = default_range(channel)
        margin = ACTUATOR_MARGIN * (hi - lo)
        wide = (max(lo - margin, model_lo), min(hi + margin, model_hi))
        if math.isfinite(wide[0]) and math.isfinite(wide[1]) and wide[0] < wide[1]:
            out[channel] = (float(wide[0]), float(wide[1]))
    return out


def range_specs(channels: Iterable[str],
                defaults: Mapping[str, tuple[float, float]] | None = None
                ) -> tuple[ParamSpec, ...]:
    """One parameter ``range.<channel>`` per channel (in order, duplicates once); ``defaults``
    replace the model's default of some channels (:func:`actuator_ranges`)."""
    out: dict[str, ParamSpec] = {}
    for channel in channels:
        lo, hi = (defaults or {}).get(channel) or default_range(channel)
        out[channel] = ParamSpec(
            name_of(channel), [float(lo), float(hi)],
            f'plausible range [min, max] of channel {channel} (its units): a value outside is '
            'refused like a non-finite one (counted, last good value kept)')
    return tuple(out.values())


@dataclass(frozen=True)
class Ranges:
    """``(min, max)`` per channel; a channel without a range accepts every finite value."""

    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    def reason(self, channel: str, value: float) -> str | None:
        """None if ``value`` is acceptable for ``channel``, else why not (one line, without the
        value, so a node logs it once however the value varies)."""
        if not math.isfinite(value):
            return f'non-finite value for {channel!r}'
        bounds = self.bounds.get(channel)
        if bounds is not None and not bounds[0] <= value <= bounds[1]:
            return (f'value for {channel!r} outside {name_of(channel)} '
                    f'[{bounds[0]:g}, {bounds[1]:g}]')
        return None

    def accepts(self, channel: str, value: float) -> bool:
        """``value`` is finite and within ``channel``'s range."""
        if not math.isfinite(value):
            return False
        bounds = self.bounds.get(channel)
        return bounds is None or bounds[0] <= value <= bounds[1]


def ranges_from(values: Mapping[str, Any], channels: Iterable[str],
                defaults: Mapping[str, tuple[float, float]] | None = None) -> Ranges:
    """The ranges of ``channels`` from parameter values (missing ones: the defaults, with
    ``defaults`` as in :func:`range_specs`); ``ConfigError`` naming the parameter unless each
    is two finite values with min < max."""
    bounds = {}
    for spec in range_specs(channels, defaults):
        value = coerce(spec, values.get(spec.name, spec.default))
        reason = spec.check(value)
        if reason is None and (len(value) != 2 or not value[0] < value[1]):
            reason = (f'{spec.name}: {value!r} must be [min, max] with min < max; '
                      f'default {spec.default!r}')
        if reason:
            raise ConfigError(reason)
        bounds[spec.name[len(PREFIX):]] = (float(value[0]), float(value[1]))
    return Ranges(MappingProxyType(bounds))
