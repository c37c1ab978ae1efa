"""Measured-disturbance feedforward for the mixing tank's two-loop PI, from F_D and T_D.

Units: flows cm³/s, temperatures °C, time s. The disturbance inflow ``F_D`` at ``T_D`` enters
the tank at once ([Michalski2021] §1); the hot flow ``F_H`` too, the cold flow only ``tau_cold`` after its
command (F_C(t) = F_Cin(t − τ_C)); ``T_out`` is measured ``tau_out`` after the tank (T_out(t) =
T(t − τ)). Added to the PI outputs (after the decoupler) are the deviations from the flows
that suit the nominal disturbance ``(F_D0, T_D0)``, so at the nominal disturbance nothing
changes:

* ``static``: the steady-state mass and energy balances of [Michalski2021] §1, F_H + F_C + F_D = α·√h and
  F_H·T_H + F_C·T_C + F_D·T_D = α·√h·T, solved for the change of (F_H, F_C) that keeps h and T:

      ΔF_H* = −Δ[F_D·(T_D − T_C)]/(T_H − T_C),   ΔF_C* = −Δ[F_D·(T_H − T_D)]/(T_H − T_C)

  exact on the nonlinear tank at every level and temperature (neither h nor T appears), sent
  at once to both flows. Its flaw: the cold part arrives τ_C late, so for τ_C after a change
  the hot part acts alone and upsets the heat balance.
* ``dynamic``: what compensates what. The cold flow can act only τ_C late, so ΔF_Cin = ΔF_C*
  is sent now (the realisable part of −G_d/G_u: the ideal would need d(t + τ_C)); the hot
  flow, which acts at once, bridges the delay: from an internal copy of the τ_C delay line it
  knows the cold compensation ΔF_C,arr that has arrived and sets

      ΔF_H = −{Δ[F_D·(T_D − T)] + ΔF_C,arr·(T_C − T)}/(T_H − T),   T = the T_out setpoint,

  which keeps the tank's heat balance Σ F_i·(T_i − T) = V·dT/dt unchanged at every instant
  (ΔF_H = ΔF_H* once ΔF_C,arr = ΔF_C*). Of the two balances the temperature's is kept
  because T_out is measured τ late (tau_out, 120 s) and its PI loop is slow. The mass
  imbalance m = ΔF_H + ΔF_C,arr + ΔF_D over the τ_C window moves the level; were the level
  loop to correct that with F_H it would undo the heat balance (measured: then dynamic is
  no better than static), so the level it causes is predicted with the linearised level of
  [Michalski2021] eq. 4 at the level setpoint r_h (V = C·r_h², F = α·√r_h, time constant 4V/F, gain
  1/(2·C·r_h) from volume to level; exact discretisation) and added to the level loop's
  error (``level_offset`` [cm]): the level loop leaves that excursion to the tank's
  self-regulation and corrects only what the model does not explain. tau_out enters no
  term: it delays the effect of the disturbance and of its compensation on T_out alike and
  cancels from −G_d/G_u; it is why the feedforward pays off (feedback learns of a
  disturbance τ late). The delay line has round(tau_cold/sample_time) samples.

A disturbance channel not (yet) measured (NaN) is taken at its nominal value.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from tank_control.core.params import param
from tank_control.core.plants.mixing_tank import OPERATING_POINT, T_MAX, T_MIN

FEEDFORWARD_CHOICES = ('none', 'static', 'dynamic')
DISTURBANCES = ('F_D', 'T_D')
_OP = OPERATING_POINT


@dataclass(frozen=True)
class FeedforwardConfig:
    """Settings of :class:`DisturbanceFeedforward`; defaults: [Michalski2021]'s tank (§1)."""

    mode: str = param('none', 'measured-disturbance feedforward from F_D and T_D: none, static '
                      '(steady-state balances) or dynamic (with the cold-flow delay); not '
                      'none: the controller reads the disturbance topic',
                      choices=FEEDFORWARD_CHOICES, read_only=True, name='two_loop.feedforward')
    T_H: float = param(_OP.T_H, 'feedforward model: hot water temperature T_H', unit='°C',
                       min=T_MIN, max=T_MAX, name='two_loop.ff.T_H', source='[Michalski2021] §1')
    T_C: float = param(_OP.T_C, 'feedforward model: cold water temperature T_C', unit='°C',
                       min=T_MIN, max=T_MAX, name='two_loop.ff.T_C', source='[Michalski2021] §1')
    tau_cold: float = param(_OP.tau_c, 'feedforward model (dynamic): delay from F_Cin to the '
                            'tank', unit='s', min=0.0, max=1e4, name='two_loop.ff.tau_cold',
                            source='[Michalski2021] §1')
    F_D0: float = param(_OP.F_D, 'nominal disturbance inflow: no feedforward there; also used '
                        'while F_D is not measured', unit='cm³/s', min=0.0, max=1e6,
                        name='two_loop.ff.F_D0')
    T_D0: float = param(_OP.T_D, 'nominal disturbance temperature: no feedforward there; also '
                        'used while T_D is not measured', unit='°C', min=T_MIN, max=T_MAX,
                        name='two_loop.ff.T_D0')
    C: float = param(_OP.C, 'feedforward model (dynamic): volume constant C in V = C·h²',
                     unit='cm', min=1e-6, max=1e6, name='two_loop.ff.C', source='[Michalski2021] §1')
    alpha: float = param(_OP.alpha, 'feedforward model (dynamic): outflow constant α in '
                         'F = α·√h', unit='cm^2.5/s', min=1e-6, max=1e6,
                         name='two_loop.ff.alpha', source='[Michalski2021] §1')

    @property
    def active(self) -> bool:
        return self.mode != 'none'

    def reason(self) -> str | None:
        if self.mode not in FEEDFORWARD_CHOICES:
            return (f'two_loop.feedforward: {self.mode!r} is not one of '
                    + ', '.join(FEEDFORWARD_CHOICES))
        if not self.T_H > self.T_C:
            return (f'two_loop.ff.T_H: {self.T_H:g} must be above two_loop.ff.T_C '
                    f'{self.T_C:g}')
        return None


class DisturbanceFeedforward:
    """The feedforward flows ``(ΔF_H, ΔF_Cin)`` [cm³/s] of a measured ``d = [F_D, T_D]``
    (module docstring); ``sample_time`` [s] of the controller."""

    disturbance_names = DISTURBANCES

    def __init__(self, config: FeedforwardConfig, sample_time: float) -> None:
        self.config = config
        self._ts = sample_time
        self.level_offset = 0.0         # predicted level excursion now [cm] (dynamic)
        self._next_offset = 0.0         # … at the next sample
        self._span = config.T_H - config.T_C
        self._n = max(int(round(config.tau_cold / sample_time)), 0) \
            if config.mode == 'dynamic' else 0
        self._sent: deque[float] = deque(maxlen=self._n + 1)
        self.last = (0.0, 0.0)

    def _measured(self, d: np.ndarray) -> tuple[float, float]:
        values = np.asarray(d, dtype=float).reshape(-1).tolist() if len(d) else []
        cfg = self.config
        f_d = values[0] if len(values) > 0 and math.isfinite(values[0]) else cfg.F_D0
        t_d = values[1] if len(values) > 1 and math.isfinite(values[1]) else cfg.T_D0
        return f_d, t_d

    def static(self, f_d: float, t_d: float) -> tuple[float, float]:
        """``(ΔF_H*, ΔF_C*)``: the steady-state change of the flows (module docstring)."""
        cfg = self.config
        t_h, t_c = cfg.T_H, cfg.T_C
        d_hot = -(f_d * (t_d - t_c) - cfg.F_D0 * (cfg.T_D0 - t_c)) / self._span
        d_cold = -(f_d * (t_h - t_d) - cfg.F_D0 * (t_h - cfg.T_D0)) / self._span
        return d_hot, d_cold

    def settle(self, d: np.ndarray) -> None:
        """The delay line in steady state for the disturbance ``d`` (a take-over)."""
        self._sent.clear()
        self.level_offset = self._next_offset = 0.0
        cold = self.static(*self._measured(d))[1]
        self._sent.extend([cold] * (self._n + 1))

    def step(self, d: np.ndarray, r_t: float, r_h: float = _OP.h) -> tuple[float, float]:
        """This sample's ``(ΔF_H, ΔF_Cin)`` for ``d`` and the setpoints ``r_t`` [°C], ``r_h``
        [cm]; :attr:`level_offset` is the level excursion predicted for now (dynamic)."""
        f_d, t_d = self._measured(d)
        d_hot, d_cold = self.static(f_d, t_d)
        if self.config.mode == 'dynamic':
            self.level_offset = self._next_offset
            if not self._sent:
                self._sent.extend([d_cold] * (self._n + 1))
            self._sent.append(d_cold)
            arrived = self._sent[0]                 # sent n samples ago: entering the tank now
            cfg = self.config
            # T in the heat balance: the setpoint, kept off T_H (where F_H has no effect)
            temp = min(max(r_t, cfg.T_C), cfg.T_H - 0.01 * self._span) \
                if math.isfinite(r_t) else cfg.T_C
            d_hot = -((f_d * (t_d - temp) - cfg.F_D0 * (cfg.T_D0 - temp))
                      + arrived * (cfg.T_C - temp)) / (cfg.T_H - temp)
            self._predict_level(d_hot + arrived + f_d - cfg.F_D0, r_h)
        self.last = (d_hot, d_cold)
        return self.last

    def _predict_level(self, imbalance: float, r_h: float) -> None:
        """Advance the predicted level excursion over one sample of the mass ``imbalance``
        [cm³/s] (module docstring); the offset used now is the one before this sample's."""
        cfg = self.config
        if not (math.isfinite(r_h) and r_h > 0.0):
            return
        volume = cfg.C * r_h * r_h
        tau = 4.0 * volume / (cfg.alpha * math.sqrt(r_h))      # [s]
        decay = math.exp(-self._ts / tau)
        self._next_offset = (decay * self.level_offset
                             + (1.0 - decay) * tau / (2.0 * cfg.C * r_h) * imbalance)
