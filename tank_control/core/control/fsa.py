"""FSA (finite spectrum assignment) controller with integral action for first-order plants
with dead time, stable ``K/(T·s + 1)·e^(−L·s)`` or unstable ``K/(T·s − 1)·e^(−L·s)``
([Precup2013] §3.6.2, eqs. 3.6.10–3.6.15; Wang et al. 1995).

Principle ([Precup2013] §3.6.2): state feedback on the state *predicted* one dead time ahead removes
the dead time from the characteristic equation; the "generalised process" is the process plus
an integrator of its output ([Precup2013] eq. 3.6.10, ``a0/(s·(s + b1))``, eq. 3.6.11
``a0 = K/T``, ``b1 = ±1/T``), and its two closed-loop poles are the roots of
``p(s) = s² + 2ξ·ω0·s + ω0²`` ([Precup2013] eq. 3.6.12). With the model ``ẋ = α·x + β·u(t − L)``
(``α = −1/T`` stable, ``+1/T`` unstable, ``β = K/T``) and ``z = ∫(r(t − L) − y)``, the
continuous law ``u = −f1·x(t + L) − f2·z(t + L)`` gives ``s² + (β·f1 − α)·s − β·f2 = p(s)``:
``f1 = (2ξ·ω0 + α)/β``, ``f2 = −ω0²/β`` (our derivation; the integral gain ``ω0²·T/K`` is the
``h1`` of [Precup2013] eqs. 3.6.14–3.6.15, ``h(s) = ω0²·(1 + s·T)/K``). On the matching model the
setpoint response is ``ω0²/p(s)·e^(−L·s)`` and a constant load leaves no steady-state error.

Implementation, exact for the zero-order-hold output (sample time ``h``, ``L = (d + f)·h``,
integer ``d``, ``0 ≤ f < 1``): the model sampled exactly is
``x(k+1) = φ·x(k) + g1·u(k−d−1) + g0·u(k−d)`` with ``φ = e^(α·h)``,
``g0 = (β/α)·(e^(α(1−f)h) − 1)``, ``g1 = e^(α(1−f)h)·(β/α)·(e^(α·f·h) − 1)``. The predicted
state ``ξ(k) = x(k+d)`` and integral ``ζ(k) = z(k+d)`` are finite sums over the measured
``y(k)``, the last ``d + 1`` outputs and the last ``d`` setpoints (the discrete FSA integral
``∫_{t−L}^{t} e^(α(t−θ))·β·u(θ)dθ``, :func:`prediction_weights`); they obey the delay-free
system ``ξ(k+1) = φ·ξ + g1·u(k−1) + g0·u(k)``, ``ζ(k+1) = ζ + h·(r(k) − ξ)``, whose state
``[ξ, ζ, u(k−1)]`` is fed back with gains that place its poles at ``e^(s·h)`` for the roots
``s`` of p(s) and at 0 (:func:`design`, Ackermann's formula; the solution is checked against
the poles). The sums are evaluated afresh every sample (an FIR in the stored inputs), never
recursively: a recursive window sum, or the difference of two runs of the model as in a Smith
predictor, carries the model's pole ``φ`` inside the controller, which for an unstable plant
(``φ > 1``) lets rounding errors grow as ``e^(t/T)`` — the known instability of naive FSA
implementations. Units: times in s, ``ω0`` in rad/s, ``K`` in y units per u unit.

Behaviour users rely on (as the PID's): output limits; anti-windup of the integral
(``back_calculation`` with tracking time ``Tt``, default ``1/ω0``, ``h/Tt`` capped at 1;
``conditional_integration``; ``none``); the prediction always runs on the applied (limited)
output; ``reset(y, u)`` makes the next output ``u`` (bumpless take-over, the input history at
the steady state of ``u``); bumpless changes of ``ω0``, ``ξ`` and the limits (the integral
absorbs them); manual/auto bumpless both ways; a non-finite ``r`` or ``y`` holds the last
output (which keeps entering the prediction) and flags ``input_fault``.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.control.pid import (BIG, anti_windup_param, limits_reason,
                                           sample_time_param)
from tank_control.core.params import ConfigError, check_config, param

MODELS = ('fopdt', 'foupdt')
"""``fopdt``: K/(T·s + 1)·e^(−L·s) (stable); ``foupdt``: K/(T·s − 1)·e^(−L·s) (unstable)."""
MAX_DELAY_SAMPLES = 100_000
"""Largest ``dead_time/sample_time`` (the prediction sums that many stored inputs)."""
MAX_UNSTABLE_RATIO = 20.0
"""Largest ``L/T`` of an unstable model: the prediction multiplies y by ``e^(L/T)``."""
MAX_OMEGA_H = 1.0
"""Largest ``ω0·h``: the sampled loop needs several samples per ``1/ω0``."""
MIN_OMEGA_H = 1e-4
"""Smallest ``ω0·h``: below it the assigned poles ``e^(s·h)`` crowd 1 and the gains lose
their precision."""


@dataclass(frozen=True)
class FsaConfig:
    """Settings of :class:`FsaController` ([Precup2013] §3.6.2); every field is a parameter.

    As parameters ``tracking_time = 0`` means the default ``Tt = 1/ω0``."""

    model: str = param('fopdt', 'process model: fopdt K/(T s + 1) e^(-L s) (stable) or foupdt '
                       'K/(T s - 1) e^(-L s) (unstable)', choices=MODELS, name='fsa.model',
                       source='[Precup2013] eq. 3.6.1')
    gain: float = param(1.0, 'model gain K (a negative K for a reverse-acting process)',
                        unit='y units per u unit', min=-1e9, max=1e9, name='fsa.gain',
                        source='[Precup2013] eq. 3.6.11')
    time_constant: float = param(10.0, 'model time constant T', unit='s', min=1e-6, max=1e9,
                                 name='fsa.time_constant', source='[Precup2013] eq. 3.6.11')
    dead_time: float = param(3.0, 'model dead time L (Tm in [Precup2013])', unit='s', min=0.0, max=1e6,
                             name='fsa.dead_time', source='[Precup2013] eq. 3.6.1')
    omega0: float = param(0.2, 'closed-loop natural frequency w0 of p(s) = s^2 + 2 xi w0 s + '
                          'w0^2; [Precup2013]: 1/(xi w0) = (0.5...1) T', unit='rad/s', min=0.0,
                          max=1e6, name='fsa.omega0', source='[Precup2013] eq. 3.6.12')
    xi: float = param(0.7, 'closed-loop damping xi of p(s) (set by the allowed overshoot; [Precup2013]: '
                      '0.5...1)', unit='-', min=0.05, max=10.0, name='fsa.xi',
                      source='[Precup2013] eq. 3.6.12')
    sample_time: float = sample_time_param(0.1)
    u_min: float = param(-1e9, 'lower output limit', unit='u units', min=-BIG, max=BIG)
    u_max: float = param(1e9, 'upper output limit', unit='u units', min=-BIG, max=BIG)
    anti_windup: str = anti_windup_param()
    tracking_time: float | None = param(None, 'back-calculation tracking time Tt (0 = default '
                                        '1/w0)', unit='s', min=0.0, max=BIG, zero=None)

    def reason(self) -> str | None:
        """Relations between the fields (one line naming the parameter), or None."""
        if self.model not in MODELS:
            return f'fsa.model: {self.model!r} is not one of ' + ', '.join(MODELS)
        for name in ('gain', 'time_constant', 'dead_time', 'omega0', 'xi', 'sample_time'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                return f'{_name(name)}: {value!r} is not a finite number'
        if self.gain == 0.0:
            return 'fsa.gain: 0 leaves the process uncontrollable; allowed a non-zero K'
        if not self.time_constant > 0.0:
            return f'fsa.time_constant: {self.time_constant!r} must be > 0 s'
        if not self.omega0 > 0.0:
            return f'fsa.omega0: {self.omega0!r} must be > 0 rad/s'
        if self.omega0 * self.sample_time < MIN_OMEGA_H:
            return (f'fsa.omega0: {self.omega0:g} rad/s is too slow for sample_time '
                    f'{self.sample_time:g} s (more than {1 / MIN_OMEGA_H:g} samples per 1/w0); '
                    f'allowed w0 >= {MIN_OMEGA_H / self.sample_time:g} rad/s')
        if self.omega0 * self.sample_time > MAX_OMEGA_H:
            return (f'fsa.omega0: {self.omega0:g} rad/s is too fast for sample_time '
                    f'{self.sample_time:g} s (w0·h = {self.omega0 * self.sample_time:.3g}); '
                    f'allowed w0 <= {MAX_OMEGA_H / self.sample_time:g} rad/s')
        if self.dead_time / self.sample_time > MAX_DELAY_SAMPLES:
            return (f'fsa.dead_time: {self.dead_time:g} s is more than {MAX_DELAY_SAMPLES} '
                    f'samples of {self.sample_time:g} s; allowed '
                    f'[0, {MAX_DELAY_SAMPLES * self.sample_time:g}] s')
        if self.model == 'foupdt' and self.sample_time > self.time_constant:
            return (f'fsa.time_constant: {self.time_constant:g} s is shorter than sample_time '
                    f'{self.sample_time:g} s: the unstable pole needs several samples per T; '
                    f'allowed [{self.sample_time:g}, 1e9] s')
        if self.model == 'foupdt' and self.dead_time > MAX_UNSTABLE_RATIO * self.time_constant:
            return (f'fsa.dead_time: {self.dead_time:g} s is more than {MAX_UNSTABLE_RATIO:g} '
                    f'time constants of the unstable model (the prediction would amplify '
                    f'errors by e^(L/T) = {math.exp(self.dead_time / self.time_constant):.3g}); '
                    f'allowed [0, {MAX_UNSTABLE_RATIO * self.time_constant:g}] s')
        return limits_reason(self.u_min, self.u_max, self.anti_windup)


def _name(field_name: str) -> str:
    return field_name if field_name == 'sample_time' else 'fsa.' + field_name


# ================================================================================ design
@dataclass(frozen=True)
class FsaDesign:
    """The sampled model and the feedback of one configuration (see the module docstring).

    ``phi, g0, g1``: ``x(k+1) = φ·x(k) + g1·u(k−d−1) + g0·u(k−d)``; ``d``, ``f``: the dead
    time in samples (``L = (d + f)·h``); ``gains``: ``(F_ξ, F_ζ, F_u)`` of
    ``u(k) = −F_ξ·ξ(k) − F_ζ·ζ(k) − F_u·u(k−1)``; ``poles``: the assigned discrete poles
    ``(e^(s1·h), e^(s2·h), 0)``; ``continuous``: ``(f1, f2)`` of the continuous law."""

    phi: float
    g0: float
    g1: float
    d: int
    f: float
    gains: tuple[float, float, float]
    poles: tuple[complex, complex, complex]
    continuous: tuple[float, float]

    def matrices(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of the delay-free predicted system with state ``[ξ, ζ, u(k−1)]``."""
        a = np.array([[self.phi, 0.0, self.g1], [-h, 1.0, 0.0], [0.0, 0.0, 0.0]])
        return a, np.array([self.g0, 0.0, 1.0])


def model_poles(config: FsaConfig) -> tuple[float, float]:
    """``(α, β)`` of ``ẋ = α·x + β·u(t − L)``: ``α = −1/T`` (fopdt) or ``+1/T`` (foupdt),
    ``β = K/T`` ([Precup2013] eq. 3.6.11: ``a0 = K/T``, ``b1 = −α``)."""
    alpha = 1.0 / config.time_constant
    return (alpha if config.model == 'foupdt' else -alpha), config.gain / config.time_constant


def _zoh_gain(alpha: float, beta: float, tau: float) -> float:
    """``∫_0^τ e^(α·σ)·β dσ = (β/α)·(e^(α·τ) − 1)``."""
    return beta / alpha * math.expm1(alpha * tau)


def design(config: FsaConfig) -> FsaDesign:
    """The sampled model and the state feedback placing the poles of the predicted system at
    ``e^(s·h)`` for the roots of p(s) ([Precup2013] eq. 3.6.12) and at 0 (Ackermann's formula). The
    closed loop's eigenvalues are computed and compared with the assigned ones; a mismatch
    (ill-conditioning) raises ``ValueError`` naming ``fsa.omega0``."""
    reason = config.reason()
    if reason:
        raise ConfigError(reason)
    h, w0, xi = config.sample_time, config.omega0, config.xi
    alpha, beta = model_poles(config)
    ratio = config.dead_time / h
    d = int(math.floor(ratio + 1e-9))
    f = ratio - d if ratio - d > 1e-9 else 0.0
    phi = math.exp(alpha * h)
    g0 = _zoh_gain(alpha, beta, (1.0 - f) * h)
    g1 = math.exp(alpha * (1.0 - f) * h) * _zoh_gain(alpha, beta, f * h)
    disc = complex(xi * xi - 1.0) ** 0.5
    s1, s2 = w0 * (-xi + disc), w0 * (-xi - disc)
    z1, z2 = np.exp(s1 * h), np.exp(s2 * h)
    # desired z·(z − z1)·(z − z2) = z³ + c1·z² + c2·z
    c1, c2 = -(z1 + z2).real, (z1 * z2).real
    a = np.array([[phi, 0.0, g1], [-h, 1.0, 0.0], [0.0, 0.0, 0.0]])
    b = np.array([g0, 0.0, 1.0])
    ctrb = np.column_stack([b, a @ b, a @ a @ b])
    p_a = np.linalg.matrix_power(a, 3) + c1 * (a @ a) + c2 * a
    gains = np.linalg.solve(ctrb.T, np.array([0.0, 0.0, 1.0])) @ p_a
    poles = (complex(z1), complex(z2), 0j)
    closed = np.sort_complex(np.linalg.eigvals(a - np.outer(b, gains)))
    if not np.allclose(closed, np.sort_complex(np.array(poles)), rtol=0.0, atol=1e-6):
        raise ValueError(f'fsa.omega0: the pole placement is ill-conditioned at w0 {w0:g} rad/s, '
                         f'sample_time {h:g} s (poles {closed.tolist()})')
    continuous = ((2.0 * xi * w0 + alpha) / beta, -w0 * w0 / beta)
    return FsaDesign(phi, g0, g1, d, f, tuple(float(g) for g in gains),  # type: ignore[arg-type]
                     poles, continuous)


def prediction_weights(des: FsaDesign) -> tuple[float, np.ndarray, float, np.ndarray]:
    """``(a_y, a, b_y, b)`` of the finite sums ``ξ(k) = a_y·y(k) + a·U`` and
    ``Σ_{j=0..d−1} x̂(k+j) = b_y·y(k) + b·U``, ``U = [u(k−1), …, u(k−d−1)]``: the sampled
    model iterated over the dead time, ``a_i = g0·φ^i [i < d] + g1·φ^(i−1) [i ≥ 1]``,
    ``b_i = g0·S_i [i < d] + g1·S_(i−1) [i ≥ 1]``, ``S_n = Σ_{j<n} φ^j``."""
    d, phi, g0, g1 = des.d, des.phi, des.g0, des.g1
    powers = phi ** np.arange(d + 1, dtype=float)               # φ^0 … φ^d
    partial = np.concatenate([[0.0], np.cumsum(powers)])        # S_0 … S_(d+1)
    a, b = np.zeros(d + 1), np.zeros(d + 1)
    a[:d] += g0 * powers[:d]
    a[1:] += g1 * powers[:d]
    b[:d] += g0 * partial[:d]
    b[1:] += g1 * partial[:d]
    return float(powers[d]), a, float(partial[d]), b


def transfer_polynomials(config: FsaConfig) -> tuple[tuple[np.ndarray, np.ndarray],
                                                     tuple[np.ndarray, np.ndarray]]:
    """``((num, den), (num_r, den))`` in z, highest power first, of the implemented law in
    its linear range: ``C(z) = −U/Y`` and ``U/R``. With ``A(z) = Σ a_i·z^(−i−1)``,
    ``B(z) = Σ b_i·z^(−i−1)`` (:func:`prediction_weights`), the integral
    ``z(k) = h·Σ_{j<k} (r(j−d) − y(j))`` and the stored setpoints, ``ζ`` carries
    ``h/(z − 1)·(R − Y) − h·(b_y·Y + B·U)`` and the law
    ``u = −F_ξ·(a_y·Y + A·U) − F_ζ·ζ − F_u·z^(−1)·U`` gives
    ``C = (F_ξ·a_y − F_ζ·h·b_y − F_ζ·h/(z − 1))/D``, ``U/R = −F_ζ·h/(z − 1)/D``,
    ``D = 1 + F_ξ·A − F_ζ·h·B + F_u·z^(−1)``; both are multiplied by ``z^(d+1)·(z − 1)``."""
    des = design(config)
    h = config.sample_time
    f_xi, f_zeta, f_u = des.gains
    a_y, a, b_y, b = prediction_weights(des)
    d = des.d
    dpoly = np.zeros(d + 2)
    dpoly[0] = 1.0
    dpoly[1:] += f_xi * a - f_zeta * h * b
    dpoly[1] += f_u
    den = np.convolve(dpoly, [1.0, -1.0])
    k = f_xi * a_y - f_zeta * h * b_y
    shift = np.zeros(d + 2)
    shift[0] = 1.0                                            # z^(d+1)
    num = np.convolve([k, -k - f_zeta * h], shift)
    num_r = -f_zeta * h * shift
    return (num, den), (num_r, den)


# ============================================================================ controller
class FsaController:
    """The FSA law behind the Controller protocol (SISO; see the module docstring).

    Reads ``output_name`` (default ``y``) and its setpoint, writes ``input_name`` (default
    ``u``). ``step`` once per sample (every ``sample_time`` seconds)."""

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, config: FsaConfig, output_name: str = 'y', input_name: str = 'u') -> None:
        check_config(config)
        self._cfg = config
        self._des = design(config)
        self._a_y, self._a, self._b_y, self._b = prediction_weights(self._des)
        d = self._des.d
        self._u_hist: deque[float] = deque([0.0] * (d + 1), maxlen=d + 1)   # u(k−1) … u(k−d−1)
        self._r_hist: deque[float] = deque([0.0] * d, maxlen=d) if d else deque(maxlen=0)
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._z = 0.0                       # ∫(r(t−L) − y) dt [y units·s]
        self._u: float | None = None        # last applied output
        self._v = 0.0                       # last unlimited output
        self._takeover = True               # fill the setpoint history at the next step
        self._track: float | None = 0.0     # make the next output this (integral re-tracked)
        self._retune_from: tuple[float, float, float] | None = None
        self._mode = 'auto'
        self._manual_u: float | None = None
        self._last_r = math.nan
        self._xi_pred = math.nan
        self._zeta = math.nan
        self._fault = self._saturated = self._aw_active = False

    # ----------------------------------------------------------------- state
    @property
    def sample_time(self) -> float:
        return self._cfg.sample_time

    @property
    def config(self) -> FsaConfig:
        return self._cfg

    @property
    def design(self) -> FsaDesign:
        return self._des

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def status(self) -> Mapping[str, Any]:
        """mode, saturated, anti_windup_active, input_fault, ``prediction`` (ξ: the output
        predicted one dead time ahead), ``integral`` (z), unlimited ``v`` and applied ``u``."""
        return {'mode': self._mode, 'saturated': self._saturated,
                'anti_windup_active': self._aw_active, 'input_fault': self._fault,
                'prediction': self._xi_pred, 'integral': self._z, 'v': self._v,
                'u': math.nan if self._u is None else self._u}

    def _clip(self, u: float) -> float:
        return min(max(u, self._cfg.u_min), self._cfg.u_max)

    def _hold(self) -> float:
        return self._u if self._u is not None else self._clip(0.0)

    # --------------------------------------------------------------- the law
    def _predict(self, y: float, r_delayed_sum: float) -> tuple[float, float, float]:
        """``(ξ, ζ − z, u(k−1))``: the predicted output, the predicted part of the integral
        and the last output, as finite sums over the stored history (never recursive)."""
        u = np.fromiter(self._u_hist, dtype=float, count=len(self._u_hist))
        xi = self._a_y * y + float(self._a @ u)
        h = self._cfg.sample_time
        ahead = h * r_delayed_sum - h * (self._b_y * y + float(self._b @ u))
        return xi, ahead, self._u_hist[0]

    @staticmethod
    def _law(gains: tuple[float, float, float], xi: float, zeta: float, u_prev: float) -> float:
        return -gains[0] * xi - gains[1] * zeta - gains[2] * u_prev

    def _z_for(self, u: float, xi: float, ahead: float, u_prev: float) -> float:
        """The integral z that makes the law's output ``u`` at this sample."""
        f_xi, f_zeta, f_u = self._des.gains
        return (u + f_xi * xi + f_u * u_prev) / -f_zeta - ahead

    def _advance(self, u: float, r: float) -> None:
        self._u_hist.appendleft(u)
        if self._r_hist.maxlen:
            self._r_hist.appendleft(r)

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Take over bumplessly: the input history at the steady state of ``u`` (limited), and
        at the next step the setpoint history at that step's ``r`` and the integral set so
        that the step returns ``u``."""
        u0 = _scalar(u, 'u')
        _scalar(y, 'y')
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        u0 = self._clip(u0)
        for _ in range(self._u_hist.maxlen or 0):
            self._u_hist.appendleft(u0)
        self._takeover, self._track = True, u0
        self._fault = False

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        y0, r0 = _scalar(y, 'y'), _scalar(r, 'r')
        if not (math.isfinite(y0) and math.isfinite(r0)):
            self._fault = True
            u = self._hold()
            self._advance(u, self._last_r if math.isfinite(self._last_r) else 0.0)
            return np.array([u])
        if self._takeover:                             # the setpoint has been r
            for _ in range(self._r_hist.maxlen or 0):
                self._r_hist.appendleft(r0)
            self._takeover = False
        elif self._fault and self._track is None:      # recovery: continue from the held output
            self._track = self._hold()
        self._fault = False
        r_sum = sum(self._r_hist)
        r_delayed = self._r_hist[-1] if self._r_hist.maxlen else r0      # r(k − d)
        xi, ahead, u_prev = self._predict(y0, r_sum)
        fixed = self._track                            # this sample's output, exactly
        if fixed is None and self._retune_from is not None:   # what the old gains give
            fixed = self._law(self._retune_from, xi, self._z + ahead, u_prev)
        if fixed is not None:
            self._z = self._z_for(fixed, xi, ahead, u_prev)
            self._track = self._retune_from = None
        if self._mode == 'manual':
            target = self._manual_u if self._manual_u is not None else self._hold()
            u = v = self._clip(target)
            self._saturated, self._aw_active = u != target, False
        else:
            v = (self._law(self._des.gains, xi, self._z + ahead, u_prev) if fixed is None
                 else fixed)
            u = self._clip(v)
            self._integrate(r_delayed - y0, u, v)
            self._saturated = u != v
        self._xi_pred, self._zeta = xi, self._z + ahead
        self._v, self._u, self._last_r = v, u, r0
        self._advance(u, r0)
        return np.array([u])

    def _integrate(self, e: float, u: float, v: float) -> None:
        """``z ← z + h·e`` with anti-windup: back-calculation ``+ min(h/Tt, 1)·(u − v)/k_z``
        (``k_z = −F_ζ``, the output's gain on z: ``h/Tt = 1`` makes the unlimited output
        equal the applied one), conditional integration, or none."""
        cfg = self._cfg
        h = cfg.sample_time
        k_z = -self._des.gains[1]
        dz = h * e
        self._aw_active = False
        if cfg.anti_windup == 'back_calculation':
            tt = cfg.tracking_time or 1.0 / cfg.omega0
            self._z += dz + min(h / tt, 1.0) * (u - v) / k_z
            self._aw_active = u != v
        elif cfg.anti_windup == 'conditional_integration':
            if (v > u and k_z * dz > 0.0) or (v < u and k_z * dz < 0.0):
                self._aw_active = True
            else:
                self._z += dz
        else:
            self._z += dz

    # ------------------------------------------------------ operator actions
    def set_gains(self, **changes: Any) -> None:
        """Change ``omega0``, ``xi``, the limits or the anti-windup (by field name) bumplessly:
        at unchanged inputs the next output is the one the old settings would give. A model
        change needs a new controller. ``ValueError`` naming the parameter leaves it
        untouched."""
        allowed = ('omega0', 'xi', 'u_min', 'u_max', 'anti_windup', 'tracking_time')
        for name in changes:
            if name not in allowed:
                raise ValueError(f'{name}: not changeable on a running FSA controller; allowed '
                                 + ', '.join(allowed))
        new = check_config(replace(self._cfg, **changes))
        des = design(new)
        if self._retune_from is None and self._u is not None:
            self._retune_from = self._des.gains
        self._cfg, self._des = new, des

    def set_manual(self, u: float | None = None) -> None:
        """Manual output ``u`` (None: hold the last output) from the next step; the prediction
        keeps running on it and the integral tracks it."""
        if u is not None and not math.isfinite(u):
            raise ValueError(f'manual_output: {u!r} is not finite')
        self._manual_u = self._hold() if u is None else float(u)
        self._mode = 'manual'

    def set_auto(self) -> None:
        """Back to automatic; the next output continues from the last one."""
        if self._mode == 'manual' and self._u is not None:
            self._track = self._u
        self._mode = 'auto'


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for the SISO FSA controller, got {arr.size}')
    return float(arr[0])
