"""SOPDT plant: second order plus dead time ([Precup2013] eq. 3.5.8, [Precup2013] eq. 3.6.1 with n = 2).

Two forms of the same model ``y = y0 + G(s)·(u + v)`` (load ``v`` at the input, [Viteckova] Fig. 1):

* ``time_constants``: ``G(s) = K/((T1·s + 1)(T2·s + 1)) · e^(−L·s)``, ``T1, T2 ≥ 0``
  (overdamped, critically damped for ``T1 = T2``; a zero time constant drops that lag);
* ``damping``: ``G(s) = K/(T²·s² + 2ζ·T·s + 1) · e^(−L·s)``, ``0 ≤ ζ ≤ 1``, ``T = 1/ω_n``
  (underdamped, critically damped at ζ = 1; [Precup2013] eq. 3.5.1 writes it with ``ω_n``).

Defaults: [Ikonen]'s plant ``2/((s + 1)(0.5·s + 1))`` (K = 2, T1 = 1 s, T2 = 0.5 s, no delay;
reconstructed in [Checks] §5).
State: the delay-free output ``x`` and its rate ``ẋ`` [output units, per s], so a live
change of any parameter (the form too) keeps the output and its slope continuous.
Exact discretisation: over a piece of constant delayed input ``w`` lasting ``τ`` seconds,
``(x − K·w, ẋ)`` is multiplied by the transition matrix ``e^(A·τ)`` of
``a2·ẍ + a1·ẋ + x = K·w``, written in closed form from the poles (real: ``−1/T1``,
``−1/T2``; complex: ``(−ζ ± j·√(1 − ζ²))/T``), so the outputs at the sample instants
do not depend on the step size. Units: times in s, ``K`` in output units per input unit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tank_control.core.params import param
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)

FORMS = ('time_constants', 'damping')
"""``time_constants``: K/((T1·s+1)(T2·s+1)); ``damping``: K/(T²·s² + 2ζ·T·s + 1)."""

_BIG = 1e6
"""Largest gain / time constant accepted (as the FOPDT's)."""

State = tuple[float, float]
"""(x, ẋ): delay-free output [output units] and its rate [output units/s]."""

Transition = tuple[float, float, float, float]
"""(φ11, φ12, φ21, φ22) of ``e^(A·τ)`` acting on (x − K·w, ẋ)."""


@dataclass(frozen=True)
class SopdtConfig:
    """Parameters of ``Sopdt`` (defaults: [Ikonen]'s plant 2/((s + 1)(0.5·s + 1)), L = 0).

    ``form`` selects which parameters are in force: ``time_constant_1``,
    ``time_constant_2`` (form ``time_constants``) or ``time_constant``, ``damping``
    (form ``damping``); the others are kept and ignored until the form changes.
    """

    gain: float = param(2.0, 'static gain K', unit='output units/input unit', min=-_BIG,
                        max=_BIG, source='[Precup2013] eq. 3.5.8')
    form: str = param('time_constants', 'denominator of G: time_constants = '
                      '(T1·s + 1)(T2·s + 1), damping = T²·s² + 2ζ·T·s + 1', choices=FORMS)
    time_constant_1: float = param(1.0, 'time constant T1 (form time_constants; 0 = no lag)',
                                   unit='s', min=0.0, max=_BIG)
    time_constant_2: float = param(0.5, 'time constant T2 (form time_constants; 0 = no lag)',
                                   unit='s', min=0.0, max=_BIG)
    time_constant: float = param(1.0, 'time constant T = 1/ω_n (form damping; 0 = pure gain '
                                 'with delay)', unit='s', min=0.0, max=_BIG,
                                 source='[Precup2013] eq. 3.5.1')
    damping: float = param(0.5, 'damping ratio ζ (form damping; 0 = undamped, 1 = critical; '
                           'above 1 use form time_constants)', unit='-', min=0.0, max=1.0,
                           source='[Precup2013] eq. 3.5.1')
    dead_time: float = dead_time_param(0.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        return dead_time_reason(self)


def _psi(z: float) -> float:
    """``(1 − e^(−z))/z`` for ``z ≥ 0`` (1 at 0), accurate for small ``z``."""
    return 1.0 if z == 0.0 else -math.expm1(-z) / z


def _real_poles(slow: float, fast: float, tau: float) -> Transition:
    """``e^(A·τ)`` for the poles ``−1/slow``, ``−1/fast`` (``slow ≥ fast > 0``).

    With ``E_i = e^(−τ/T_i)`` and the divided difference
    ``s = (E_slow − E_fast)/(1/fast − 1/slow) = E_slow·τ·ψ(τ·(1/fast − 1/slow))``
    (no cancellation, also for ``T1 = T2``): φ11 = E_slow + s/slow, φ12 = s,
    φ21 = −s/(slow·fast), φ22 = E_fast − s/slow.
    """
    e_slow, e_fast = math.exp(-tau / slow), math.exp(-tau / fast)
    s = e_slow * tau * _psi(tau * (1.0 / fast - 1.0 / slow))
    return (e_slow + s / slow, s, -(s / slow) / fast, e_fast - s / slow)


def _complex_poles(t: float, zeta: float, tau: float) -> Transition:
    """``e^(A·τ)`` for the poles ``σ ± j·ω_d``, ``σ = −ζ/T``, ``ω_d = √(1 − ζ²)/T``:
    with ``c = e^(στ)·cos(ω_d τ)`` and ``s = e^(στ)·sin(ω_d τ)/ω_d``,
    φ11 = c − σ·s, φ12 = s, φ21 = −s/T², φ22 = c + σ·s."""
    sigma = -zeta / t
    omega = math.sqrt((1.0 - zeta) * (1.0 + zeta)) / t
    decay = math.exp(sigma * tau)
    c = decay * math.cos(omega * tau)
    s = decay * math.sin(omega * tau) / omega
    return (c - sigma * s, s, -(s / t) / t, c + sigma * s)


def advance(config: SopdtConfig, x: State, w: float, tau: float) -> State:
    """The state ``(x, ẋ)`` after ``tau`` seconds of constant input ``w`` (exact)."""
    target = config.gain * w
    e, rate = x[0] - target, x[1]
    if config.form == 'damping':
        t, zeta = config.time_constant, config.damping
        if t == 0.0:
            return (target, 0.0)
        phi = _real_poles(t, t, tau) if zeta == 1.0 else _complex_poles(t, zeta, tau)
    else:
        slow = max(config.time_constant_1, config.time_constant_2)
        fast = min(config.time_constant_1, config.time_constant_2)
        if slow == 0.0:                       # K·e^(−L·s)
            return (target, 0.0)
        if fast == 0.0:                       # K/(T·s + 1)·e^(−L·s): ẋ = (K·w − x)/T
            e *= math.exp(-tau / slow)
            return (target + e, -e / slow)
        phi = _real_poles(slow, fast, tau)
    return (target + phi[0] * e + phi[1] * rate, phi[2] * e + phi[3] * rate)


class Sopdt(DeadTimePlant):
    """``K/((T1·s + 1)(T2·s + 1))·e^(−L·s)`` or ``K/(T²·s² + 2ζ·T·s + 1)·e^(−L·s)`` with
    input load disturbance ([Precup2013] eq. 3.5.8, [Viteckova] Fig. 1); channels ``y``/``u``/``v``."""

    def __init__(self, config: SopdtConfig | None = None) -> None:
        super().__init__(config if config is not None else SopdtConfig())

    def reset(self) -> None:
        """Back to rest at t = 0: input history 0, y = output_offset, ẏ = 0."""
        super().reset()
        self._x = (0.0, 0.0)

    def outputs(self) -> np.ndarray:
        """``[y]`` at the current instant (noise-free)."""
        return np.array([self._config.output_offset + self._x[0]])

    @property
    def rate(self) -> float:
        """``dy/dt`` at the current instant [output units/s]."""
        return self._x[1]

    def _advance(self, x: State, w: float, duration: float) -> State:
        return advance(self._config, x, w, duration)
