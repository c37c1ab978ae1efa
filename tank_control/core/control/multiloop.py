"""Two-loop PI for the mixing tank, with or without decoupling ([Michalski2021] §2–3, eqs. 1–3).

Pairing of [Michalski2021]: level ``h`` [cm] ← hot inflow ``F_H`` [cm³/s], outlet temperature ``T_out``
[°C] ← cold inflow command ``F_Cin`` [cm³/s]. Each loop a parallel PI ``v = kp·e + ki·∫e dt``
(forward Euler); decoupling ``F_H = v_h + D12·v_T``, ``F_Cin = v_T + D21·v_h`` with D12 = −1
and D21 static (2.69) or the filter of [Michalski2021] eq. 2; a setpoint guard for setpoints the tank
cannot hold ([Michalski2021] §2.2); anti-windup on the applied flows. Document settings, limits and the
reasoning: docs/controllers.md ("two_loop_pi").
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.control.pid import ANTI_WINDUP_CHOICES, anti_windup_param, sample_time_param
from tank_control.core.params import param
from tank_control.core.plants.mixing_tank import OPERATING_POINT

DECOUPLING_CHOICES = ('none', 'static', 'dynamic')
D21_NUM = (0.00619, 2.122e-5)        # [Michalski2021] eq. 2, numerator in z: b0·z + b1
D21_DEN = (0.002301, 7.897e-6)       # denominator: a0·z + a1
_GAIN = 1e6


@dataclass
class PiLoop:
    """One parallel PI loop: v = kp·e + ki·∫e dt. kp [u/y units], ki [u/(y units·s)],
    tracking_time [s] (None: kp/ki, or the sample time for a pure integral loop).

    [Michalski2021]'s ``Ki`` (a discrete PI at 1 s) is read as the integral gain kp/ti in 1/s: the same
    number as a per-sample gain at Ts = 1 s, and meaningful at other sample times. The parallel
    form is needed because the decoupled T loop has kp = 0, which has no kp/ti form.
    """

    kp: float
    ki: float
    tracking_time: float | None = None


@dataclass
class SetpointGuard:
    """Steady-state feasibility of the setpoints ([Michalski2021] §1 balance at nominal disturbances).
    Flows cm³/s, temperatures °C, levels cm, alpha cm^2.5/s; defaults: [Michalski2021]'s operating point."""

    enabled: bool = True
    h_min: float = 1.0
    h_max: float = 190.0
    margin: float = 0.5
    alpha: float = OPERATING_POINT.alpha
    F_D: float = OPERATING_POINT.F_D
    T_D: float = OPERATING_POINT.T_D
    T_H: float = OPERATING_POINT.T_H
    T_C: float = OPERATING_POINT.T_C

    def limit(self, r: np.ndarray) -> np.ndarray:
        """Setpoints [h, T_out] limited to what the tank can hold at steady state."""
        if not self.enabled:
            return r
        return np.array(self.limit_pair(float(r[0]), float(r[1])))

    def limit_pair(self, r_h: float, r_t: float) -> tuple[float, float]:
        """:meth:`limit` of the setpoints ``r_h`` [cm], ``r_t`` [°C] as floats."""
        if not self.enabled:
            return r_h, r_t
        h = min(max(r_h, self.h_min), self.h_max)
        total = self.alpha * math.sqrt(h)
        free = max(total - self.F_D, 0.0)
        lo = (free * self.T_C + self.F_D * self.T_D) / total + self.margin
        hi = (free * self.T_H + self.F_D * self.T_D) / total - self.margin
        t = 0.5 * (lo + hi) if lo > hi else min(max(r_t, lo), hi)
        return h, t


@dataclass
class TwoLoopPiConfig:
    """Settings of :class:`TwoLoopPi` ([Michalski2021] §2–3); flows in cm³/s, time in s. Defaults: [Michalski2021] §2.1
    without decoupling. ``v_limit`` (not a parameter): |PI output| limit with decoupling,
    None → u_max."""

    sample_time: float = sample_time_param(note=' ([Michalski2021] used 1 s)')
    decoupling: str = param('none', 'decoupler: none ([Michalski2021] §2), static D21 = 2.69 or dynamic D21 '
                            'filter ([Michalski2021] eqs. 1-3)', choices=DECOUPLING_CHOICES, read_only=True,
                            name='two_loop.decoupling')
    kp_h: float = param(0.9, 'h ← F_H proportional gain', unit='cm³/s per cm', min=-_GAIN,
                        max=_GAIN, name='two_loop.kp_h')
    ki_h: float = param(0.01, 'h ← F_H integral gain kp/ti', unit='cm³/s per cm·s', min=-_GAIN,
                        max=_GAIN, name='two_loop.ki_h')
    kp_T: float = param(-0.2, 'T_out ← F_Cin proportional gain', unit='cm³/s per °C',
                        min=-_GAIN, max=_GAIN, name='two_loop.kp_T')
    ki_T: float = param(-0.002, 'T_out ← F_Cin integral gain', unit='cm³/s per °C·s',
                        min=-_GAIN, max=_GAIN, name='two_loop.ki_T')
    d12: float = param(-1.0, 'decoupler D12 (v_T into F_H)', unit='-', min=-100.0, max=100.0,
                       name='two_loop.d12', source='[Michalski2021] eq. 1')
    d21: float = param(2.69, 'static decoupler D21 (v_h into F_Cin); ignored with decoupling = '
                       'dynamic', unit='-', min=-100.0, max=100.0, name='two_loop.d21',
                       source='[Michalski2021] eq. 2')
    u_min: float = param(0.0, 'lower flow limit for F_H and F_Cin', unit='cm³/s', min=0.0,
                         max=1e4)
    u_max: float = param(300.0, 'upper flow limit for F_H and F_Cin', unit='cm³/s', min=0.0,
                         max=1e4)
    anti_windup: str = anti_windup_param()
    setpoint_guard: bool = param(True, 'limit setpoints to what the tank can reach at steady '
                                 'state (nominal disturbance inflow), see [Michalski2021] §2.2',
                                 name='two_loop.setpoint_guard')
    h_min: float = param(1.0, 'lowest level setpoint used', unit='cm', min=0.1, max=1e4,
                         name='two_loop.h_min')
    h_max: float = param(190.0, 'highest level setpoint used', unit='cm', min=0.1, max=1e4,
                         name='two_loop.h_max')
    guard_margin: float = param(0.5, 'distance kept from the reachable T_out limits', unit='°C',
                                min=0.0, max=20.0, name='two_loop.guard_margin')
    v_limit: float | None = None

    @property
    def h_loop(self) -> PiLoop:
        return PiLoop(self.kp_h, self.ki_h)

    @property
    def t_loop(self) -> PiLoop:
        return PiLoop(self.kp_T, self.ki_T)

    @property
    def guard(self) -> SetpointGuard:
        return SetpointGuard(self.setpoint_guard, self.h_min, self.h_max, self.guard_margin)

    def reason(self) -> str | None:
        """One-line reason naming the invalid parameter, or None."""
        return config_reason(self)


def document_config(decoupling: str = 'none', **changes: Any) -> TwoLoopPiConfig:
    """The settings of [Michalski2021]: §2.1 without decoupling, §3.1 with it ('static' or 'dynamic')."""
    if decoupling == 'none':
        cfg = TwoLoopPiConfig()
    else:
        cfg = TwoLoopPiConfig(kp_h=0.04, ki_h=0.0004, kp_T=0.0, ki_T=-0.01, decoupling=decoupling)
    return replace(cfg, **changes)


def config_reason(cfg: TwoLoopPiConfig) -> str | None:
    """One-line reason naming the invalid parameter, or None."""
    for name, loop in (('h', cfg.h_loop), ('T', cfg.t_loop)):
        for attr in ('kp', 'ki'):
            value = getattr(loop, attr)
            if not _finite(value):
                return f'two_loop.{attr}_{name}: {value!r} is not a finite number'
        if loop.kp == 0.0 and loop.ki == 0.0:
            return f'two_loop.kp_{name}, two_loop.ki_{name}: both 0; at least one must be non-zero'
        if (loop.kp > 0 > loop.ki) or (loop.kp < 0 < loop.ki):   # signs: kp·ki may underflow
            return (f'two_loop.ki_{name}: {loop.ki:g} must have the sign of two_loop.kp_{name} '
                    f'({loop.kp:g})')
    if cfg.decoupling not in DECOUPLING_CHOICES:
        return (f'two_loop.decoupling: {cfg.decoupling!r} is not one of '
                + ', '.join(DECOUPLING_CHOICES))
    for name in ('d12', 'd21'):
        if not _finite(getattr(cfg, name)):
            return f'two_loop.{name}: {getattr(cfg, name)!r} is not a finite number'
    for name in ('u_min', 'u_max', 'sample_time'):
        if not _finite(getattr(cfg, name)):
            return f'{name}: {getattr(cfg, name)!r} is not a finite number'
    if not cfg.u_min < cfg.u_max:
        return f'u_min: {cfg.u_min:g} must be below u_max {cfg.u_max:g}'
    if cfg.sample_time <= 0:
        return f'sample_time: {cfg.sample_time:g} is out of range; allowed (0, inf) s'
    if cfg.v_limit is not None and (not _finite(cfg.v_limit) or cfg.v_limit <= 0):
        return f'v_limit: {cfg.v_limit!r} is out of range; allowed (0, inf) or None'
    if cfg.decoupling != 'none' and abs(1.0 - cfg.d12 * _d21_gain(cfg)) < 1e-9:
        return 'two_loop.d12, two_loop.d21: 1 − d12·d21 = 0 makes the decoupler singular'
    if cfg.anti_windup not in ANTI_WINDUP_CHOICES:
        return f'anti_windup: {cfg.anti_windup!r} is not one of ' + ', '.join(ANTI_WINDUP_CHOICES)
    if not (0.0 < cfg.h_min < cfg.h_max):
        return (f'two_loop.h_min: {cfg.h_min:g} must satisfy 0 < h_min < two_loop.h_max = '
                f'{cfg.h_max:g}')
    return None


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _tracking_gain(loop: PiLoop, h: float) -> float:
    """The back-calculation gain min(h/Tt, 1) per sample of ``h`` seconds, Tt = tracking_time,
    else kp/ki, else h; a Tt that underflows to 0 (kp/ki of extreme gains) gives 1 and one that
    overflows gives 0 (the limits of h/Tt), never a division by zero."""
    tt = loop.tracking_time or (loop.kp / loop.ki if loop.kp != 0 and loop.ki != 0 else h)
    if not tt > 0.0:
        return 1.0
    return min(h / tt, 1.0)


def _d21_gain(cfg: TwoLoopPiConfig) -> float:
    if cfg.decoupling == 'dynamic':
        return (D21_NUM[0] + D21_NUM[1]) / (D21_DEN[0] + D21_DEN[1])
    return cfg.d21


class D21Filter:
    """[Michalski2021] eq. 2 as a difference equation: a0·y(k) + a1·y(k−1) = b0·u(k) + b1·u(k−1).

    [Michalski2021] eq. 3 prints ``+7.897e−6·y(k−1)``; the transfer function of eq. 2 and its quoted gain
    2.69 need ``−`` (eq. 3 as printed has DC gain 2.709), so eq. 2 is implemented.
    """

    def __init__(self) -> None:
        self.u_prev = 0.0
        self.y_prev = 0.0

    @staticmethod
    def dc_gain() -> float:
        return (D21_NUM[0] + D21_NUM[1]) / (D21_DEN[0] + D21_DEN[1])

    def settle(self, u: float) -> None:
        """Put the filter in steady state for a constant input u."""
        self.u_prev = u
        self.y_prev = self.dc_gain() * u

    def step(self, u: float) -> float:
        y = (D21_NUM[0] * u + D21_NUM[1] * self.u_prev - D21_DEN[1] * self.y_prev) / D21_DEN[0]
        self.u_prev, self.y_prev = u, y
        return y


_FLOAT64 = np.dtype(np.float64)


def _floats(values: Any) -> list[float]:
    """A signal vector as a flat list of floats (a 1-D float64 array without conversion)."""
    if type(values) is np.ndarray and values.dtype is _FLOAT64 and values.ndim == 1:
        return values.tolist()
    return np.asarray(values, dtype=float).reshape(-1).tolist()


def _integrate(method: str, integral: float, di: float, aw_gain: float, w: float,
               v_eff: float) -> tuple[float, bool]:
    """One PI loop's integral after a sample and whether anti-windup acted: ``di`` = ki·h·e,
    ``w`` the wanted and ``v_eff`` the effective output; back-calculation adds
    ``aw_gain·(v_eff − w)``, conditional integration skips a step that pushes further into
    the limit."""
    if method == 'back_calculation':
        return integral + (di + aw_gain * (v_eff - w)), v_eff != w
    push = w - v_eff
    if method == 'conditional_integration' and push != 0 and di * push > 0:
        return integral, True
    return integral + di, False


class TwoLoopPi:
    """Two-loop PI of [Michalski2021] behind the Controller protocol.

    Outputs (measured) ``('h', 'T_out')``, inputs (manipulated)
    ``('F_H', 'F_Cin')``, no measured disturbances. ``reset(y, u)`` is
    completed at the next ``step`` (which knows the setpoints): that step
    returns ``u`` (within the limits).

    Optional parts (attributes, None: off): ``scheduler`` picks the gains each sample
    (``core/control/scheduling.py``, taken with :meth:`set_gains`); ``feedforward`` adds
    measured-disturbance flows after the decoupler (``core/control/feedforward.py``; the
    controller then reads its ``disturbance_names``).
    """

    output_names = ('h', 'T_out')
    input_names = ('F_H', 'F_Cin')
    disturbance_names: tuple[str, ...] = ()

    def __init__(self, config: TwoLoopPiConfig | None = None) -> None:
        cfg = config or TwoLoopPiConfig()
        reason = config_reason(cfg)
        if reason:
            raise ValueError(reason)
        self.config = cfg
        self._integral = [0.0, 0.0]
        self._d21 = D21Filter()
        self._u = [math.nan, math.nan]
        self._pending: np.ndarray | None = None
        self._initialised = False
        self._fault = False
        self._last_sample: tuple[Any, ...] | None = None   # what status reports
        self.scheduler: Any = None
        self.feedforward: Any = None
        self._ff = (0.0, 0.0)          # this sample's feedforward flows [F_H, F_Cin]

    @property
    def config(self) -> TwoLoopPiConfig:
        """The settings in use (assign a new, valid configuration to change them)."""
        return self._config

    @config.setter
    def config(self, cfg: TwoLoopPiConfig) -> None:
        self._config = cfg
        self._guard = cfg.guard
        self._guarded: tuple[float, float, float, float] | None = None   # last (r, r_used)
        self._loop_pair = (cfg.h_loop, cfg.t_loop)
        self._v_lo, self._v_hi = self._v_range()
        self._set_pi()

    def _set_pi(self) -> None:
        h = self._config.sample_time
        # per loop: kp, the integral gain per sample ki·h, and the back-calculation gain
        # min(h/Tt, 1) with Tt = tracking_time, else kp/ki, else h
        self._pi = tuple((loop.kp, loop.ki * h, _tracking_gain(loop, h))
                         for loop in self._loop_pair)

    def set_gains(self, kp_h: float, ki_h: float, kp_T: float, ki_T: float,
                  e: list[float]) -> None:
        """Take new PI gains bumplessly at the errors ``e`` = [e_h, e_T] of this sample: each
        integral absorbs the change of kp·e, so kp·e + I is unchanged (a new ki acts on
        future errors)."""
        old = self._loop_pair
        new = (PiLoop(kp_h, ki_h, old[0].tracking_time), PiLoop(kp_T, ki_T, old[1].tracking_time))
        if (old[0].kp, old[0].ki, old[1].kp, old[1].ki) == (kp_h, ki_h, kp_T, ki_T):
            return
        for i in (0, 1):
            self._integral[i] += (old[i].kp - new[i].kp) * e[i]
        self._loop_pair = new
        self._set_pi()

    @property
    def sample_time(self) -> float:
        return self.config.sample_time

    def _loops(self) -> tuple[PiLoop, PiLoop]:
        return self._loop_pair

    def _v_range(self) -> tuple[float, float]:
        cfg = self.config
        if cfg.decoupling == 'none':
            return cfg.u_min, cfg.u_max
        lim = cfg.u_max if cfg.v_limit is None else cfg.v_limit
        return -lim, lim

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.size != 2 or not np.all(np.isfinite(u)):
            raise ValueError(f'reset: u must be 2 finite flows (F_H, F_Cin), got {u!r}')
        self._pending = np.clip(u, self.config.u_min, self.config.u_max)

    def _init_from(self, e: list[float], u: np.ndarray) -> None:
        """States such that the PI outputs reproduce the flows u at error e."""
        cfg = self.config
        lo, hi = self._v_range()
        given, u = u, u - np.array(self._ff)    # the PI outputs (and decoupler) give the rest
        if cfg.decoupling == 'none':
            v = u.copy()
        else:
            g21 = _d21_gain(cfg)
            v = np.linalg.solve(np.array([[1.0, cfg.d12], [g21, 1.0]]), u)
            v = np.clip(v, lo, hi)
            self._d21.settle(float(v[0]))
        for i, loop in enumerate(self._loops()):
            self._integral[i] = float(v[i] - loop.kp * e[i])
        self._u = given.tolist()
        self._initialised = True

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        if (type(y) is np.ndarray and type(r) is np.ndarray and y.dtype is r.dtype is _FLOAT64
                and y.ndim == r.ndim == 1):
            y_l, r_l = y.tolist(), r.tolist()       # what _floats gives, without the calls
        else:
            y_l, r_l = _floats(y), _floats(r)
        if len(y_l) != 2 or len(r_l) != 2:
            raise ValueError(f'y, r: expected 2 values (h, T_out), got {len(y_l)} and {len(r_l)}')
        y_h, y_t = y_l
        r_0, r_1 = r_l
        isfinite = math.isfinite
        if not (isfinite(y_h) and isfinite(y_t) and isfinite(r_0) and isfinite(r_1)):
            self._fault = True
            return self._held()
        last = self._guarded           # the guard is a function of r: reuse its last result
        if last is not None and last[0] == r_0 and last[1] == r_1:
            r_h, r_t = last[2], last[3]
        else:
            r_h, r_t = self._guard.limit_pair(r_0, r_1)
            self._guarded = (r_0, r_1, r_h, r_t)
        limited = r_h != r_0 or r_t != r_1
        e = [r_h - y_h, r_t - y_t]
        if self.feedforward is not None:
            if self._pending is not None or self._fault or not self._initialised:
                self.feedforward.settle(d)
            self._ff = self.feedforward.step(d, r_t, r_h)
            e[0] += self.feedforward.level_offset    # the level excursion it plans (dynamic)
        if self.scheduler is not None:
            self._schedule((y_h, y_t), e)
        if self._pending is not None:
            self._init_from(e, self._pending)
            self._pending = None
        elif self._fault:
            self._init_from(e, self._held())
        elif not self._initialised:
            self._integral[:] = [0.0, 0.0]
            self._d21.settle(0.0)
            self._initialised = True
        self._fault = False
        return self._compute(e, (limited, r_h, r_t))

    def _schedule(self, y: tuple[float, float], e: list[float]) -> None:
        """The scheduler's gains for this sample (before a pending take-over, the flows it
        takes over with)."""
        u = self._pending.tolist() if self._pending is not None else self._u
        gains = self.scheduler.gains(self.scheduler.variable(y, u))
        if gains is not None:
            kp_h, ki_h, kp_t, ki_t = gains       # the table's four columns
            self.set_gains(kp_h, ki_h, kp_t, ki_t, e)

    def _held(self) -> np.ndarray:
        if all(map(math.isfinite, self._u)):
            return np.array(self._u)
        return np.clip(np.zeros(2), self.config.u_min, self.config.u_max)

    def _compute(self, e: list[float], setpoints: tuple[bool, float, float]) -> np.ndarray:
        """One sample at the errors ``e``; ``setpoints``: whether the guard limited them, and
        the setpoints used (for :attr:`status`). Loop h first, then loop T, on floats."""
        cfg = self._config
        lo, hi = self._v_lo, self._v_hi
        u_min, u_max = cfg.u_min, cfg.u_max
        e_h, e_t = e
        integral = self._integral
        (kp_h, kih_h, aw_gain_h), (kp_t, kih_t, aw_gain_t) = self._pi
        w_h, w_t = kp_h * e_h + integral[0], kp_t * e_t + integral[1]
        v_h, v_t = min(max(w_h, lo), hi), min(max(w_t, lo), hi)
        if cfg.decoupling == 'none':
            cross_h = cross_t = 0.0
        else:
            c21 = self._d21.step(v_h) if cfg.decoupling == 'dynamic' else cfg.d21 * v_h
            # [Michalski2021] §3.1: decoupler outputs clipped
            cross_h, cross_t = min(max(cfg.d12 * v_t, lo), hi), min(max(c21, lo), hi)
        ff_h, ff_t = self._ff
        cross_h += ff_h          # the feedforward flows enter like the decoupler terms
        cross_t += ff_t
        s_h, s_t = v_h + cross_h, v_t + cross_t
        u_h = min(max(s_h, u_min), u_max)
        u_t = min(max(s_t, u_min), u_max)
        # anti-windup sees the applied flows: loop i's effective output is u_i − (decoupler
        # and feedforward terms into u_i), within the PI output range; an unclipped flow gives
        # back v_i itself ((v + c) − c differs from v by rounding, which conditional
        # integration would take for a push into a limit and freeze the integrator)
        v_eff_h = v_h if u_h == s_h else min(max(u_h - cross_h, lo), hi)
        v_eff_t = v_t if u_t == s_t else min(max(u_t - cross_t, lo), hi)
        method = cfg.anti_windup
        integral[0], aw_h = _integrate(method, integral[0], kih_h * e_h, aw_gain_h, w_h, v_eff_h)
        integral[1], aw_t = _integrate(method, integral[1], kih_t * e_t, aw_gain_t, w_t, v_eff_t)
        self._u = [u_h, u_t]
        sat_h = u_h != s_h or v_h != w_h
        sat_t = u_t != s_t or v_t != w_t
        self._last_sample = (cfg.decoupling, sat_h, sat_t, aw_h or aw_t, v_h, v_t,
                             integral[0], integral[1], *setpoints)
        return np.array([u_h, u_t])

    @property
    def status(self) -> Mapping[str, Any]:
        """The last sample: decoupling, saturation flags, anti-windup, input fault, the PI
        outputs ``v.*`` and integrals ``i.*``, and the setpoints used (guard)."""
        if self._last_sample is None:
            return {'input_fault': True} if self._fault else {}
        (decoupling, sat_h, sat_t, aw, v_h, v_t, i_h, i_t, limited, r_h, r_t
         ) = self._last_sample
        status = {'decoupling': decoupling, 'saturated': sat_h or sat_t,
                  'saturated.F_H': sat_h, 'saturated.F_Cin': sat_t, 'anti_windup_active': aw,
                  'input_fault': self._fault, 'v.h': v_h, 'v.T_out': v_t, 'i.h': i_h,
                  'i.T_out': i_t, 'setpoint_limited': limited, 'r.h': r_h, 'r.T_out': r_t}
        if self.scheduler is not None:
            (kp_h, ki_h), (kp_t, ki_t) = ((lp.kp, lp.ki) for lp in self._loop_pair)
            status.update({'schedule.value': self.scheduler.value, 'kp_h': kp_h, 'ki_h': ki_h,
                           'kp_T': kp_t, 'ki_T': ki_t})
        if self.feedforward is not None:
            status.update({'ff.F_H': self._ff[0], 'ff.F_Cin': self._ff[1],
                           'ff.h_offset': self.feedforward.level_offset})
        return status
