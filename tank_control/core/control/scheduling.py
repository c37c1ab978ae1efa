"""PI gain scheduling of the mixing tank's two-loop PI over its operating point.

A table of breakpoints ``s_0 < s_1 < … < s_n`` of a scheduling variable (the level ``h`` [cm],
the outlet temperature ``T_out`` [°C], or the applied flow ``F_H`` or ``F_Cin`` [cm³/s]) with
the gains ``kp_h, ki_h, kp_T, ki_T`` of :class:`~tank_control.core.control.multiloop.TwoLoopPi`
at each; between breakpoints the gains are interpolated linearly, outside they are those of the
nearest end (Åström & Wittenmark, *Adaptive Control*, 2nd ed., ch. 9: gain scheduling).

Bumpless at run time: the PI output ``w = kp·e + I`` (integral ``I = Σ ki·h·e``) is kept
continuous when the gains move by adding ``(kp_old − kp_new)·e`` to ``I``
(:meth:`TwoLoopPi.set_gains`); a new ``ki`` acts on future errors only.

:func:`design_schedule` computes such a table: at each operating point (level, temperature,
nominal disturbance) the linearised tank ([Michalski2021] eqs. 4–6 at that point, with its delays) gives
the two diagonal channels as first-order-plus-dead-time models, and a tuning rule of
``core/tuning/rules.py`` is applied to each.
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from tank_control.core.params import param
from tank_control.core.plants.mixing_tank import OPERATING_POINT
from tank_control.core.tuning.rules import tune

SCHEDULE_VARIABLES = ('none', 'h', 'T_out', 'F_H', 'F_Cin')
GAIN_NAMES = ('kp_h', 'ki_h', 'kp_T', 'ki_T')
_GAIN = 1e6


def _table(default: float, what: str, unit: str) -> Any:
    name = what.split(' ')[0]
    return param((default,), f'{what} at each breakpoint (gain scheduling)', unit=unit,
                 min=-_GAIN, max=_GAIN, name=f'two_loop.schedule.{name}')


@dataclass(frozen=True)
class GainSchedule:
    """The gain table of the two-loop PI (module docstring); ``variable`` none: the fixed gains
    ``two_loop.kp_h`` … apply and the table is not used."""

    variable: str = param('none', 'scheduling variable: none (fixed gains two_loop.kp_h ...), '
                          'h [cm] or T_out [°C] (measured), F_H or F_Cin [cm³/s] (the last '
                          'applied flow)', choices=SCHEDULE_VARIABLES,
                          name='two_loop.schedule.variable')
    breakpoints: tuple[float, ...] = param((OPERATING_POINT.h,), 'values of the scheduling '
                                           'variable, strictly increasing', unit='variable units',
                                           min=-_GAIN, max=_GAIN,
                                           name='two_loop.schedule.breakpoints')
    kp_h: tuple[float, ...] = _table(0.9, 'kp_h (h ← F_H proportional gain)', 'cm³/s per cm')
    ki_h: tuple[float, ...] = _table(0.01, 'ki_h (h ← F_H integral gain)', 'cm³/s per cm·s')
    kp_T: tuple[float, ...] = _table(-0.2, 'kp_T (T_out ← F_Cin proportional gain)',
                                     'cm³/s per °C')
    ki_T: tuple[float, ...] = _table(-0.002, 'ki_T (T_out ← F_Cin integral gain)',
                                     'cm³/s per °C·s')

    @property
    def active(self) -> bool:
        return self.variable != 'none'

    def reason(self) -> str | None:
        """One-line reason naming the invalid ``two_loop.schedule.*`` parameter, or None."""
        return schedule_reason(self)

    def gains(self, s: float) -> tuple[float, float, float, float]:
        """``(kp_h, ki_h, kp_T, ki_T)`` at ``s``: linear between breakpoints, the end values
        outside them."""
        kp_h, ki_h, kp_t, ki_t = interpolate(self.breakpoints,
                                             (self.kp_h, self.ki_h, self.kp_T, self.ki_T), s)
        return kp_h, ki_h, kp_t, ki_t


def schedule_reason(table: GainSchedule) -> str | None:
    """Why ``table`` is not a usable gain table (the parameter named), or None: equal lengths,
    finite values, strictly increasing breakpoints, and each row a valid PI pair (kp and ki of
    one sign, not both 0), of one sign over the table."""
    prefix = 'two_loop.schedule.'
    if table.variable not in SCHEDULE_VARIABLES:
        return (f'{prefix}variable: {table.variable!r} is not one of '
                + ', '.join(SCHEDULE_VARIABLES))
    columns = {'breakpoints': table.breakpoints,
               **{name: getattr(table, name) for name in GAIN_NAMES}}
    for name, column in columns.items():
        if len(column) == 0:
            return f'{prefix}{name}: empty; give one value per breakpoint'
        for value in column:
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                return f'{prefix}{name}: {value!r} is not a finite number'
    n = len(table.breakpoints)
    for name in GAIN_NAMES:
        if len(columns[name]) != n:
            return (f'{prefix}{name}: {len(columns[name])} values for {n} breakpoints; the '
                    'lengths must be equal')
    for k in range(1, n):
        if not table.breakpoints[k] > table.breakpoints[k - 1]:
            return (f'{prefix}breakpoints: must be strictly increasing; '
                    f'{table.breakpoints[k]:g} follows {table.breakpoints[k - 1]:g}')
    for loop in ('h', 'T'):
        for k, (kp, ki) in enumerate(zip(columns[f'kp_{loop}'], columns[f'ki_{loop}'])):
            if kp == 0.0 and ki == 0.0:
                return f'{prefix}kp_{loop}, {prefix}ki_{loop}: both 0 at breakpoint {k}'
            if (kp > 0 > ki) or (kp < 0 < ki):
                return (f'{prefix}ki_{loop}: {ki:g} at breakpoint {k} must have the sign of '
                        f'{prefix}kp_{loop} ({kp:g})')
        values = columns[f'kp_{loop}'] + columns[f'ki_{loop}']
        if min(values) < 0.0 < max(values):     # interpolation would pass through kp = ki = 0
            return (f'{prefix}kp_{loop}, {prefix}ki_{loop}: gains of both signs; the action of '
                    'the loop must not reverse across the table')
    return None


def interpolate(breakpoints: tuple[float, ...], columns: Iterable[tuple[float, ...]],
                s: float) -> tuple[float, ...]:
    """Each column at ``s``, linear between ``breakpoints`` (increasing), the end values
    outside them."""
    cols = tuple(columns)
    n = len(breakpoints)
    if s <= breakpoints[0] or n == 1:
        return tuple(c[0] for c in cols)
    if s >= breakpoints[-1]:
        return tuple(c[-1] for c in cols)
    k = bisect.bisect_right(breakpoints, s)          # breakpoints[k-1] <= s < breakpoints[k]
    x0, x1 = breakpoints[k - 1], breakpoints[k]
    w = (s - x0) / (x1 - x0)
    return tuple(c[k - 1] + w * (c[k] - c[k - 1]) for c in cols)


class Scheduler:
    """Runs a :class:`GainSchedule` on a :class:`TwoLoopPi`: each sample the scheduling
    variable picks the gains, which the controller takes bumplessly."""

    def __init__(self, table: GainSchedule) -> None:
        self.table = table
        self._index = {'h': 0, 'T_out': 1}.get(table.variable)
        self._flow = {'F_H': 0, 'F_Cin': 1}.get(table.variable)
        self._columns = (table.kp_h, table.ki_h, table.kp_T, table.ki_T)
        self.value = math.nan               # the scheduling variable at the last sample

    def variable(self, y: tuple[float, float], u: list[float]) -> float:
        """The scheduling variable from the measurement ``y = (h, T_out)`` or the last applied
        flows ``u = [F_H, F_Cin]`` (NaN before the first output)."""
        if self._index is not None:
            return y[self._index]
        assert self._flow is not None               # the variable is h, T_out, F_H or F_Cin
        return u[self._flow]

    def gains(self, s: float) -> tuple[float, ...] | None:
        """The table's gains at ``s``; None for a non-finite ``s`` (keep the gains)."""
        self.value = s
        if not math.isfinite(s):
            return None
        return interpolate(self.table.breakpoints, self._columns, s)


# --------------------------------------------------------------------------- design
@dataclass(frozen=True)
class ChannelModels:
    """The diagonal channels of the linearised tank at one operating point, as FOPDT models
    ``K·e^(−L·s)/(T·s + 1)`` ([Michalski2021] eqs. 4–6 with the delays; derivation in
    :func:`diagonal_channels`). Level: K [cm per cm³/s], T, L [s]; temperature: K [°C per
    cm³/s], T, L [s]; ``F_H``, ``F_C`` [cm³/s] hold the point."""

    h: float
    T: float
    F_H: float
    F_C: float
    level: tuple[float, float, float]
    temperature: tuple[float, float, float]
    temperature_closed: tuple[float, float, float]


def steady_flows(h: float, T: float, F_D: float = OPERATING_POINT.F_D,
                 T_D: float = OPERATING_POINT.T_D, T_H: float = OPERATING_POINT.T_H,
                 T_C: float = OPERATING_POINT.T_C, alpha: float = OPERATING_POINT.alpha
                 ) -> tuple[float, float]:
    """``(F_H, F_C)`` [cm³/s] holding level ``h`` [cm] and temperature ``T`` [°C] at steady
    state ([Michalski2021] §1: F_H + F_C + F_D = α·√h, F_H·T_H + F_C·T_C + F_D·T_D = α·√h·T)."""
    total = alpha * math.sqrt(h)
    f_h = (total * (T - T_C) - F_D * (T_D - T_C)) / (T_H - T_C)
    return f_h, total - F_D - f_h


def diagonal_channels(h: float, T: float, F_D: float = OPERATING_POINT.F_D,
                      T_D: float = OPERATING_POINT.T_D, *, C: float = OPERATING_POINT.C,
                      alpha: float = OPERATING_POINT.alpha, T_H: float = OPERATING_POINT.T_H,
                      T_C: float = OPERATING_POINT.T_C, tau_cold: float = OPERATING_POINT.tau_c,
                      tau_out: float = OPERATING_POINT.tau, sample_time: float = 1.0
                      ) -> ChannelModels:
    """The paired channels of the tank linearised at ``(h, T)`` (``mixing_tank.jacobian``).

    With V = C·h², F = α·√h: dΔV/dt = −F/(4V)·ΔV + ΔF_H + ΔF_C + …, so h ← F_H is
    K = 2h/F [cm per cm³/s], T = 4V/F [s]; dΔT/dt = −F/V·ΔT + (T_C − T)/V·ΔF_C + … (the V term
    vanishes at equilibrium), so T_out ← F_Cin is K = (T_C − T)/F [°C per cm³/s], T = V/F,
    L = tau_cold + tau_out [s]. The level has no delay: L = sample_time/2 (the zero-order hold),
    so that delay-based rules apply.

    ``temperature_closed`` is the T_out ← F_Cin channel with the (fast) level loop closed, the
    equivalent process of sequential loop closing (Hovd & Skogestad 1994; [Precup2013] §3.7): the level
    loop takes back every change of the cold flow with the hot one (ΔF_H = −ΔF_C), so
    K = (T_C − T_H)/F, (T_H − T_C)/(T − T_C) times the open channel's (3.7 at [Michalski2021]'s point: its
    relative gain); T and L as open.
    """
    volume, total = C * h * h, alpha * math.sqrt(h)
    f_h, f_c = steady_flows(h, T, F_D, T_D, T_H, T_C, alpha)
    return ChannelModels(h, T, f_h, f_c,
                         (2.0 * h / total, 4.0 * volume / total, 0.5 * sample_time),
                         ((T_C - T) / total, volume / total, tau_cold + tau_out),
                         ((T_C - T_H) / total, volume / total, tau_cold + tau_out))


def design_schedule(points: Iterable[tuple[float, float]], *, rule: str = 'simc',
                    temperature_rule: str | None = None,
                    level_tau_c: float | None = None, temperature_tau_c: float | None = None,
                    level_options: Mapping[str, Any] | None = None,
                    temperature_options: Mapping[str, Any] | None = None,
                    sequential: bool = True, **tank: Any) -> GainSchedule:
    """A gain table over the level: at each ``(h [cm], T [°C])`` of ``points`` (increasing
    h) the :func:`diagonal_channels` models tuned as PI by ``rule`` (``rules.tune``; e.g.
    ``simc``, ``lambda``, ``amigo``, ``ms``; the temperature loop by ``temperature_rule`` if
    given); ``*_tau_c`` [s] the closed-loop time constants
    for simc/lambda, ``*_options`` further process arguments of the rule; ``sequential``: the
    temperature loop is designed on ``temperature_closed`` (the level loop closed; False: the
    open channel, which ignores the interaction and, tuned so, is unstable in the coupled
    loop); ``tank``: the tank constants of :func:`diagonal_channels`. Gains in the parallel
    form ki = kp/ti."""
    rows: list[tuple[float, ...]] = []
    for h, T in points:
        models = diagonal_channels(h, T, **tank)
        row: list[float] = [h]
        for (gain, time_constant, dead_time), name, tau_c, options in (
                (models.level, rule, level_tau_c, level_options),
                (models.temperature_closed if sequential else models.temperature,
                 temperature_rule or rule, temperature_tau_c, temperature_options)):
            args: dict[str, Any] = dict(gain=gain, time_constant=time_constant,
                                        dead_time=dead_time, model='fopdt', **(options or {}))
            if tau_c is not None:
                args['tau_c'] = tau_c
            result = tune(name, 'pi', **args)
            row += [result['kp'], result['kp'] / result['ti']]
        rows.append(tuple(row))
    columns = list(zip(*rows))
    return GainSchedule('h', *(tuple(float(v) for v in c) for c in columns))
