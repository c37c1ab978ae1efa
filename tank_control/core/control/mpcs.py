"""MPCS: offset-free predictive control of the mixing tank ([Michalski2021] §4 analytic, §6 QP; [Michalski2021] §4, §6).

Outputs ``h`` [cm], ``T_out`` [°C]; inputs ``F_H``, ``F_Cin`` [cm³/s]; measured disturbances
``F_D`` [cm³/s], ``T_D`` [°C] as feed-forward; time in s (sample time 1 s in [Michalski2021]). Per sample:
Kalman correction (:mod:`mpcs_estimator`), prediction over the delayed model
(:mod:`mpcs_prediction`), the analytic move clipped to the limits or the constrained QP
(:mod:`mpcs_qp`, clipped analytic fallback), estimator time update. The algorithm and why the
defaults align T_out's horizon and weight the steady state: docs/mpcs.md ("The algorithm").
"""
from __future__ import annotations

import copy
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, TypeGuard

import numpy as np

from tank_control.core.control.mpcs_estimator import (DISTURBANCE_MODELS, EstimatorConfig,
                                                      KalmanEstimator, take_over)
from tank_control.core.control.mpcs_model import DelayedModel, equilibrium_inputs, tank_model
from tank_control.core.control.mpcs_prediction import CostConfig, Prediction
from tank_control.core.control.mpcs_qp import DenseQp
from tank_control.core.control.pid import sample_time_param
from tank_control.core.params import check_config, config_from, param, param_name
from tank_control.core.plants.mixing_tank import OPERATING_POINT, TankOperatingPoint

SOLVERS = ('analytic', 'qp')


_UNITS_IN = 'cm³/s'
_OP = OPERATING_POINT
#: Longest output dead time ``model.tau`` the estimator carries, in samples. Its delay register
#: makes the Kalman design's Riccati equation (dense) grow with the cube of it: 600 samples
#: built in 1.75 s, so 900 in about 6 s and 3600 in minutes (measured on the 2-core VM,
#: docs/mpcs.md) — a live set that long would stall the node's sampling.
MAX_OUTPUT_DELAY_SAMPLES = 900


def _m(default: Any, description: str, name: str, lo: float | None = None,
       hi: float | None = None, **meta: Any) -> Any:
    return param(default, description, name='mpcs.' + name, min=lo, max=hi, **meta)


@dataclass(frozen=True)
class MpcsConfig:
    """All settings of :class:`Mpcs`; field ``x_y`` is the parameter ``mpcs.x.y`` (``lam`` is
    ``mpcs.lambda``, ``sample_time`` the common ``sample_time``). Lists are one value for both
    inputs [F_H, F_Cin] (outputs [h, T_out]) or one per channel."""

    sample_time: float = sample_time_param(1.0, 0.01, 60.0, ' ([Michalski2021]: 1 s); the dead times must '
                                           'be multiples of it')
    horizon: int = _m(600, 'prediction horizon N [samples] ([Michalski2021]: 50…500)', 'horizon', 1, 2000)
    control_horizon: int = _m(200, 'control horizon Nu [samples], <= N ([Michalski2021]: 10…100)',
                              'control_horizon', 1, 2000)
    lam: tuple[float, ...] = _m((0.5,), 'move weight λ on ||Δu||², one value or one per input '
                                '[F_H, F_Cin] ((cm/(cm³/s))² scale; [Michalski2021]: 0.1…1)', 'lambda',
                                1e-6, 1e6)
    output_weights: tuple[float, ...] = _m((1.0, 1.0), 'output weights W_y on [h (per cm), '
                                           'T_out (per °C)], one value or one per output',
                                           'output_weights', 0.0, 1e3)
    terminal_weight: float = _m(100.0, 'weight w_∞ of the predicted steady-state error (lets a '
                                'horizon shorter than the 180 s F_Cin dead time use F_Cin; 0 = '
                                "the document's cost)", 'terminal_weight', 0.0, 1e6)
    block: int = _m(10, 'move blocking: one free move every `block` samples within Nu (1 = '
                    'every sample)', 'block', 1, 100)
    align: bool = _m(True, 'count the horizon of T_out from its 120 s dead time (predict '
                     'T_out(k+τ+p) = T(k+p)); false = literal p = 1..N', 'align')
    solver: str = _m('analytic', 'analytic = precomputed unconstrained gain, clipped; qp = '
                     'constrained QP each sample (DAQP)', 'solver', choices=SOLVERS)
    u_min: tuple[float, ...] = _m((0.0, 0.0), f'lower limits of [F_H, F_Cin] [{_UNITS_IN}]',
                                  'u_min', 0.0, 1e4)
    u_max: tuple[float, ...] = _m((100.0, 100.0), f'upper limits of [F_H, F_Cin] '
                                  f'[{_UNITS_IN}]', 'u_max', 0.0, 1e4)
    du_max: tuple[float, ...] = _m((0.2, 0.2), 'rate limits |Δu| per sample of [F_H, F_Cin] '
                                   f'[{_UNITS_IN} per sample] ([Michalski2021]: 0.2)', 'du_max', 1e-6, 1e4)
    soft_bounds: bool = _m(False, 'qp only: keep the predicted outputs within mpcs.y_min … '
                           'mpcs.y_max as soft constraints (penalised slack)', 'soft_bounds')
    y_min: tuple[float, ...] = _m((0.0, 0.0), 'soft lower bounds on predicted [h [cm], T_out '
                                  '[°C]]', 'y_min', -1e4, 1e4)
    y_max: tuple[float, ...] = _m((200.0, 100.0), 'soft upper bounds on predicted [h [cm], '
                                  'T_out [°C]]', 'y_max', -1e4, 1e4)
    soft_weight: float = _m(1e4, 'quadratic weight of the soft-bound slack', 'soft_weight', 0.0,
                            1e9)
    feedforward: bool = _m(True, 'use measured F_D, T_D in the prediction', 'feedforward')
    disturbance_model: str = _m('input', 'offset-free disturbance model: input = unknown loads '
                                'on the tank states, output = output biases',
                                'disturbance_model', choices=DISTURBANCE_MODELS)
    disturbance_noise: float = _m(1e-4, 'Kalman: variance of the disturbance random walk per '
                                  'sample, relative to a unit measurement-noise variance '
                                  '(larger = faster offset removal, more noise)',
                                  'disturbance_noise', 1e-12, 1e6)
    state_noise: float = _m(1e-4, 'Kalman: relative variance of the state noise', 'state_noise',
                            1e-12, 1e6)
    qp_iter_limit: int = _m(1000, 'QP iteration limit (beyond: fall back to the clipped analytic '
                            'move)', 'qp_iter_limit', 1, 100000)
    relinearize: bool = _m(True, 'rebuild the model at the equilibrium of the setpoint (and the '
                           'measured F_D, T_D) when it is farther than relinearize_h / '
                           "relinearize_T from the model's operating point", 'relinearize')
    relinearize_h: float = _m(5.0, 'level distance that triggers a re-linearisation [cm]',
                              'relinearize_h', 0.1, 1e3)
    relinearize_T: float = _m(1.0, 'temperature distance that triggers a re-linearisation [°C]',
                              'relinearize_T', 0.01, 100.0)
    op_F_H: float = _m(_OP.F_H, f'operating point: hot inflow [{_UNITS_IN}]', 'op.F_H', 0.0, 1e4)
    op_F_Cin: float = _m(_OP.F_C, f'operating point: cold inflow [{_UNITS_IN}]', 'op.F_Cin', 0.0,
                         1e4)
    op_F_D: float = _m(_OP.F_D, f'operating point: disturbance inflow [{_UNITS_IN}]', 'op.F_D',
                       0.0, 1e4)
    op_T_H: float = _m(_OP.T_H, 'operating point: hot water temperature [°C]', 'op.T_H', 0.0,
                       100.0)
    op_T_C: float = _m(_OP.T_C, 'operating point: cold water temperature [°C]', 'op.T_C', 0.0,
                       100.0)
    op_T_D: float = _m(_OP.T_D, 'operating point: disturbance temperature [°C]', 'op.T_D', 0.0,
                       100.0)
    model_C: float = _m(_OP.C, 'tank constant C in V = C·h² [cm]', 'model.C', 1e-3, 1e3)
    model_alpha: float = _m(_OP.alpha, 'outflow constant α in F = α·√h [cm^2.5/s]',
                            'model.alpha', 1e-3, 1e3)
    model_tau: float = _m(_OP.tau, 'output dead time on T_out [s]', 'model.tau', 0.0, 3600.0)
    model_tau_c: float = _m(_OP.tau_c, 'input dead time on F_Cin [s]', 'model.tau_c', 0.0,
                            3600.0)

    def operating_point(self) -> TankOperatingPoint:
        return TankOperatingPoint(F_H=self.op_F_H, F_C=self.op_F_Cin, F_D=self.op_F_D,
                                  T_H=self.op_T_H, T_C=self.op_T_C, T_D=self.op_T_D,
                                  C=self.model_C, alpha=self.model_alpha,
                                  tau=self.model_tau, tau_c=self.model_tau_c)

    def reason(self) -> str | None:
        """Relations between the settings (one-line reason naming the parameters), or None."""
        if self.control_horizon > self.horizon:
            return (f'mpcs.control_horizon: {self.control_horizon} must be <= mpcs.horizon '
                    f'({self.horizon})')
        for name in ('u_min', 'u_max', 'du_max', 'lam'):
            if len(getattr(self, name)) not in (1, 2):
                return f'{param_name(MpcsConfig, name)}: 1 or 2 values ([F_H, F_Cin])'
        if np.any(_two(self.u_min) >= _two(self.u_max)):
            return 'mpcs.u_min/mpcs.u_max: each lower limit must be below its upper limit'
        if len(self.y_min) != 2 or len(self.y_max) != 2 or any(
                a >= b for a, b in zip(self.y_min, self.y_max)):
            return 'mpcs.y_min/mpcs.y_max: 2 values each ([h, T_out]), min below max'
        if self.op_F_H + self.op_F_Cin + self.op_F_D <= 0.0:
            return ('mpcs.op.F_H/F_Cin/F_D: the total inflow of the operating point must be > 0 '
                    'cm³/s')
        if len(self.output_weights) not in (1, 2):
            return 'mpcs.output_weights: 1 or 2 values ([h, T_out])'
        samples = self.model_tau / self.sample_time
        if samples > MAX_OUTPUT_DELAY_SAMPLES:
            return (f'mpcs.model.tau: {self.model_tau:g} s is {samples:.0f} samples at sample_time '
                    f'{self.sample_time:g} s; the estimator carries at most '
                    f'{MAX_OUTPUT_DELAY_SAMPLES} (its design grows with the cube of it: minutes '
                    f'beyond that), so at most {MAX_OUTPUT_DELAY_SAMPLES * self.sample_time:g} s')
        return None


_ESTIMATOR_FIELDS = {'sample_time', 'disturbance_model', 'disturbance_noise', 'state_noise',
                     'op_F_H', 'op_F_Cin', 'op_F_D', 'op_T_H', 'op_T_C', 'op_T_D', 'model_C',
                     'model_alpha', 'model_tau', 'model_tau_c'}


def horizon_warning(cfg: MpcsConfig, model: DelayedModel | None = None) -> str:
    """A one-line warning when the horizons do not cover the model's dead times, else ''.

    ``model``: the prediction model in use (default: the tank at the configured
    operating point). Not a refusal: the document's own horizons ([Michalski2021] §4, §6:
    N = 50…100) are shorter on purpose and stay usable as reproductions. Two
    conditions, each named with its minimum (derivation and measurements:
    docs/mpcs.md):

    * ``mpcs.horizon``: N·Ts ≥ the longest input→output dead time the cost looks
      through (F_Cin: 180 s; 300 s to T_out without ``mpcs.align``) plus the
      model's settling, its slowest time constant ``−Ts/ln max|eig A|`` [s]
      (the level, ``4·C·h0^1.5/α`` = 292 s at h0 = 81 cm);
    * ``mpcs.control_horizon``: the last planned move, at sample
      ``(⌈Nu/block⌉ − 1)·block``, comes after the longest input dead time
      relative to the fastest input (F_Cin 180 s after F_H), so that a move of
      F_H can be planned for when the cold water arrives.
    """
    m = model or tank_model(cfg.operating_point(), cfg.sample_time)
    ts = cfg.sample_time
    offsets = m.output_delays if cfg.align else (0,) * m.n_y
    seen = max(dm + dy - off for dm in m.input_delays
               for dy, off in zip(m.output_delays, offsets))
    tau = -ts / math.log(float(np.max(np.abs(np.linalg.eigvals(m.a)))))     # [s]
    n_min = seen + math.ceil(tau / ts - 1e-9)
    spread = max(m.input_delays) - min(m.input_delays)
    slow = Mpcs.input_names[int(np.argmax(m.input_delays))] \
        if m.n_u == len(Mpcs.input_names) else f'input {int(np.argmax(m.input_delays))}'
    blk = cfg.block
    last_move = (math.ceil(cfg.control_horizon / blk) - 1) * blk
    nu_min = (spread // blk + 1) * blk + 1 if spread > 0 else 1
    parts = []
    if cfg.horizon < max(n_min, nu_min):
        parts.append(f'mpcs.horizon: {cfg.horizon} samples do not cover the longest dead time '
                     f'the cost sees ({seen * ts:g} s) plus the model\'s settling (slowest time '
                     f'constant {tau:.0f} s): at least {max(n_min, nu_min)} for weight-independent '
                     f'offset-free settling')
    if last_move <= spread:
        parts.append(f'mpcs.control_horizon: the last planned move (sample {last_move}) is '
                     f'not after the {spread * ts:g} s dead time of {slow}: at least {nu_min} '
                     f'with mpcs.block {blk}')
    return '; '.join(parts)


_FLOAT64 = np.dtype(np.float64)


def _finite(a: Any) -> bool:
    """``np.all(np.isfinite(a))``; a short float vector is checked item by item."""
    if type(a) is np.ndarray and a.dtype is _FLOAT64 and a.ndim == 1 and a.size <= 8:
        for item in a.tolist():
            if not math.isfinite(item):
                return False
        return True
    return bool(np.all(np.isfinite(a)))


def _two(values: tuple[float, ...]) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    return np.full(2, arr[0]) if arr.size == 1 else arr


class _Design:
    """Everything precomputed from a configuration (swapped atomically by ``configure``)."""

    def __init__(self, cfg: MpcsConfig, model: DelayedModel | None = None,
                 estimator: KalmanEstimator | None = None) -> None:
        self.cfg = cfg
        self.model = model or tank_model(cfg.operating_point(), cfg.sample_time)
        self.estimator = estimator or KalmanEstimator(
            self.model, EstimatorConfig(cfg.disturbance_model, cfg.disturbance_noise,
                                        cfg.state_noise))
        cost = CostConfig(cfg.horizon, cfg.control_horizon, cfg.lam, cfg.output_weights,
                          cfg.terminal_weight, cfg.block, cfg.align)
        self.pred = Prediction(self.estimator.sys, cost)
        self.warning = horizon_warning(cfg, self.model)
        m, p = self.model, self.pred
        self.u_min, self.u_max = _two(cfg.u_min) - m.u0, _two(cfg.u_max) - m.u0   # deviations
        self.du_max = _two(cfg.du_max)
        nu = m.n_u
        # simple bounds on ΔU: the first move is a one-sample move; a blocked move later
        # stands for a ramp over `block` samples
        du = np.tile(self.du_max * cfg.block, p.n_moves)
        du[:nu] = self.du_max
        self.soft = cfg.soft_bounds and cfg.solver == 'qp'
        n_dec = p.n_dec
        if self.soft:
            ny = m.n_y
            n_var = n_dec + ny
            h = np.zeros((n_var, n_var))
            h[:n_dec, :n_dec] = p.hessian
            h[n_dec:, n_dec:] = cfg.soft_weight * np.eye(ny)
            sel = np.tile(np.eye(ny), (cfg.horizon, 1))        # slack of each predicted row
            a = np.block([[p.cum, np.zeros((p.cum.shape[0], ny))],
                          [p.g, -sel], [p.g, sel]])
            self.lb = np.concatenate([-du, np.zeros(ny)])
            self.ub = np.concatenate([du, np.full(ny, np.inf)])
            y_lo = np.asarray(cfg.y_min, float) - m.y0
            y_hi = np.asarray(cfg.y_max, float) - m.y0
            self.y_lo, self.y_hi = np.tile(y_lo, cfg.horizon), np.tile(y_hi, cfg.horizon)
        else:
            h, a = p.hessian, p.cum
            self.lb, self.ub = -du, du
        self.n_var = h.shape[0]
        self.qp = DenseQp(h, a, cfg.qp_iter_limit) if cfg.solver == 'qp' else None
        # per sample: the input of every planned move (np.tile of an input vector) and the
        # limits as floats (absolute inputs, rate)
        self.move_inputs = np.tile(np.arange(nu), p.n_moves)
        self.u_low = (self.u_min + m.u0).tolist()
        self.u_high = (self.u_max + m.u0).tolist()
        self.du_high = self.du_max.tolist()
        self.y0 = m.y0.tolist()                       # the model's operating point [h, T_out]


class Mpcs:
    """The MPCS controller (``Controller`` protocol of ``core/interfaces.py``)."""

    output_names = ('h', 'T_out')
    input_names = ('F_H', 'F_Cin')
    disturbance_names = ('F_D', 'T_D')

    def __init__(self, config: MpcsConfig | None = None, model: DelayedModel | None = None
                 ) -> None:
        """``model``: a prediction model to use instead of the tank built from the config
        (e.g. from a plant's ``linearize``); it is kept across ``configure`` calls."""
        cfg = check_config(config or MpcsConfig())
        self._fixed_model = model
        self._design = _Design(cfg, model)
        self._reset_counters()
        m = self._design.model
        self._u = m.u0.copy()
        self._y = m.y0.copy()
        self._d = m.d0.copy()
        self._pending_d = True
        self._needs_init = True     # no reset(): initialise from the first measurement
        self._init_buffers(m)
        self._design.estimator.reset(np.zeros(m.n_y), np.zeros(m.n_u), np.zeros(m.n_d))

    # --- Controller protocol -------------------------------------------------------
    @property
    def config(self) -> MpcsConfig:
        return self._design.cfg

    @property
    def sample_time(self) -> float:
        return self._design.cfg.sample_time

    def reset(self, y: np.ndarray, u: np.ndarray, d: np.ndarray | None = None) -> None:
        """Bumpless start (without a call, the first ``step`` does it with the
        operating point's inputs and its measurement): delay lines filled with ``u``, estimator at the equilibrium
        that explains ``y`` with ``u`` and ``d``. Without ``d`` the equilibrium is
        recomputed with the first measured ``d`` at the next ``step`` (so a
        disturbance that is already present is not mistaken for a step in it).
        Non-finite ``y``/``u`` are replaced by the operating point (counted)."""
        m = self._design.model
        y = np.asarray(y, dtype=float)
        u = np.asarray(u, dtype=float)
        if y.shape != m.y0.shape or not _finite(y):
            self._counters['bad_measurements'] += 1
            y = m.y0
        if u.shape != m.u0.shape or not _finite(u):
            self._counters['bad_setpoints'] += 1
            u = np.clip(m.u0, self._design.u_min + m.u0, self._design.u_max + m.u0)
        self._u, self._y = u.copy(), y.copy()
        self._pending_d = d is None
        self._needs_init = False
        if self._valid_d(d, m):
            self._d = np.asarray(d, dtype=float).copy()
        else:
            self._d = m.d0.copy()
        self._init_buffers(m)
        self._design.estimator.reset(self._y - m.y0, self._u - m.u0, self._d_dev(m))

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One sample (``t`` [s]; ``y`` = [h, T_out]; ``r`` setpoints; ``d`` = [F_D, T_D]).

        A channel of ``d`` that is missing or non-finite (NaN: never measured, e.g. the
        reference does not publish it) keeps its last measured value, initially the
        operating point's ``mpcs.op.F_D`` [cm³/s] / ``mpcs.op.T_D`` [°C]: see
        :meth:`_fill_d`. The output is never NaN: a non-finite measurement skips the
        estimator correction, a non-finite setpoint holds the last input.
        """
        y = np.asarray(y, dtype=float)
        r = np.asarray(r, dtype=float)
        d = self._fill_d(d)
        if self._needs_init and y.shape == self._y.shape and _finite(y):
            self.reset(y, self._u, d)   # bumpless from the operating point's inputs
        if self._design.cfg.relinearize and self._fixed_model is None:
            self._relinearize(r, d)
        des = self._design
        m, pred, est = des.model, des.pred, des.estimator
        if self._valid_d(d, m):
            self._d = np.asarray(d, dtype=float).copy()
            if self._pending_d:         # reset(y, u) without d: equilibrium with this d
                est.reset(self._y - m.y0, self._u_eff(m) - m.u0, self._d_dev(m))
        self._pending_d = False
        d_dev = self._d_dev(m)
        if _finite(y):
            self._y = y.copy()
            est.correct(y - m.y0)
        else:
            self._counters['bad_measurements'] += 1
        u_prev = self._u
        z = pred.z_vector(est.xi, [b - m.u0[i] for i, b in enumerate(self._buffers)],
                          u_prev - m.u0, d_dev)
        if not _finite(r) or len(r) != m.n_y:
            self._counters['bad_setpoints'] += 1
            u = u_prev.copy()
        else:
            u = self._move(des, z, r - m.y0, u_prev)
        self._advance(m, est, u, d_dev)
        self._counters['samples'] += 1
        return u.copy()

    @property
    def warning(self) -> str:
        """:func:`horizon_warning` of the design in use ('' if none); controller_node logs
        each new one and shows it in ``/diagnostics``."""
        return self._design.warning

    @property
    def status(self) -> Mapping[str, Any]:
        """Scalars for diagnostics: solver, timing [ms], counters, estimator state."""
        des = self._design
        est = des.estimator
        n = des.model.n_x
        lo, hi = des.u_min + des.model.u0, des.u_max + des.model.u0     # absolute limits
        at_limit = [bool(u <= a + 1e-9 * (1 + abs(a)) or u >= b - 1e-9 * (1 + abs(b)))
                    for u, a, b in zip(self._u.tolist(), lo.tolist(), hi.tolist())]
        return {
            # the applied input at an absolute limit (u_min/u_max), as SISO 'saturated'
            'saturated': any(at_limit),
            **{f'saturated.{name}': flag for name, flag in zip(self.input_names, at_limit)},
            'solver': des.cfg.solver,
            'horizon': des.cfg.horizon,
            'control_horizon': des.cfg.control_horizon,
            'solve_time_ms': self._last_solve * 1e3,
            'solve_time_max_ms': self._max_solve * 1e3,
            'fallbacks': self._counters['fallbacks'],
            'last_exitflag': self._last_flag,
            'qp_iterations': self._last_iter,
            'active_constraints': self._last_active,
            'clipped': self._last_clipped,
            'samples': self._counters['samples'],
            'bad_measurements': self._counters['bad_measurements'],
            'bad_setpoints': self._counters['bad_setpoints'],
            'rebuilds': self._counters['rebuilds'],
            'relinearizations': self._counters['relinearizations'],
            'warning': des.warning,              # horizon_warning of the design in use, or ''
            'warnings': self._counters['warnings'],   # designs built with a warning
            'op_h': float(des.model.y0[0]),                     # [cm]
            'op_T': float(des.model.y0[1]),                     # [°C]
            # estimated disturbance: on [dh/dt·Ts, dT/dt·Ts] ('input') or [h, T_out] ('output')
            'disturbance_h': float(est.xi[n]),
            'disturbance_T': float(est.xi[n + 1]),
            'innovation_h': float(est.innovation[0]),           # [cm]
            'innovation_T_out': float(est.innovation[1]),       # [°C]
        }

    # --- runtime reconfiguration ---------------------------------------------------
    def configure(self, **changes: Any) -> MpcsConfig:
        """Apply parameter changes (``mpcs.horizon=…`` or ``horizon=…`` style keys).

        The new matrices are built before anything is swapped, so a rejected change
        leaves the controller untouched (``ValueError`` with the reason) and an accepted
        one takes effect at the next ``step`` — no sample is missed, the input continues
        from its last value. A new operating point carries the estimate over
        (:func:`mpcs_estimator.take_over`); other model/estimator changes restart
        the estimator at the equilibrium that explains the last measurement.
        """
        old = self._design
        fields_ = {f.name for f in fields(MpcsConfig)}
        cfg = config_from(MpcsConfig, {param_name(MpcsConfig, k) if k in fields_ else k: v
                                       for k, v in changes.items()}, old.cfg)
        if cfg == old.cfg:
            return cfg
        changed = {f.name for f in fields(MpcsConfig)
                   if getattr(cfg, f.name) != getattr(old.cfg, f.name)}
        if changed & _ESTIMATOR_FIELDS:
            new = _Design(cfg, self._fixed_model)
            m = new.model
            self._design = new
            self._resize_buffers(m)
            d_phys = self._d if cfg.feedforward else None
            if not (old.cfg.feedforward == cfg.feedforward
                    and take_over(old.estimator, new.estimator, self._u_eff(m), d_phys)):
                new.estimator.reset(self._y - m.y0, self._u_eff(m) - m.u0, self._d_dev(m))
        else:
            self._design = _Design(cfg, old.model, old.estimator)
        self._counters['rebuilds'] += 1
        self._counters['warnings'] += int(bool(self._design.warning))
        return cfg

    def adopt(self, other: Mpcs) -> bool:
        """Take the design of ``other`` — a copy of this controller reconfigured elsewhere
        (a live change built off the sampling path) — as :meth:`configure` would at this
        sample: the new matrices, this controller's estimate and inputs. Only when the two
        share the model and estimator settings (horizons, weights, limits, solver changed):
        else False and nothing changes."""
        new, old = other._design, self._design
        if any(getattr(new.cfg, f) != getattr(old.cfg, f) for f in _ESTIMATOR_FIELDS):
            return False
        if new.cfg == old.cfg:
            return True
        design = copy.copy(new)
        design.model, design.estimator = old.model, old.estimator
        self._design = design
        self._counters['rebuilds'] += 1
        self._counters['warnings'] += int(bool(design.warning))
        return True

    # --- internals -----------------------------------------------------------------
    def _relinearize(self, r: np.ndarray, d: np.ndarray | None) -> None:
        """Gain scheduling on the setpoint: a new operating point at the equilibrium of
        ``r`` ([Michalski2021] §4: the linearisation error grows with the distance from it)."""
        cfg, m = self._design.cfg, self._design.model
        if r.shape != m.y0.shape or not _finite(r):
            return
        (r_h, r_t), (y0_h, y0_t) = r.tolist(), self._design.y0
        if abs(r_h - y0_h) <= cfg.relinearize_h and abs(r_t - y0_t) <= cfg.relinearize_T:
            return
        f_d, t_d = (d[0], d[1]) if self._valid_d(d, m) else (cfg.op_F_D, cfg.op_T_D)
        op = replace(cfg.operating_point(), F_D=float(f_d), T_D=float(t_d))
        flows = equilibrium_inputs(op, float(r[0]), float(r[1]))
        if flows is None:
            return                                  # unreachable: keep the current model
        try:
            self.configure(op_F_H=flows[0], op_F_Cin=flows[1], op_F_D=op.F_D, op_T_D=op.T_D)
        except ValueError:
            return                                  # outside the parameter ranges
        self._counters['relinearizations'] += 1

    def _fill_d(self, d: np.ndarray | None) -> np.ndarray | None:
        """Per channel: a finite measured value, else the last one used (``self._d``,
        which starts at the operating point ``mpcs.op.F_D``, ``mpcs.op.T_D``). ``None``
        or a wrongly sized ``d`` passes unchanged (no feed-forward update)."""
        if d is None:
            return None
        d = np.asarray(d, dtype=float)
        if d.shape != self._d.shape:
            return d
        if _finite(d):
            return d.copy()
        return np.where(np.isfinite(d), d, self._d)

    def _valid_d(self, d: np.ndarray | None, m: DelayedModel) -> TypeGuard[np.ndarray]:
        return (self._design.cfg.feedforward and d is not None and len(d) == m.n_d
                and _finite(d))

    def _d_dev(self, m: DelayedModel) -> np.ndarray:
        """Measured disturbance deviation used in the model (zero without feed-forward)."""
        return self._d - m.d0 if self._design.cfg.feedforward else np.zeros(m.n_d)

    def _u_eff(self, m: DelayedModel) -> np.ndarray:
        """The inputs acting on the tank now (delayed channels from their lines)."""
        u_eff = self._u.copy()
        for i, buf in enumerate(self._buffers):
            if buf.size:
                u_eff[i] = buf[0]
        return u_eff

    def _reset_counters(self) -> None:
        self._counters = {'samples': 0, 'fallbacks': 0, 'bad_measurements': 0,
                          'bad_setpoints': 0, 'rebuilds': 0, 'relinearizations': 0,
                          'warnings': int(bool(self._design.warning))}
        self._last_solve = self._max_solve = 0.0
        self._last_flag = 0
        self._last_iter = 0
        self._last_active = 0
        self._last_clipped = False

    def _init_buffers(self, m: DelayedModel) -> None:
        self._buffers = [np.full(dm, self._u[i]) for i, dm in enumerate(m.input_delays)]

    def _resize_buffers(self, m: DelayedModel) -> None:
        new = []
        for i, dm in enumerate(m.input_delays):
            old = self._buffers[i] if i < len(self._buffers) else np.zeros(0)
            if old.size >= dm:
                new.append(old[old.size - dm:].copy())
            else:
                fill = old[0] if old.size else self._u[i]
                new.append(np.concatenate([np.full(dm - old.size, fill), old]))
        self._buffers = new

    def _move(self, des: _Design, z: np.ndarray, r_dev: np.ndarray, u_prev: np.ndarray
              ) -> np.ndarray:
        """The new input: analytic (clipped) or QP with analytic fallback."""
        pred, m = des.pred, des.model
        start = time.perf_counter()
        du_analytic = pred.k_r @ r_dev - pred.k_z @ z
        u = None
        if des.qp is not None:
            u_prev_dev = u_prev - m.u0
            f = pred.f_z @ z - pred.f_r @ r_dev
            cum_lo = (des.u_min - u_prev_dev)[des.move_inputs]       # tiled over the moves
            cum_hi = (des.u_max - u_prev_dev)[des.move_inputs]
            if des.soft:
                y_free = pred.m_z @ z
                f = np.concatenate([f, np.zeros(m.n_y)])
                lo = np.concatenate([cum_lo, np.full(y_free.size, -np.inf), des.y_lo - y_free])
                hi = np.concatenate([cum_hi, des.y_hi - y_free, np.full(y_free.size, np.inf)])
            else:
                lo, hi = cum_lo, cum_hi
            res = des.qp.solve(f, des.lb, des.ub, lo, hi)
            self._last_flag, self._last_iter, self._last_active = (res.exitflag, res.iterations,
                                                                   res.active)
            if res.x is not None:
                u = u_prev + res.x[:m.n_u]
            else:
                self._counters['fallbacks'] += 1
        if u is None or not _finite(u):
            if u is not None:
                self._counters['fallbacks'] += 1
            u = self._clip(des, u_prev, du_analytic, u_prev)
        else:
            # the QP honours the limits to its tolerance; clip the last ulp as well
            u = self._clip(des, u_prev, u - u_prev, u_prev)
        elapsed = time.perf_counter() - start
        self._last_solve = elapsed
        self._max_solve = max(self._max_solve, elapsed)
        return u

    def _clip(self, des: _Design, u_prev: np.ndarray, du: np.ndarray, fallback: np.ndarray
              ) -> np.ndarray:
        """Rate limit, then absolute limits (the absolute limits always win)."""
        if not _finite(du):
            du = np.zeros_like(du)
        # elementwise as np.clip: the rate limit, then the absolute limits
        wanted = [a + b for a, b in zip(u_prev.tolist(), du.tolist())]
        u_l = [min(max(a + min(max(b, -c), c), lo), hi) for a, b, c, lo, hi in
               zip(u_prev.tolist(), du.tolist(), des.du_high, des.u_low, des.u_high)]
        self._last_clipped = any(abs(a - b) > 1e-9 for a, b in zip(u_l, wanted))
        u = np.array(u_l)
        return u if _finite(u) else fallback

    def _advance(self, m: DelayedModel, est: KalmanEstimator, u: np.ndarray,
                 d_dev: np.ndarray) -> None:
        """Estimator time update with the inputs acting over [k, k+1); shift delay lines."""
        u_eff = u.copy()
        for i, buf in enumerate(self._buffers):
            if buf.size:
                u_eff[i] = buf[0]
                buf[:-1] = buf[1:]
                buf[-1] = u[i]
        est.predict(u_eff - m.u0, d_dev)
        self._u = u
