"""Smith predictor with a PI primary (004 §3.6.1, Fig. 3.6; SPEC §2.6).

The primary PI (a :class:`Pid2Dof` with ``td = 0``) is designed for the
delay-free model ``Hp*(s)`` and acts on the predicted measurement::

    y_pred(k) = y(k) + ŷ*(k) − ŷ_L(k)

where ``ŷ*`` is the internal model without dead time and ``ŷ_L`` the same
model with the dead time ``L`` (004 eqs. 3.6.3–3.6.4). With a perfect model
``y = ŷ_L`` and the primary sees the undelayed ``ŷ*``: the dead time leaves
the loop (004 eq. 3.6.6).

Internal models (exact for a zero-order-hold input, sample time h):

* ``fopdt``: K/(T·s + 1)·e^(−L·s). ŷ*(k+1) = a·ŷ*(k) + K(1−a)·u(k), a = e^(−h/T).
  ``L = (d + f)·h`` with integer d ≥ 0 and 0 ≤ f < 1; during a sample period
  the delayed input is u(k−d−1) for the first f·h seconds and u(k−d) for the
  rest, which gives exactly
  ŷ_L(k+1) = a·ŷ_L(k) + K·e^(−(1−f)h/T)(1 − e^(−f·h/T))·u(k−d−1) + K(1 − e^(−(1−f)h/T))·u(k−d).
* ``ipdt``: k1/s·e^(−L·s). Only the difference is needed, and it is the
  exact integral of the input over the last L seconds:
  ŷ* − ŷ_L = k1·h·(Σ_{j=1..d} u(k−j) + f·u(k−d−1)); no ever-growing states.

Known limitation (IPDT): the classical Smith predictor with an integrating
model leaves a steady-state error k1·L·v0 after a constant input load v0
(the prediction assumes the constant compensating input still drives the
output); setpoint tracking is exact. Use the 2-DOF PID (MDP tuning) when
load rejection matters.

The PI primary for the FOPDT model comes from ``tune('smith_pi', 'pi', ...)``
(004 eqs. 3.6.7, 3.6.9).
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.control.pid import Pid2Dof, PidConfig, limit_relations_reason, pid_params
from tank_control.core.params import ParamSpec

MODELS = ('fopdt', 'ipdt')


@dataclass
class SmithConfig:
    """Internal model (gain [y/u units, 1/s for ipdt], time_constant [s], dead_time [s])
    and the PI primary (kp, ti [s], setpoint weight b, limits, anti-windup)."""

    model: str
    gain: float
    dead_time: float
    kp: float
    ti: float
    time_constant: float | None = None
    b: float = 1.0
    sample_time: float = 1.0
    u_min: float = -math.inf
    u_max: float = math.inf
    du_max: float = math.inf
    anti_windup: str = 'back_calculation'
    tracking_time: float | None = None


def config_reason(cfg: SmithConfig) -> str | None:
    """One-line reason naming the invalid setting, or None."""
    if cfg.model not in MODELS:
        return f'model: {cfg.model!r} is not one of ' + ', '.join(MODELS)
    if not _finite(cfg.gain) or cfg.gain == 0.0:
        return f'gain: {cfg.gain!r} must be a finite non-zero number'
    if not _finite(cfg.dead_time) or cfg.dead_time < 0.0:
        return f'dead_time: {cfg.dead_time!r} is out of range; allowed [0, inf) s'
    if cfg.model == 'fopdt':
        if cfg.time_constant is None or not _finite(cfg.time_constant) or cfg.time_constant <= 0:
            return f'time_constant: {cfg.time_constant!r} is out of range; allowed (0, inf) s for fopdt'
    if not _finite(cfg.sample_time) or cfg.sample_time <= 0.0:
        return f'sample_time: {cfg.sample_time!r} is out of range; allowed (0, inf) s'
    if cfg.dead_time / cfg.sample_time > 1e6:
        return f'dead_time: {cfg.dead_time:g} s is more than 1e6 samples'
    return None


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


class SmithPredictor:
    """Smith predictor + PI primary behind the Controller protocol (SISO).

    Reads ``output_name`` (default ``y``) and its setpoint, writes
    ``input_name`` (default ``u``). ``reset(y, u)`` puts the internal model in
    the steady state of a constant ``u`` and is completed at the next ``step``
    (which returns ``u``).
    """

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, config: SmithConfig, output_name: str = 'y', input_name: str = 'u') -> None:
        reason = config_reason(config)
        if reason:
            raise ValueError(reason)
        self.config = config
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self.primary = Pid2Dof(PidConfig(
            kp=config.kp, ti=config.ti, td=0.0, b=config.b, c=0.0, sample_time=config.sample_time,
            u_min=config.u_min, u_max=config.u_max, du_max=config.du_max,
            anti_windup=config.anti_windup, tracking_time=config.tracking_time))
        h = config.sample_time
        ratio = config.dead_time / h
        self._d = int(math.floor(ratio + 1e-9))
        self._f = max(0.0, ratio - self._d) if ratio - self._d > 1e-9 else 0.0
        self._hist: deque[float] = deque([0.0] * (self._d + 2), maxlen=self._d + 2)   # u(k−1) … u(k−d−2)
        if config.model == 'fopdt':
            t = config.time_constant
            self._a = math.exp(-h / t)
            self._c_old = math.exp(-(1 - self._f) * h / t) * (1 - math.exp(-self._f * h / t))
            self._c_new = 1 - math.exp(-(1 - self._f) * h / t)
        self._y_free = 0.0     # ŷ*
        self._y_del = 0.0      # ŷ_L
        self._pending: float | None = None
        self._mode_request: tuple[str, float | None] | None = None
        self._last_pred = math.nan

    @property
    def sample_time(self) -> float:
        return self.config.sample_time

    def _u_ago(self, j: int) -> float:
        """u(k − j) for j ≥ 1 (the history holds the most recent first)."""
        return self._hist[j - 1]

    def _difference(self) -> float:
        """ŷ*(k) − ŷ_L(k), the prediction correction."""
        if self.config.model == 'ipdt':
            total = sum(self._u_ago(j) for j in range(1, self._d + 1)) + self._f * self._u_ago(self._d + 1)
            return self.config.gain * self.config.sample_time * total
        return self._y_free - self._y_del

    def _advance(self, u: float) -> None:
        """Advance the internal model by one sample with input u(k) = u."""
        if self.config.model == 'fopdt':
            k = self.config.gain
            self._y_free = self._a * self._y_free + k * (1 - self._a) * u
            u_new = u if self._d == 0 else self._u_ago(self._d)     # u(k − d)
            u_old = self._u_ago(self._d + 1)                         # u(k − d − 1)
            self._y_del = self._a * self._y_del + k * (self._c_old * u_old + self._c_new * u_new)
        self._hist.appendleft(u)

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        u0 = float(np.asarray(u, dtype=float).reshape(-1)[0])
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        u0 = min(max(u0, self.config.u_min), self.config.u_max)   # the output the primary gives
        for _ in range(self._hist.maxlen):
            self._hist.appendleft(u0)
        if self.config.model == 'fopdt':
            self._y_free = self._y_del = self.config.gain * u0
        self._pending = u0

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        y0 = _scalar(y, 'y')
        r0 = _scalar(r, 'r')
        if not (math.isfinite(y0) and math.isfinite(r0)):
            u = self.primary.update(r0, y0)        # holds and flags input_fault
            return np.array([u])
        y_pred = y0 + self._difference()
        if self._pending is not None:
            self.primary.reset(r0, y_pred, self._pending)
            self._pending = None
        self._apply_mode()
        u = self.primary.update(r0, y_pred)
        self._last_pred = y_pred
        self._advance(u)
        return np.array([u])

    def set_manual(self, u: float | None = None) -> None:
        """Manual output ``u`` (None: hold the last output); takes effect at the next step,
        also right after ``reset`` (the internal model keeps running on the manual output)."""
        if u is not None and not math.isfinite(u):
            raise ValueError(f'manual_output: {u!r} is not finite')
        self._mode_request = ('manual', u)

    def set_auto(self) -> None:
        """Back to automatic, bumplessly (the primary continues from the last output)."""
        self._mode_request = ('auto', None)

    def _apply_mode(self) -> None:
        if self._mode_request is None:
            return
        mode, u = self._mode_request
        self._mode_request = None
        if mode == 'manual':
            self.primary.set_manual(u)
        else:
            self.primary.set_auto()

    @property
    def status(self) -> Mapping[str, Any]:
        st = dict(self.primary.status)
        st['prediction'] = self._last_pred
        st['model'] = self.config.model
        return st


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for the SISO Smith predictor, got {arr.size}')
    return float(arr[0])


_PRIMARY_NAMES = ('sample_time', 'kp', 'ti', 'b', 'u_min', 'u_max', 'du_max', 'anti_windup',
                  'tracking_time', 'mode', 'manual_output', 'fail_safe', 'fail_safe_output',
                  'tuning.te', 'tuning.xi', 'tuning.order')


def smith_params() -> tuple[ParamSpec, ...]:
    """ParamSpecs: the PI primary (same names as the PID's) and the internal model ``smith.*``.

    With ``tuning.rule = smith_pi`` the primary's kp, ti come from 004 eqs.
    3.6.7/3.6.9 using smith.gain and smith.time_constant (fopdt only).
    """
    primary = tuple(s for s in pid_params() if s.name in _PRIMARY_NAMES)
    return primary + (
        ParamSpec('tuning.rule', 'none', 'none: kp, ti by hand; smith_pi: from the model '
                  '(004 eqs. 3.6.7 with tuning.te, 3.6.9 with tuning.xi)', choices=('none', 'smith_pi')),
        ParamSpec('smith.model', 'fopdt', 'internal model: fopdt K/(T s+1) e^(-L s) or ipdt k1/s e^(-L s)',
                  choices=MODELS, read_only=True),
        ParamSpec('smith.gain', 1.0, 'model gain K [y/u units] (ipdt: k1 [1/s])', min=-1e9, max=1e9),
        ParamSpec('smith.time_constant', 1.0, 'model time constant T [s] (fopdt)', min=1e-6, max=1e9),
        ParamSpec('smith.dead_time', 0.0, 'model dead time L [s]', min=0.0, max=1e6),
    )


def smith_config_from_params(values: Mapping[str, Any]) -> SmithConfig:
    """SmithConfig from parameter values (defaults for missing names); ValueError if invalid."""
    merged = {spec.name: spec.default for spec in smith_params()}
    merged.update(values)
    kp, ti = float(merged['kp']), float(merged['ti'])
    rule = merged['tuning.rule']
    if rule == 'smith_pi':
        from tank_control.core.tuning.rules import tune
        order = int(merged['tuning.order'])
        extra = {'te': float(merged['tuning.te'])} if order == 1 else {'xi': float(merged['tuning.xi'])}
        extra = {k: v for k, v in extra.items() if v > 0}
        g = tune('smith_pi', 'pi', gain=float(merged['smith.gain']),
                 time_constant=float(merged['smith.time_constant']), n=order, **extra)
        kp, ti = g['kp'], g['ti']
    elif rule != 'none':
        raise ValueError(f"tuning.rule: {rule!r} does not apply to the Smith predictor; allowed none, smith_pi")
    cfg = SmithConfig(
        model=str(merged['smith.model']), gain=float(merged['smith.gain']),
        dead_time=float(merged['smith.dead_time']), time_constant=float(merged['smith.time_constant']),
        kp=kp, ti=ti if ti > 0 else math.inf, b=float(merged['b']),
        sample_time=float(merged['sample_time']),
        u_min=float(merged['u_min']), u_max=float(merged['u_max']),
        du_max=float(merged['du_max']) if merged['du_max'] > 0 else math.inf,
        anti_windup=str(merged['anti_windup']),
        tracking_time=float(merged['tracking_time']) if merged['tracking_time'] > 0 else None)
    reason = config_reason(cfg)
    if reason:
        raise ValueError(reason)
    SmithPredictor(cfg)        # validates the primary as well
    return cfg


def check_smith_relations(values: Mapping[str, Any]) -> str | None:
    """Cross-parameter checks (u_min < u_max, kp > 0, outputs within limits, model
    complete, a tuning rule with what it needs): a one-line reason or None."""
    merged = {spec.name: spec.default for spec in smith_params()}
    merged.update(values)
    reason = limit_relations_reason(merged)
    if reason:
        return reason
    try:
        smith_config_from_params(merged)
    except ValueError as exc:
        return str(exc)
    return None
