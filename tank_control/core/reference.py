"""Setpoint and disturbance schedules per channel: the reference publisher's arithmetic.

A channel is a piecewise-constant target — ``values[i]`` from ``times[i]`` on — optionally
followed at the rate ``ramp_rate`` [channel units/s] ([DeadTimeNotes] Fig. 1.15: 0 → 100 in 25 s is
``ramp_rate = 4``). The value at time ``t`` [s] is a closed-form function of the schedule and
``t`` (no hidden integrator state), so reference_node and the in-process loop compute
bit-identical values. Parameter layout (``setpoint.<ch>.times`` ...), ``value`` and runtime
overrides: docs/nodes.md ("reference_node").
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.params import ParamSpec, unknown_reason

KINDS = ('setpoint', 'disturbance')
FIELDS = ('value', 'times', 'values', 'ramp_rate', 'min', 'max')
UNBOUNDED = 1.0e9   # default |limit|: no practical limit


@dataclass(frozen=True)
class ChannelSchedule:
    """One channel's schedule (units of the channel, times in seconds)."""

    times: tuple[float, ...] = (0.0,)
    values: tuple[float, ...] = (0.0,)
    ramp_rate: float = 0.0
    min: float = -UNBOUNDED
    max: float = UNBOUNDED

    @classmethod
    def constant(cls, value: float, **limits: float) -> ChannelSchedule:
        return cls(times=(0.0,), values=(float(value),), **limits)

    def check(self, name: str) -> str | None:
        """One-line reason why the schedule of channel ``name`` is invalid, or None."""
        if not self.min < self.max:
            return f'{name}.min: {self.min:g} must be below {name}.max {self.max:g}'
        if not self.times:
            return f'{name}.times: empty; give at least one time/value pair'
        if len(self.times) != len(self.values):
            return (f'{name}.times/values: {len(self.times)} times but {len(self.values)} '
                    'values; they must have equal lengths (set both together)')
        if any(not math.isfinite(t) or t < 0 for t in self.times):
            return f'{name}.times: {list(self.times)}; allowed finite values >= 0'
        if any(b < a for a, b in zip(self.times, self.times[1:])):
            return f'{name}.times: {list(self.times)} must be non-decreasing'
        if not (math.isfinite(self.ramp_rate) and self.ramp_rate >= 0):
            return f'{name}.ramp_rate: {self.ramp_rate:g}; allowed [0, inf)'
        for v in self.values:
            if not self.min <= v <= self.max:   # also rejects NaN
                return (f'{name}.values: {v:g} is out of range; allowed '
                        f'[{self.min:g}, {self.max:g}]')
        return None

    def target(self, t: float) -> float:
        """The scheduled (unramped) target at ``t`` [s]."""
        i = bisect.bisect_right(self.times, t)
        return self.values[max(i - 1, 0)]

    def at(self, t: float) -> float:
        """The channel value at ``t`` [s]: the target, rate-limited by ``ramp_rate``."""
        if self.ramp_rate <= 0.0:      # the target
            return self.values[max(bisect.bisect_right(self.times, t) - 1, 0)]
        x = self.values[0]
        n = bisect.bisect_right(self.times, t)
        for i in range(n):
            end = self.times[i + 1] if i + 1 < n else t
            x = _approach(x, self.values[i], self.ramp_rate * (end - self.times[i]))
        return x

    def held_until(self, t: float) -> float:
        """The first instant after ``t`` [s] at which the value may differ from ``at(t)``: the
        next scheduled time (``inf`` after the last); ``t`` itself while a ramp is moving the
        value (it has not reached its target)."""
        if self.ramp_rate > 0.0 and self.at(t) != self.target(t):
            return t
        i = bisect.bisect_right(self.times, t)
        return self.times[i] if i < len(self.times) else math.inf

    def compacted(self, t: float) -> ChannelSchedule:
        """The same values from ``t`` on, with the past folded into the value at ``t``
        (held from 0) — so limits are never judged on values already past."""
        future = bisect.bisect_right(self.times, t)
        x, target = self.at(t), self.target(t)
        times, values = [0.0], [x]
        if target != x:                       # a ramp in progress continues toward target
            times.append(t)
            values.append(target)
        return replace(self, times=tuple(times) + self.times[future:],
                       values=tuple(values) + self.values[future:])

    def override(self, value: float, t: float) -> ChannelSchedule:
        """Target ``value`` from ``t`` on; scheduled entries after ``t`` are dropped
        (a ramp continues from the value reached at ``t``)."""
        return replace(self, times=(0.0, t), values=(self.at(t), float(value)))


def _approach(x: float, target: float, delta: float) -> float:
    """Move ``x`` toward ``target`` by at most ``delta`` (>= 0)."""
    if target > x:
        return min(x + delta, target)
    return max(x - delta, target)


class Reference:
    """Setpoints and disturbances as functions of time, per named channel."""

    def __init__(self, setpoints: Mapping[str, ChannelSchedule] | None = None,
                 disturbances: Mapping[str, ChannelSchedule] | None = None) -> None:
        self._channels: dict[str, dict[str, ChannelSchedule]] = {
            'setpoint': dict(setpoints or {}), 'disturbance': dict(disturbances or {})}
        reasons = [r for kind in KINDS for name, s in self._channels[kind].items()
                   if (r := s.check(f'{kind}.{name}'))]
        if reasons:
            raise ValueError('; '.join(reasons))

    @property
    def setpoint_names(self) -> tuple[str, ...]:
        return tuple(self._channels['setpoint'])

    @property
    def disturbance_names(self) -> tuple[str, ...]:
        return tuple(self._channels['disturbance'])

    def schedule(self, kind: str, name: str) -> ChannelSchedule:
        return self._channels[kind][name]

    def setpoints(self, t: float) -> np.ndarray:
        """Setpoints at ``t`` [s], ordered as ``setpoint_names``."""
        return np.array([s.at(t) for s in self._channels['setpoint'].values()], dtype=float)

    def disturbances(self, t: float) -> np.ndarray:
        """Disturbances at ``t`` [s], ordered as ``disturbance_names``."""
        return np.array(self.values('disturbance', t), dtype=float)

    def held_until(self, kind: str, t: float) -> float:
        """The first instant after ``t`` [s] at which a channel of ``kind`` may change
        (:meth:`ChannelSchedule.held_until`; ``inf`` if none will)."""
        return min((s.held_until(t) for s in self._channels[kind].values()), default=math.inf)

    def values(self, kind: str, t: float) -> list[float]:
        """The channels of ``kind`` (``setpoint`` or ``disturbance``) at ``t`` [s] as floats,
        in channel order."""
        return [s.at(t) for s in self._channels[kind].values()]

    def set_value(self, kind: str, name: str, value: float, t: float) -> str | None:
        """Operator override: target ``value`` from ``t`` on. Returns a reason if rejected."""
        return self.update(kind, name, {'value': value}, t)

    def update(self, kind: str, name: str, changes: Mapping[str, Any], t: float = 0.0) -> str | None:
        """Change one channel live (``times``, ``values``, ``ramp_rate``, ``min``, ``max``;
        ``value`` is an override from ``t``). A rejected change leaves it untouched."""
        channels = self._channels.get(kind)
        if channels is None or name not in channels:
            return f'{kind}.{name}: unknown channel; known: {", ".join(channels or ()) or "none"}'
        fields = dict(changes)
        unknown = set(fields) - set(FIELDS)
        if unknown:
            return f'{kind}.{name}: unknown field(s) {sorted(unknown)}; allowed {", ".join(FIELDS)}'
        value = fields.pop('value', None)
        try:
            for key in ('times', 'values'):
                if key in fields:
                    fields[key] = tuple(float(v) for v in fields[key])
            for key in ('ramp_rate', 'min', 'max'):
                if key in fields:
                    fields[key] = float(fields[key])
            base = channels[name]
            if 'times' not in fields and 'values' not in fields:
                base = base.compacted(t)      # keep the future, judge no past values
            candidate = replace(base, **fields)
            if value is not None:
                value = float(value)
                if not candidate.min <= value <= candidate.max:
                    return (f'{kind}.{name}.value: {value:g} is out of range; allowed '
                            f'[{candidate.min:g}, {candidate.max:g}]')
                candidate = candidate.override(value, t)
        except (TypeError, ValueError) as exc:
            return f'{kind}.{name}: {exc}'
        reason = candidate.check(f'{kind}.{name}')
        if reason:
            return reason
        channels[name] = candidate
        return None


# --------------------------------------------------------------------------- parameters

def channel_lists(values: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """The setpoint and disturbance channel names of a flat parameter dict.

    ValueError if a name is not a string: ROS 2 params files read an unquoted
    ``y``/``n``/``on``/``yes`` as a boolean, so such names must be quoted (``['y']``).
    """
    out = []
    for kind in KINDS:
        names = values.get(f'{kind}.channels', [])
        for name in names:
            if not isinstance(name, str):
                raise ValueError(f'{kind}.channels: {name!r} is not a channel name; quote names '
                                 "such as 'y' (YAML reads an unquoted y as a boolean)")
        out.append([c for c in names if c])
    return out[0], out[1]


def schedule_from_fields(name: str, fields: Mapping[str, Any]) -> ChannelSchedule:
    """A ChannelSchedule from the fields given for channel ``name`` (ValueError with a reason)."""
    fields = dict(fields)
    unknown = set(fields) - set(FIELDS)
    if unknown:
        raise ValueError(f'{name}: unknown field(s) {sorted(unknown)}; allowed {", ".join(FIELDS)}')
    value = fields.pop('value', None)
    if value is not None and 'times' not in fields and 'values' not in fields:
        fields['times'], fields['values'] = [0.0], [value]
        value = None
    try:
        kw: dict[str, Any] = {k: (tuple(float(v) for v in val) if k in ('times', 'values') else float(val))
              for k, val in fields.items()}
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name}: {exc}') from None
    if 'values' in kw and 'times' not in kw and len(kw['values']) == 1:
        kw['times'] = (0.0,)
    schedule = ChannelSchedule(**kw)
    reason = schedule.check(name)
    if reason:
        raise ValueError(reason)
    if value is not None and value not in (schedule.at(0.0), schedule.values[-1]):
        raise ValueError(f'{name}.value: {value!r} with times/values; give either value (a '
                         'constant) or times/values, not both (with both, value must be the '
                         f'schedule\'s value at t = 0, {schedule.at(0.0):g}, or after an '
                         f'override its last target, {schedule.values[-1]:g}, as a dump writes '
                         'it)')
    return schedule


def reference_from_params(values: Mapping[str, Any]) -> Reference:
    """Build a ``Reference`` from the flat parameters of a params file (ValueError with the
    reasons). Names under ``setpoint.``/``disturbance.`` must be ``<kind>.channels`` or a field
    of a listed channel (a typo is refused with the nearest known name); other names are the
    node's own and left to it."""
    setpoint_channels, disturbance_channels = channel_lists(values)
    built: dict[str, dict[str, ChannelSchedule]] = {'setpoint': {}, 'disturbance': {}}
    listed = {('setpoint', c) for c in setpoint_channels} | {('disturbance', c) for c in disturbance_channels}
    known = [f'{kind}.channels' for kind in KINDS] + [
        f'{kind}.{ch}.{name}' for kind, ch in sorted(listed) for name in FIELDS]
    reasons = []
    for key in values:
        parts = split_param_name(key)
        if parts and (parts[0], parts[1]) not in listed:
            reasons.append(f'{key}: channel {parts[1]!r} is not in {parts[0]}.channels')
        elif not parts and key.split('.')[0] in KINDS and key not in known:
            reasons.append(unknown_reason(key, known))
    for kind, names in (('setpoint', setpoint_channels), ('disturbance', disturbance_channels)):
        for ch in names:
            prefix = f'{kind}.{ch}.'
            fields = {k[len(prefix):]: v for k, v in values.items() if k.startswith(prefix)}
            try:
                built[kind][ch] = schedule_from_fields(f'{kind}.{ch}', fields)
            except ValueError as exc:
                reasons.append(str(exc))
    if reasons:
        raise ValueError('; '.join(reasons))
    return Reference(built['setpoint'], built['disturbance'])


def channel_specs(reference: Reference) -> tuple[ParamSpec, ...]:
    """ParamSpecs of the reference's channels; defaults are the given reference's schedules.

    ``value`` is declared with the channel's value at t = 0 and acts as the
    runtime override (layout and semantics: docs/nodes.md, "reference_node").
    """
    specs = [
        # [''] stands for "no channels" (a ROS list parameter needs an item to have a type)
        ParamSpec('setpoint.channels', list(reference.setpoint_names) or [''],
                  'setpoint channel names (= controlled outputs)', read_only=True),
        ParamSpec('disturbance.channels', list(reference.disturbance_names) or [''],
                  'disturbance channel names (plant disturbance inputs)', read_only=True),
    ]
    for kind in KINDS:
        names = reference.setpoint_names if kind == 'setpoint' else reference.disturbance_names
        for ch in names:
            s = reference.schedule(kind, ch)
            p = f'{kind}.{ch}'
            specs += [
                ParamSpec(f'{p}.value', s.at(0.0), f'{kind} {ch}: set at runtime to override the '
                          'schedule from the next instant on [channel units]'),
                ParamSpec(f'{p}.times', list(s.times), f'{kind} {ch}: instants of scheduled '
                          'changes, non-decreasing [s]', min=0.0),
                ParamSpec(f'{p}.values', list(s.values), f'{kind} {ch}: target from times[i] on '
                          '[channel units]'),
                ParamSpec(f'{p}.ramp_rate', s.ramp_rate, f'{kind} {ch}: rate limit of transitions '
                          '(0 = steps) [channel units/s]', min=0.0),
                ParamSpec(f'{p}.min', s.min, f'{kind} {ch}: lowest accepted value'),
                ParamSpec(f'{p}.max', s.max, f'{kind} {ch}: highest accepted value'),
            ]
    return tuple(specs)


def split_param_name(name: str) -> tuple[str, str, str] | None:
    """``'setpoint.T_out.value'`` → ``('setpoint', 'T_out', 'value')``; None if not a channel field."""
    parts = name.split('.')
    if len(parts) < 3 or parts[0] not in KINDS or parts[-1] not in FIELDS:
        return None
    return parts[0], '.'.join(parts[1:-1]), parts[-1]
