"""Discrete two-degree-of-freedom PID controller ([Viteckova] eq. 19 with the real derivative of eq. 13).

    U = kp·[ (b·W − Y) + 1/(ti·s)·(W − Y) + td·s/(Tf·s + 1)·(c·W − Y) ],   Tf = td/n

Backward-difference derivative filter, forward-Euler integral, output limits and rate limit,
anti-windup (back-calculation, conditional integration), bumpless manual/auto and gain changes.
Units: ``kp`` in output units per measurement unit, ``ti``, ``td``, ``sample_time`` in s,
``du_max`` in output units per s. Discretisation, the u(0) kick and every guarantee:
docs/controllers.md ("pid").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tank_control.core.control.siso_law import SisoController, SisoLaw
from tank_control.core.params import TIME_TINY, param

ANTI_WINDUP_CHOICES = ('back_calculation', 'conditional_integration', 'none')


def limits_reason(u_min: float, u_max: float, anti_windup: str) -> str | None:
    """Why output limits and anti-windup method do not fit (None if they do)."""
    if not u_min < u_max:
        return f'u_min: {u_min:g} must be below u_max {u_max:g}'
    if anti_windup not in ANTI_WINDUP_CHOICES:
        return f'anti_windup: {anti_windup!r} is not one of ' + ', '.join(ANTI_WINDUP_CHOICES)
    return None
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
    """Settings of :class:`Pid2Dof` ([Viteckova] eq. 19); every field is a parameter of the same name.

    ``kp`` in output units per measurement unit (a negative kp reverses the sign, as
    ``direct_action`` does; the parameter takes kp > 0), times in seconds, limits in output
    units, ``du_max`` in output units per second. As parameters ``ti = 0`` means no integral
    action (``inf``), ``du_max = 0`` no rate limit, ``tracking_time = 0`` the default Tt.
    """

    kp: float = param(1.0, 'proportional gain kp; > 0, use direct_action for the opposite '
                      'sign', unit='u units per y unit', min=0.0, max=BIG, source='[Viteckova] eq. 19')
    ti: float = param(math.inf, 'integral time Ti (0 = no integral action)', unit='s', min=0.0,
                      max=BIG, zero=math.inf, tiny=TIME_TINY, source='[Viteckova] eq. 19')
    td: float = param(0.0, 'derivative time Td (0 = no derivative action)', unit='s', min=0.0,
                      max=BIG, tiny=TIME_TINY, source='[Viteckova] eq. 19')
    n: float = param(10.0, 'derivative filter ratio n = Td/Tf', unit='-', min=N_MIN, max=N_MAX,
                     source='[Viteckova] eq. 14')
    b: float = param(1.0, 'setpoint weight in the P term', unit='-', min=0.0, max=1.0,
                     source='[Viteckova] eq. 19')
    c: float = param(1.0, 'setpoint weight in the D term', unit='-', min=0.0, max=1.0,
                     source='[Viteckova] eq. 19')
    sample_time: float = sample_time_param()
    u_min: float = param(-1e9, 'lower output limit', unit='u units', min=-BIG, max=BIG)
    u_max: float = param(1e9, 'upper output limit', unit='u units', min=-BIG, max=BIG)
    du_max: float = param(math.inf, 'output rate limit (0 = none)', unit='u units/s', min=0.0,
                          max=BIG, zero=math.inf)
    anti_windup: str = anti_windup_param()
    tracking_time: float | None = param(None, 'back-calculation tracking time Tt (0 = default '
                                        'sqrt(Ti*Td) for PID, Ti for PI)', unit='s', min=0.0,
                                        max=BIG, zero=None, tiny=TIME_TINY)
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
        ('n', N_MIN <= config.n <= N_MAX, f'allowed [{N_MIN:g}, {N_MAX:g}] ([Viteckova] eq. 14)'),
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


class Pid2Dof(SisoLaw[PidConfig]):
    """Discrete 2-DOF PID with filtered derivative ([Viteckova] eq. 19, eqs. 13–14).

    ``update`` is called once per sample (every ``sample_time`` seconds). P static, D a
    backward difference on the filter (pole ``β = Tf/(Tf + h)``, state ``x`` of ``c·r − y``),
    I forward Euler stored in output units. Guarantees: no derivative spike at the first
    sample or after ``reset``; bumpless gain changes, manual/auto transfer and recovery from a
    non-finite input (held output, ``status['input_fault']``); limits and rate limit also in
    manual. Discretisation, the u(0) kick and anti-windup: docs/controllers.md ("pid").
    Modes, limits, faults and the integral: :class:`SisoLaw`.
    """

    unknown_setting = 'unknown PID parameter'

    def __init__(self, config: PidConfig) -> None:
        super().__init__(config)
        self._p = 0.0
        self._d = 0.0
        self._rate_limited = False

    def _set_config(self, cfg: PidConfig) -> None:
        """Also the derivative filter pole β (None without derivative action) and the largest
        output change per sample (None without a rate limit)."""
        super()._set_config(cfg)
        self._beta = _beta(cfg) if cfg.td > 0.0 else None
        self._du_step = cfg.du_max * cfg.sample_time if math.isfinite(cfg.du_max) else None

    def _check(self, config: PidConfig) -> None:
        reason = config_reason(config)
        if reason:
            raise ValueError(reason)

    def _flags(self) -> dict[str, bool]:
        return {'rate_limited': self._rate_limited}

    @property
    def rate_step(self) -> float | None:
        """The largest output change per sample, ``du_max·sample_time`` [u units] (None without
        a rate limit)."""
        return self._du_step

    def _terms(self) -> dict[str, float]:
        """The p, i, d terms of the last sample."""
        return {'p': self._p, 'i': self._i_out, 'd': self._d}

    def _default_tracking_time(self) -> float:
        return default_tracking_time(self._cfg.ti, self._cfg.td)

    def _rest(self, r: float, y: float) -> float:
        """Filter state ``c·r − y`` and zero derivative term; returns the P term."""
        cfg = self._cfg
        self._x = cfg.c * r - y
        self._p = self._gain() * (cfg.b * r - y)
        self._d = 0.0
        return self._p

    def _limit(self, v: float) -> float:
        """Limits, then rate limit relative to the last output, then limits again."""
        cfg = self._cfg
        lo, hi = cfg.u_min, cfg.u_max
        clipped = min(max(v, lo), hi)
        step = self._du_step
        if self._u is not None and step is not None:
            u = min(max(min(max(clipped, self._u - step), self._u + step), lo), hi)
        else:
            u = clipped                                # the limits again change nothing
        self._rate_limited = u != clipped
        return u

    def _update_auto(self, r: float, y: float) -> float:
        cfg = self._cfg
        k = self._k
        p = k * (cfg.b * r - y)
        ed = cfg.c * r - y
        beta = self._beta
        if beta is not None:                           # Tf/(Tf + h), backward difference
            x_next = beta * self._x + (1.0 - beta) * ed
            d = k * cfg.n * (ed - x_next)
        else:
            d = 0.0
            x_next = ed
        v = p + self._i + d
        if not self._accept(v, x_next):
            return self._hold_output()
        self._p, self._d = p, d
        return self._apply(r, y, v, k, r - y)

    def _retune(self, old: PidConfig, new: PidConfig, r: float, y: float) -> None:
        """Keep P + I + D of the next sample at unchanged inputs ([Viteckova] eq. 19 gains, limits, ...)."""
        x_new = self._x + (new.c - old.c) * r     # keeps c·r − y − x unchanged
        p_old = self._gain(old) * (old.b * r - y)
        # D of the next sample at unchanged inputs: kp·n·β·(c·r − y − x)
        d_old = self._gain(old) * old.n * _beta(old) * (old.c * r - y - self._x) if old.td > 0 else 0.0
        p_new = self._gain(new) * (new.b * r - y)
        d_new = self._gain(new) * new.n * _beta(new) * (new.c * r - y - x_new) if new.td > 0 else 0.0
        self._x = x_new
        self._i += (p_old + d_old) - (p_new + d_new)


class PidController(SisoController[Pid2Dof]):
    """:class:`Pid2Dof` behind the Controller protocol of core/interfaces.py (SISO).

    Reads the measured channel ``output_name`` (default ``y``) and its
    setpoint, writes the manipulated channel ``input_name`` (default ``u``).
    ``reset(y, u)`` is completed at the first ``step`` (which knows ``r``),
    so that step returns ``u`` exactly.
    """

    law_name = 'PID'

    def __init__(self, config: PidConfig, output_name: str = 'y', input_name: str = 'u') -> None:
        super().__init__(Pid2Dof(config), output_name, input_name)

    @property
    def pid(self) -> Pid2Dof:
        return self._law

    def set_gains(self, **changes: Any) -> None:
        self.pid.set_gains(**changes)
