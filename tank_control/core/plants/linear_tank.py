"""The mixing tank linearised at its operating point, with its two delays ([Michalski2021] eqs. 4–6, §2.3).

The first-order Taylor expansion of [Michalski2021] §1 around ``x_op = [V_op, T_op]`` (``V_op = C·h_op²``)
and the operating-point inflows ``w_op = [F_H, F_C, F_D, T_H, T_C, T_D]``:

    dx/dt = f(x_op, w_op) + A·(x − x_op) + B·(w − w_op)        (A, B: ``mixing_tank.jacobian``)
    h = h_op + (V − V_op)/(2·C·h_op),   T_out(t) = T(t − τ),   F_C(t) = F_Cin(t − τ_C)

The constant term ``f(x_op, w_op)`` ([Michalski2021]'s k_const) makes the equilibrium of the linear
plant that of the tank to first order ([Michalski2021] §1 prints T_op = 33.57; the steady state is
2115/63). Nothing physical is clipped: flows may go negative and T may leave [T_C, T_H] — what
[Michalski2021] §2.3/§3.3 call the danger of trusting the linear model (only a value beyond ±FLOW_MAX is,
so the state stays finite). Exact: the inputs are held over
each step and F_C is delayed exactly (``DelayLine``); the state is advanced over every
constant piece by ``exp([[A, B·w + f], [0, 0]]·τ)``, and T_out is the state ``τ`` seconds
back, advanced exactly from the piece it falls in, so no delay is rounded to the tick.
Units: cm, cm³, cm³/s, °C, s.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from tank_control.core.scipy_lazy import expm

from tank_control.core.interfaces import NS_PER_S, StatusValue, seconds
from tank_control.core.params import check_config, config_from
from tank_control.core.plants.delay_line import DelayLine
from tank_control.core.plants.mixing_tank import FLOW_MAX, MixingTankConfig, jacobian
from tank_control.core.plants.siso import StepLength, as_floats

_SHARED = ('C', 'alpha', 'F_H', 'F_C', 'F_D', 'T_H', 'T_C', 'T_D', 'h_op', 'T_op', 'tau_cold',
           'tau_out', 'initial_h', 'initial_T', 'max_dead_time')
"""The nonlinear tank's parameters the linear one has (declared once, in ``MixingTankConfig``)."""

_KEPT = 16
"""Piece lengths whose transition matrices are kept."""


def _reason(self: Any) -> str | None:
    for name in ('tau_cold', 'tau_out'):
        value = getattr(self, name)
        if value > self.max_dead_time:
            return (f'{name}: {value:g} is above max_dead_time; '
                    f'allowed [0, {self.max_dead_time:g}]')
    return None


LinearTankConfig = dataclasses.make_dataclass(
    'LinearTankConfig',
    [(f.name, f.type, dataclasses.field(default=f.default, metadata=f.metadata))
     for f in dataclasses.fields(MixingTankConfig) if f.name in _SHARED],
    frozen=True, namespace={'reason': _reason, '__module__': __name__,
                            '__doc__': 'Parameters of ``LinearTank`` (those of '
                                       '``MixingTankConfig`` it uses).'})


def _expanded(cfg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, f0, w_op)``: the Jacobians at the operating point, the nonlinear right-hand
    side there and the operating-point inflows (module docstring)."""
    a, b = jacobian(cfg)
    w_op = np.array([cfg.F_H, cfg.F_C, cfg.F_D, cfg.T_H, cfg.T_C, cfg.T_D])
    v_op = cfg.C * cfg.h_op ** 2
    f_in = cfg.F_H + cfg.F_C + cfg.F_D
    heat = cfg.F_H * cfg.T_H + cfg.F_C * cfg.T_C + cfg.F_D * cfg.T_D
    f0 = np.array([f_in - cfg.alpha * math.sqrt(cfg.h_op), (heat - f_in * cfg.T_op) / v_op])
    return a, b, f0, w_op


class LinearTank:
    """The linearised mixing tank with delays on F_Cin (τ_C) and T_out (τ); module docstring."""

    output_names: tuple[str, ...] = ('h', 'T_out')
    input_names: tuple[str, ...] = ('F_H', 'F_Cin')
    disturbance_names: tuple[str, ...] = ('F_D', 'T_D', 'T_H', 'T_C')

    def __init__(self, config: Any = None) -> None:
        self._set_config(check_config(config if config is not None else LinearTankConfig()))
        self._cold = DelayLine(self._config.max_dead_time, initial=self._config.F_C)
        self._dt = StepLength()
        self.reset()

    def _set_config(self, cfg: Any) -> None:
        self._config = cfg
        self._a, self._b, self._f0, self._w_op = _expanded(cfg)
        self._x_op = np.array([cfg.C * cfg.h_op ** 2, cfg.T_op])
        self._pieces: dict[int, np.ndarray] = {}

    @property
    def config(self) -> Any:
        """The current configuration (change it with ``configure``)."""
        return self._config

    def configure(self, **changes: Any) -> None:
        """Change parameters live (all-or-nothing), effective from the next ``step``: the
        state (V, T) is kept, the expansion is made at the new operating point; ``F_C``,
        ``initial_h``, ``initial_T`` act at the next ``reset``. ``ValueError`` (one line)."""
        self._set_config(config_from(LinearTankConfig, changes, self._config, live=True))

    def reset(self) -> None:
        """State (C·initial_h², initial_T), held so before t = 0 (T_out's history); the τ_C
        line pre-filled with F_C."""
        cfg = self._config
        self._x = np.array([cfg.C * cfg.initial_h ** 2, cfg.initial_T])
        self._t_ns = 0
        self._cold.reset(cfg.F_C)
        self._F_C = cfg.F_C
        self._steps = 0
        self._clipped_inputs = 0
        # (start [ns], state there, affine input b·(w − w_op) + f0 held from there on)
        self._history: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._starts: list[int] = []

    @property
    def time(self) -> float:
        """Plant time [s] since ``reset``."""
        return seconds(self._t_ns)

    @property
    def state(self) -> np.ndarray:
        """``[V, T]``: volume [cm³] and (undelayed) tank temperature [°C]."""
        return self._x.copy()

    def level(self) -> float:
        """The linearised level h_op + (V − V_op)/(2·C·h_op) [cm]."""
        cfg = self._config
        return cfg.h_op + (self._x[0] - self._x_op[0]) / (2.0 * cfg.C * cfg.h_op)

    def outputs(self) -> np.ndarray:
        """``[h, T_out]`` now, with T_out(t) = T(t − τ) (noise-free)."""
        return np.array([self.level(), self._state_at(self._t_ns - round(
            self._config.tau_out * NS_PER_S))[1]])

    def nominal_inputs(self) -> np.ndarray:
        """``[F_H, F_Cin]`` of the operating point [cm³/s]."""
        return np.array([self._config.F_H, self._config.F_C])

    def nominal_disturbances(self) -> np.ndarray:
        """``[F_D, T_D, T_H, T_C]`` of the operating point (also used when ``d`` is empty)."""
        cfg = self._config
        return np.array([cfg.F_D, cfg.T_D, cfg.T_H, cfg.T_C])

    def _transition(self, duration_ns: int) -> np.ndarray:
        """``exp([[A, I], [0, 0]]·τ)`` (3 × 3 blocks of 2): Φ = [:2, :2], Γ = [:2, 2:]."""
        piece = self._pieces.get(duration_ns)
        if piece is None:
            block = np.zeros((4, 4))
            block[:2, :2] = self._a
            block[:2, 2:] = np.eye(2)
            piece = expm(block * (duration_ns / NS_PER_S))
            if len(self._pieces) >= _KEPT:
                self._pieces.pop(next(iter(self._pieces)))
            self._pieces[duration_ns] = piece
        return piece

    def _advanced(self, x: np.ndarray, drive: np.ndarray, duration_ns: int) -> np.ndarray:
        """``x`` after ``duration_ns`` of the constant ``drive`` (exact)."""
        if duration_ns <= 0:
            return x
        e = self._transition(duration_ns)
        # d(x − x_op)/dt = A·(x − x_op) + drive
        return self._x_op + e[:2, :2] @ (x - self._x_op) + e[:2, 2:] @ drive

    def _state_at(self, t_ns: int) -> np.ndarray:
        """The state at plant time ``t_ns`` (≤ now): the initial state before the first
        step, else advanced from the start of the piece holding ``t_ns``."""
        index = bisect.bisect_right(self._starts, t_ns) - 1
        if index < 0:
            return self._history[0][1] if self._history else self._x
        start, x, drive = self._history[index]
        if index == len(self._history) - 1 and t_ns >= self._t_ns:
            return self._x
        return self._advanced(x, drive, t_ns - start)

    def step(self, u: Any, d: Any, dt: float) -> None:
        """Advance ``dt`` seconds with ``u = [F_H, F_Cin]`` and ``d = [F_D, T_D, T_H, T_C]``
        held (empty ``d``: operating point). ``ValueError`` (state untouched) on a wrong size,
        non-finite value or bad ``dt``; no physical value is clipped (module docstring), only a
        value beyond ±FLOW_MAX (a numeric guard)."""
        f_hot, f_cold_in = as_floats('u', u, 2)
        d_vec = as_floats('d', d, 4, allow_empty=True) or self.nominal_disturbances().tolist()
        if not all(-FLOW_MAX <= v <= FLOW_MAX for v in (f_hot, f_cold_in, *d_vec)):
            # a numeric guard, not physics: |value| <= FLOW_MAX keeps the state finite
            self._clipped_inputs += 1
            f_hot, f_cold_in = (min(max(v, -FLOW_MAX), FLOW_MAX) for v in (f_hot, f_cold_in))
            d_vec = [min(max(v, -FLOW_MAX), FLOW_MAX) for v in d_vec]
        dt_ns = self._dt.ns(dt)
        f_dist, t_dist, t_hot, t_cold = d_vec
        cfg = self._config
        t_ns = self._t_ns
        self._cold.push(t_ns, f_cold_in)
        start = t_ns
        for duration, f_cold in self._cold.segments(t_ns, dt_ns / NS_PER_S, cfg.tau_cold):
            duration_ns = round(duration * NS_PER_S)
            if duration_ns <= 0:
                continue
            w = np.array([f_hot, f_cold, f_dist, t_hot, t_cold, t_dist])
            drive = self._b @ (w - self._w_op) + self._f0
            self._history.append((start, self._x, drive))
            self._starts.append(start)
            self._x = self._advanced(self._x, drive, duration_ns)
            start += duration_ns
            self._F_C = f_cold
        self._t_ns = t_ns + dt_ns
        self._prune()
        self._steps += 1

    def _prune(self) -> None:
        """Drop pieces that ended more than ``max_dead_time`` ago."""
        keep_from = self._t_ns - round(self._config.max_dead_time * NS_PER_S)
        drop = bisect.bisect_right(self._starts, keep_from) - 1
        if drop > 0:
            del self._history[:drop]
            del self._starts[:drop]

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """``time`` [s], ``steps``, the state ``V`` [cm³], ``T`` [°C], ``h`` [cm] and ``F_C``,
        the delayed cold inflow now entering [cm³/s]; ``clipped_inputs``: steps with a value
        beyond ±FLOW_MAX, clipped to it."""
        return {'time': self.time, 'steps': self._steps, 'V': float(self._x[0]),
                'T': float(self._x[1]), 'h': self.level(), 'F_C': self._F_C,
                'clipped_inputs': self._clipped_inputs}
