"""Smith predictor with a PI primary ([Precup2013] §3.6.1, Fig. 3.6; eqs. 3.6.3–3.6.6).

The primary PI (a :class:`Pid2Dof` with ``td = 0``) acts on ``y_pred(k) = y(k) + ŷ*(k) −
ŷ_L(k)``: the internal model without and with its dead time L, exact for a zero-order-hold
input (``fopdt`` K/(T·s+1)·e^(−L·s), ``sopdt`` K/((T·s+1)(T2·s+1))·e^(−L·s) — [Precup2013] eq. 3.6.5
with n = 2 is T2 = T — or ``ipdt`` k1/s·e^(−L·s)). Times in s. Structure, the
IPDT load-offset limitation and tuning: docs/controllers.md ("smith_pi").
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from tank_control.core.scipy_lazy import expm

from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.params import param

MODELS = ('fopdt', 'ipdt', 'sopdt')


@dataclass(frozen=True)
class SmithModel:
    """The internal model ([Precup2013] eqs. 3.6.3–3.6.5): ``fopdt`` K/(T·s+1)·e^(−L·s), ``ipdt``
    k1/s·e^(−L·s) or ``sopdt`` K/((T·s+1)(T2·s+1))·e^(−L·s) ([Precup2013]'s n = 2: T2 = T)."""

    model: str = param('fopdt', 'internal model: fopdt K/(T s+1) e^(-L s), ipdt k1/s e^(-L s) or '
                       "sopdt K/((T s+1)(T2 s+1)) e^(-L s) ([Precup2013] eq. 3.6.5's n = 2: T2 = T)",
                       choices=MODELS, read_only=True, name='smith.model')
    gain: float = param(1.0, 'model gain K (ipdt: k1)', unit='y units per u unit (ipdt: per s)',
                        min=-1e9, max=1e9, name='smith.gain')
    time_constant: float = param(1.0, 'model time constant T (fopdt)', unit='s', min=1e-6,
                                 max=1e9, name='smith.time_constant')
    dead_time: float = param(0.0, 'model dead time L', unit='s', min=0.0, max=1e6,
                             name='smith.dead_time')
    time_constant2: float = param(1.0, 'second model time constant T2 (sopdt; [Precup2013] eq. 3.6.5 with '
                                  'n = 2: T2 = T)', unit='s', min=1e-6, max=1e9,
                                  name='smith.time_constant2')

    def reason(self) -> str | None:
        """One-line reason naming the invalid parameter, or None."""
        if self.model not in MODELS:
            return f'smith.model: {self.model!r} is not one of ' + ', '.join(MODELS)
        if not _finite(self.gain) or self.gain == 0.0:
            return f'smith.gain: {self.gain!r} must be a finite non-zero number'
        if not _finite(self.dead_time) or self.dead_time < 0.0:
            return f'smith.dead_time: {self.dead_time!r} is out of range; allowed [0, inf) s'
        if self.model != 'ipdt' and (not _finite(self.time_constant)
                                     or self.time_constant <= 0):
            return (f'smith.time_constant: {self.time_constant!r} is out of range; allowed '
                    f'(0, inf) s for {self.model}')
        if self.model == 'sopdt' and (not _finite(self.time_constant2)
                                      or self.time_constant2 <= 0):
            return (f'smith.time_constant2: {self.time_constant2!r} is out of range; allowed '
                    '(0, inf) s for sopdt')
        return None


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


class SmithPredictor:
    """Smith predictor + PI primary behind the Controller protocol (SISO).

    Reads ``output_name`` (default ``y``) and its setpoint, writes
    ``input_name`` (default ``u``). ``reset(y, u)`` puts the internal model in
    the steady state of a constant ``u`` and is completed at the next ``step``
    (which returns ``u``). With the ``ipdt`` model a constant input load v0 leaves a
    steady-state error k1·L·v0 (the classical structure's limitation); setpoint tracking is exact.
    """

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, model: SmithModel, primary: PidConfig, output_name: str = 'y',
                 input_name: str = 'u') -> None:
        reason = model.reason()
        if reason:
            raise ValueError(reason)
        self.model = model
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self.primary = Pid2Dof(replace(primary, td=0.0, c=0.0))
        h = primary.sample_time
        if model.dead_time / h > 1e6:
            raise ValueError(f'smith.dead_time: {model.dead_time:g} s is more than 1e6 samples')
        ratio = model.dead_time / h
        self._d = int(math.floor(ratio + 1e-9))
        self._f = max(0.0, ratio - self._d) if ratio - self._d > 1e-9 else 0.0
        self._hist: deque[float] = deque([0.0] * (self._d + 2), maxlen=self._d + 2)   # u(k−1) … u(k−d−2)
        if model.model == 'fopdt':
            t = model.time_constant
            self._a = math.exp(-h / t)
            self._c_old = math.exp(-(1 - self._f) * h / t) * (1 - math.exp(-self._f * h / t))
            self._c_new = 1 - math.exp(-(1 - self._f) * h / t)
        elif model.model == 'sopdt':
            self._ss = _sopdt_zoh(model.gain, model.time_constant, model.time_constant2, h,
                                  self._f)
            self._x_free = np.zeros(2)
            self._x_del = np.zeros(2)
        self._y_free = 0.0     # ŷ*
        self._y_del = 0.0      # ŷ_L
        self._pending: float | None = None
        self._mode_request: tuple[str, float | None] | None = None
        self._last_pred = math.nan

    @property
    def sample_time(self) -> float:
        return self.primary.config.sample_time

    def _u_ago(self, j: int) -> float:
        """u(k − j) for j ≥ 1 (the history holds the most recent first)."""
        return self._hist[j - 1]

    def _difference(self) -> float:
        """ŷ*(k) − ŷ_L(k), the prediction correction.

        ``ipdt``: only the difference is needed, and it is the exact integral of the input over
        the last L = (d + f)·h seconds, ``k1·h·(Σ_{j=1..d} u(k−j) + f·u(k−d−1))``: no
        ever-growing states.
        """
        if self.model.model == 'ipdt':
            total = sum(self._u_ago(j) for j in range(1, self._d + 1)) + self._f * self._u_ago(self._d + 1)
            return self.model.gain * self.sample_time * total
        return self._y_free - self._y_del

    def _advance(self, u: float) -> None:
        """Advance the internal model by one sample with input u(k) = u.

        ``fopdt``, exact for a ZOH input: ``ŷ*(k+1) = a·ŷ*(k) + K(1−a)·u(k)``, a = e^(−h/T).
        With ``L = (d + f)·h`` (integer d ≥ 0, 0 ≤ f < 1) the delayed input is u(k−d−1) for
        the first f·h seconds of a sample and u(k−d) for the rest, which gives exactly
        ``ŷ_L(k+1) = a·ŷ_L(k) + K·e^(−(1−f)h/T)(1 − e^(−f·h/T))·u(k−d−1)
        + K(1 − e^(−(1−f)h/T))·u(k−d)``.
        """
        if self.model.model == 'fopdt':
            k = self.model.gain
            self._y_free = self._a * self._y_free + k * (1 - self._a) * u
            u_new = u if self._d == 0 else self._u_ago(self._d)     # u(k − d)
            u_old = self._u_ago(self._d + 1)                         # u(k − d − 1)
            self._y_del = self._a * self._y_del + k * (self._c_old * u_old + self._c_new * u_new)
        elif self.model.model == 'sopdt':
            ad, g_full, g_old, g_new = self._ss
            u_new = u if self._d == 0 else self._u_ago(self._d)
            u_old = self._u_ago(self._d + 1)
            self._x_free = ad @ self._x_free + g_full * u
            self._x_del = ad @ self._x_del + g_old * u_old + g_new * u_new
            self._y_free, self._y_del = float(self._x_free[0]), float(self._x_del[0])
        self._hist.appendleft(u)

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        u0 = float(np.asarray(u, dtype=float).reshape(-1)[0])
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        limits = self.primary.config
        u0 = min(max(u0, limits.u_min), limits.u_max)   # the output the primary gives
        for _ in range(self._hist.maxlen or 0):
            self._hist.appendleft(u0)
        if self.model.model == 'fopdt':
            self._y_free = self._y_del = self.model.gain * u0
        elif self.model.model == 'sopdt':
            self._x_free = np.array([self.model.gain * u0, 0.0])
            self._x_del = self._x_free.copy()
            self._y_free = self._y_del = self.model.gain * u0
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
        st['model'] = self.model.model
        return st


def _sopdt_zoh(gain: float, t1: float, t2: float, h: float, f: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH of K/((T1·s+1)(T2·s+1)) in the state x = (y, dy/dt) (repeated poles included):
    ``(Ad, Γ(h), e^(A(1−f)h)·Γ(f·h), Γ((1−f)·h))`` with ``Γ(τ) = ∫₀^τ e^(As) ds·B``; the last
    two weigh u(k−d−1) and u(k−d) of a dead time (d + f)·h, as for the FOPDT."""
    a = np.array([[0.0, 1.0], [-1.0 / (t1 * t2), -(t1 + t2) / (t1 * t2)]])
    b = np.array([0.0, gain / (t1 * t2)])

    def gamma(tau: float) -> tuple[np.ndarray, np.ndarray]:
        m = np.zeros((3, 3))
        m[:2, :2], m[:2, 2] = a * tau, b * tau
        e = expm(m)
        return e[:2, :2], e[:2, 2]
    ad, g_full = gamma(h)
    rest, g_new = gamma((1.0 - f) * h)
    _, g_f = gamma(f * h)
    return ad, g_full, rest @ g_f, g_new


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for the SISO Smith predictor, got {arr.size}')
    return float(arr[0])
