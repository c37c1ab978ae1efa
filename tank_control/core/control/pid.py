"""Discrete two-degree-of-freedom PID controller (000 eq. 19 with the real derivative of eq. 13).

    U = kp·[ (b·W − Y) + 1/(ti·s)·(W − Y) + td·s/(Tf·s + 1)·(c·W − Y) ],   Tf = td/n

Backward-difference derivative filter, forward-Euler integral, output limits and rate limit,
anti-windup (back-calculation, conditional integration), bumpless manual/auto and gain changes.
Units: ``kp`` in output units per measurement unit, ``ti``, ``td``, ``sample_time`` in s,
``du_max`` in output units per s. Discretisation, the u(0) kick and every guarantee:
docs/controllers.md ("pid").
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from tank_control.core.params import param

ANTI_WINDUP_CHOICES = ('back_calculation', 'conditional_integration', 'none')
N_MIN, N_MAX = 2.0, 50.0
BIG = 1e12
"""Largest magnitude of a gain, time or output limit parameter."""


def sample_time_param(default: float = 1.0, minimum: float = 1e-3, maximum: float = 3600.0,
                      note: str = '') -> Any:
    """``sample_time``: the controller sample time h [s] (read-only)."""
    return param(default, 'controller sample time h' + note, unit='s', min=minimum, max=maximum,
                 read_only=True)


def anti_windup_param() -> Any:
    """``anti_windup``: the integrator anti-windup method."""
    return param('back_calculation', 'integrator anti-windup method', choices=ANTI_WINDUP_CHOICES)


@dataclass
class PidConfig:
    """Settings of :class:`Pid2Dof` (000 eq. 19); every field is a parameter of the same name.

    ``kp`` in output units per measurement unit (a negative kp reverses the sign, as
    ``direct_action`` does; the parameter takes kp > 0), times in seconds, limits in output
    units, ``du_max`` in output units per second. As parameters ``ti = 0`` means no integral
    action (``inf``), ``du_max = 0`` no rate limit, ``tracking_time = 0`` the default Tt.
    """

    kp: float = param(1.0, 'proportional gain kp; > 0, use direct_action for the opposite '
                      'sign', unit='u units per y unit', min=0.0, max=BIG, source='000 eq. 19')
    ti: float = param(math.inf, 'integral time Ti (0 = no integral action)', unit='s', min=0.0,
                      max=BIG, zero=math.inf, source='000 eq. 19')
    td: float = param(0.0, 'derivative time Td (0 = no derivative action)', unit='s', min=0.0,
                      max=BIG, source='000 eq. 19')
    n: float = param(10.0, 'derivative filter ratio n = Td/Tf', unit='-', min=N_MIN, max=N_MAX,
                     source='000 eq. 14')
    b: float = param(1.0, 'setpoint weight in the P term', unit='-', min=0.0, max=1.0,
                     source='000 eq. 19')
    c: float = param(1.0, 'setpoint weight in the D term', unit='-', min=0.0, max=1.0,
                     source='000 eq. 19')
    sample_time: float = sample_time_param()
    u_min: float = param(-1e9, 'lower output limit', unit='u units', min=-BIG, max=BIG)
    u_max: float = param(1e9, 'upper output limit', unit='u units', min=-BIG, max=BIG)
    du_max: float = param(math.inf, 'output rate limit (0 = none)', unit='u units/s', min=0.0,
                          max=BIG, zero=math.inf)
    anti_windup: str = anti_windup_param()
    tracking_time: float | None = param(None, 'back-calculation tracking time Tt (0 = default '
                                        'sqrt(Ti*Td) for PID, Ti for PI)', unit='s', min=0.0,
                                        max=BIG, zero=None)
    direct_action: bool = param(False, 'true: output rises when the measurement rises '
                                '(equivalent to a negative kp)')

    def reason(self) -> str | None:
        """One-line reason why the settings are invalid, naming the parameter, or None."""
        return config_reason(self)


def config_reason(config: PidConfig) -> str | None:
    """One-line reason why ``config`` is invalid, naming the parameter, or None."""
    def number(name: str) -> float:
        return getattr(config, name)

    for name in ('kp', 'td', 'n', 'b', 'c', 'sample_time'):
        value = number(name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return f'{name}: {value!r} is not a finite number'
    checks = [
        ('kp', config.kp != 0.0, 'must be non-zero (negative = reverse sign)'),
        ('td', config.td >= 0.0, 'allowed [0, inf)'),
        ('n', N_MIN <= config.n <= N_MAX, f'allowed [{N_MIN:g}, {N_MAX:g}] (000 eq. 14)'),
        ('b', 0.0 <= config.b <= 1.0, 'allowed [0, 1]'),
        ('c', 0.0 <= config.c <= 1.0, 'allowed [0, 1]'),
        ('sample_time', config.sample_time > 0.0, 'allowed (0, inf) s'),
    ]
    for name, ok, allowed in checks:
        if not ok:
            return f'{name}: {number(name)!r} is out of range; {allowed}'
    if not _is_number(config.ti) or math.isnan(config.ti) or config.ti <= 0.0:
        return f'ti: {config.ti!r} is out of range; allowed (0, inf] s (inf = no integral action)'
    for name in ('u_min', 'u_max'):
        if not _is_number(number(name)) or math.isnan(number(name)):
            return f'{name}: {number(name)!r} is not a number'
    if not config.u_min < config.u_max:
        return f'u_min: {config.u_min:g} must be below u_max {config.u_max:g}'
    if not _is_number(config.du_max) or math.isnan(config.du_max) or config.du_max <= 0.0:
        return f'du_max: {config.du_max!r} is out of range; allowed (0, inf] units/s (inf = no rate limit)'
    if config.anti_windup not in ANTI_WINDUP_CHOICES:
        return f'anti_windup: {config.anti_windup!r} is not one of ' + ', '.join(ANTI_WINDUP_CHOICES)
    tt = config.tracking_time
    if tt is not None and (not _is_number(tt) or not math.isfinite(tt) or tt <= 0.0):
        return f'tracking_time: {tt!r} is out of range; allowed (0, inf) s or None (default)'
    if not isinstance(config.direct_action, bool):
        return f'direct_action: {config.direct_action!r} is not a bool'
    return None


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def default_tracking_time(ti: float, td: float) -> float:
    """Tracking time Tt [s] used when none is configured: √(ti·td) for PID,
    ti for PI (Åström–Hägglund); inf when there is no integral action."""
    if math.isinf(ti):
        return math.inf
    return math.sqrt(ti * td) if td > 0.0 else ti


def _beta(cfg: PidConfig) -> float:
    """Pole ``β = Tf/(Tf + h)`` of the backward-difference derivative filter, Tf = td/n.

    Chosen over Tustin (rings when ``h > 2·Tf``) and a step-invariant filter held for a sample
    (realises ``kp·td·x/(1 − e^(−x))``, x = h/Tf, instead of ``kp·td``): 0 < β < 1 for every
    Tf/h, and the area of the response to an error step is exactly ``kp·td`` for any h.
    """
    tf = cfg.td / cfg.n
    return tf / (tf + cfg.sample_time)


class Pid2Dof:
    """Discrete 2-DOF PID with filtered derivative (000 eq. 19, eqs. 13–14).

    ``update`` is called once per sample (every ``sample_time`` seconds). P static, D a
    backward difference on the filter (pole ``β = Tf/(Tf + h)``, state ``x`` of ``c·r − y``),
    I forward Euler stored in output units. Guarantees: no derivative spike at the first
    sample or after ``reset``; bumpless gain changes, manual/auto transfer and recovery from a
    non-finite input (held output, ``status['input_fault']``); limits and rate limit also in
    manual. Discretisation, the u(0) kick and anti-windup: docs/controllers.md ("pid").
    """

    def __init__(self, config: PidConfig) -> None:
        reason = config_reason(config)
        if reason:
            raise ValueError(reason)
        self._cfg = replace(config)
        self._mode = 'auto'
        self._manual_u: float | None = None
        self._i = 0.0            # integral term [output units]
        self._x = 0.0            # derivative low-pass state [units of c·r − y]
        self._u: float | None = None   # last applied output
        self._v = 0.0            # last unsaturated output
        self._p = 0.0
        self._d = 0.0
        self._i_out = 0.0
        self._last: tuple[float, float] | None = None   # last finite (r, y)
        self._initialised = False
        self._fault = False
        self._saturated = False
        self._rate_limited = False
        self._aw_active = False

    # ----------------------------------------------------------------- state
    @property
    def config(self) -> PidConfig:
        """A copy of the current settings."""
        return replace(self._cfg)

    @property
    def output(self) -> float | None:
        """Last applied output (None before the first sample)."""
        return self._u

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def status(self) -> dict[str, Any]:
        """mode, saturated, rate_limited, anti_windup_active, input_fault and the
        p, i, d terms, unsaturated v and applied u of the last sample."""
        return {
            'mode': self._mode,
            'saturated': self._saturated,
            'rate_limited': self._rate_limited,
            'anti_windup_active': self._aw_active,
            'input_fault': self._fault,
            'p': self._p, 'i': self._i_out, 'd': self._d,
            'v': self._v,
            'u': math.nan if self._u is None else self._u,
        }

    def _gain(self, cfg: PidConfig | None = None) -> float:
        cfg = cfg or self._cfg
        return -cfg.kp if cfg.direct_action else cfg.kp

    def _clip(self, u: float) -> float:
        return min(max(u, self._cfg.u_min), self._cfg.u_max)

    # ------------------------------------------------------------- operation
    def reset(self, r: float, y: float, u: float) -> None:
        """Initialise bumplessly: with the same ``r`` and ``y`` the next
        ``update`` returns ``u`` (clipped to the limits). No derivative kick."""
        for name, value in (('r', r), ('y', y), ('u', u)):
            if not math.isfinite(value):
                raise ValueError(f'reset: {name} = {value!r} is not finite')
        u = self._clip(float(u))
        self._track(float(r), float(y), u)
        self._u = u
        self._v = u
        self._fault = False
        if self._mode == 'manual':
            self._manual_u = u

    def _track(self, r: float, y: float, u: float) -> None:
        """Set the states so that v(r, y) = u with zero derivative term."""
        cfg = self._cfg
        self._x = cfg.c * r - y
        self._p = self._gain() * (cfg.b * r - y)
        self._d = 0.0
        self._i = u - self._p
        self._i_out = self._i
        self._last = (r, y)
        self._initialised = True

    def update(self, r: float, y: float) -> float:
        """One sample: setpoint ``r`` and measurement ``y`` → output ``u``."""
        if not (math.isfinite(r) and math.isfinite(y)):
            self._fault = True
            return self._hold_output()
        r, y = float(r), float(y)
        if self._fault:
            self._fault = False
            self._track(r, y, self._hold_output())
        if not self._initialised:
            self._track(r, y, 0.0)
            self._i = self._i_out = 0.0
        if self._mode == 'manual':
            return self._update_manual(r, y)
        return self._update_auto(r, y)

    def _hold_output(self) -> float:
        return self._u if self._u is not None else self._clip(0.0)

    def _limit(self, v: float) -> float:
        """Limits, then rate limit relative to the last output, then limits again."""
        cfg = self._cfg
        u = self._clip(v)
        if self._u is not None and math.isfinite(cfg.du_max):
            step = cfg.du_max * cfg.sample_time
            u = min(max(u, self._u - step), self._u + step)
        u = self._clip(u)
        self._rate_limited = u != self._clip(v)
        return u

    def _update_manual(self, r: float, y: float) -> float:
        target = self._manual_u if self._manual_u is not None else self._hold_output()
        u = self._limit(target)
        self._track(r, y, u)
        self._v = u
        self._u = u
        self._saturated = u != target
        self._aw_active = False
        return u

    def _update_auto(self, r: float, y: float) -> float:
        cfg = self._cfg
        k = self._gain()
        h = cfg.sample_time
        p = k * (cfg.b * r - y)
        ed = cfg.c * r - y
        if cfg.td > 0.0:
            beta = _beta(cfg)                          # Tf/(Tf + h), backward difference
            x_next = beta * self._x + (1.0 - beta) * ed
            d = k * cfg.n * (ed - x_next)
        else:
            d = 0.0
            x_next = ed
        v = p + self._i + d
        if not (math.isfinite(v) and math.isfinite(x_next)):
            self._fault = True        # overflow from absurd inputs: keep the state and the last output
            return self._hold_output()
        self._x = x_next
        u = self._limit(v)
        self._p, self._d, self._v = p, d, v
        i_used = self._i
        self._aw_active = False
        if math.isfinite(cfg.ti):
            di = k * h / cfg.ti * (r - y)
            if cfg.anti_windup == 'back_calculation':
                tt = cfg.tracking_time or default_tracking_time(cfg.ti, cfg.td)
                self._i += di + min(h / tt, 1.0) * (u - v)   # h/Tt ≤ 1: stable for any Tt
                self._aw_active = u != v
            elif cfg.anti_windup == 'conditional_integration':
                if (v > u and di > 0.0) or (v < u and di < 0.0):
                    self._aw_active = True
                else:
                    self._i += di
            else:
                self._i += di
        self._saturated = u != v
        self._i_out = i_used
        self._u = u
        self._last = (r, y)
        return u

    # ------------------------------------------------------ operator actions
    def set_gains(self, **changes: Any) -> None:
        """Change any PidConfig field bumplessly (000 eq. 19 gains, limits, ...).

        Raises ValueError (naming the parameter and the allowed range) and
        leaves the controller untouched if a value is invalid.
        """
        known = {f.name for f in fields(PidConfig)}
        for name in changes:
            if name not in known:
                raise ValueError(f'{name}: unknown PID parameter; allowed ' + ', '.join(sorted(known)))
        new = replace(self._cfg, **changes)
        reason = config_reason(new)
        if reason:
            raise ValueError(reason)
        old = self._cfg
        if self._initialised and self._last is not None:
            r, y = self._last
            x_new = self._x + (new.c - old.c) * r     # keeps c·r − y − x unchanged
            p_old = self._gain(old) * (old.b * r - y)
            # D of the next sample at unchanged inputs: kp·n·β·(c·r − y − x)
            d_old = self._gain(old) * old.n * _beta(old) * (old.c * r - y - self._x) if old.td > 0 else 0.0
            p_new = self._gain(new) * (new.b * r - y)
            d_new = self._gain(new) * new.n * _beta(new) * (new.c * r - y - x_new) if new.td > 0 else 0.0
            self._x = x_new
            self._i += (p_old + d_old) - (p_new + d_new)
        self._cfg = new

    def set_manual(self, u: float | None = None) -> None:
        """Switch to manual: the output becomes ``u`` (limited) from the next
        sample; without ``u`` the last output is held (bumpless)."""
        if u is not None and not math.isfinite(u):
            raise ValueError(f'manual_output: {u!r} is not finite')
        self._manual_u = self._hold_output() if u is None else float(u)
        self._mode = 'manual'

    def set_auto(self) -> None:
        """Switch to automatic; the next output continues from the last one."""
        if self._mode == 'manual' and self._last is not None and self._u is not None:
            self._track(*self._last, self._u)
        self._mode = 'auto'


class PidController:
    """:class:`Pid2Dof` behind the Controller protocol of core/interfaces.py (SISO).

    Reads the measured channel ``output_name`` (default ``y``) and its
    setpoint, writes the manipulated channel ``input_name`` (default ``u``).
    ``reset(y, u)`` is completed at the first ``step`` (which knows ``r``),
    so that step returns ``u`` exactly.
    """

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, config: PidConfig, output_name: str = 'y', input_name: str = 'u') -> None:
        self.pid = Pid2Dof(config)
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._pending: tuple[float, float] | None = None

    @property
    def sample_time(self) -> float:
        return self.pid.config.sample_time

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        y0, u0 = _scalar(y, 'y'), _scalar(u, 'u')
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        self._pending = (y0, u0)

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        y0, r0 = _scalar(y, 'y'), _scalar(r, 'r')
        if self._pending is not None and math.isfinite(y0) and math.isfinite(r0):
            self.pid.reset(r0, y0, self._pending[1])
            self._pending = None
        return np.array([self.pid.update(r0, y0)], dtype=float)

    def set_gains(self, **changes: Any) -> None:
        self.pid.set_gains(**changes)

    @property
    def status(self) -> Mapping[str, Any]:
        return self.pid.status


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for a SISO PID, got {arr.size}')
    return float(arr[0])
