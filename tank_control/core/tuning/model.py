"""Process models for tuning and loop analysis: FOPDT, IPDT and SOPDT with exact dead time.

* ``fopdt``: ``K/(T·s + 1)·e^(−L·s)`` (001 eq. 6.14, 004 eq. 3.3.11);
* ``ipdt``: ``k1/s·e^(−L·s)`` (000 eq. 1; ``gain`` = k1 per second);
* ``sopdt``: ``K/((T1·s + 1)(T2·s + 1))·e^(−L·s)`` (004 eq. 3.5.8 with real poles; T2 ≤ T1).

Gains in output units per input unit (IPDT: per second), times in s. :meth:`ProcessModel.response`
gives the continuous response or, with a sample time, the exact ZOH model the implemented
discrete loop sees (``core/analysis/frequency.py``); :meth:`ProcessModel.state_space` the
same model for simulation. The gain is taken positive (a reverse-acting process is run with
``direct_action``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr

KINDS = ('fopdt', 'ipdt', 'sopdt')


@dataclass(frozen=True)
class ProcessModel:
    """``kind`` one of :data:`KINDS`; ``gain`` K (k1 for IPDT, per s), ``dead_time`` L [s],
    ``time_constant`` T or T1 [s] (FOPDT, SOPDT), ``time_constant2`` T2 [s] (SOPDT)."""

    kind: str
    gain: float
    dead_time: float
    time_constant: float = 0.0
    time_constant2: float = 0.0

    def reason(self) -> str | None:
        """One-line reason why the model is unusable, naming the parameter, or None."""
        if self.kind not in KINDS:
            return f'model: {self.kind!r} is not a model kind; allowed ' + ', '.join(KINDS)
        for name in ('gain', 'dead_time', 'time_constant', 'time_constant2'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                return f'{name}: {value!r} is not a finite number'
        if self.gain <= 0.0:
            return f'gain: {self.gain:g} must be > 0 (the magnitude of the process gain)'
        if self.dead_time < 0.0:
            return f'dead_time: {self.dead_time:g} must be >= 0'
        if self.kind in ('fopdt', 'sopdt') and self.time_constant <= 0.0:
            return f'time_constant: {self.kind} needs a time constant > 0'
        if self.kind == 'sopdt' and self.time_constant2 <= 0.0:
            return 'time_constant2: sopdt needs a second time constant > 0'
        return None

    def check(self) -> ProcessModel:
        reason = self.reason()
        if reason:
            raise ValueError(reason)
        return self

    # ----------------------------------------------------------------------------- form
    def numerator_denominator(self) -> tuple[list[float], list[float]]:
        """``num(s)``, ``den(s)`` of the delay-free part, highest power first."""
        if self.kind == 'ipdt':
            return [self.gain], [1.0, 0.0]
        if self.kind == 'fopdt':
            return [self.gain], [self.time_constant, 1.0]
        t1, t2 = self.time_constant, self.time_constant2
        return [self.gain], [t1 * t2, t1 + t2, 1.0]

    def response(self, sample_time: float | None = None) -> fr.FrequencyResponse:
        """Continuous response (``sample_time`` None) or the exact ZOH model at
        ``sample_time`` [s] (fractional dead time included)."""
        self.check()
        if not sample_time:
            if self.kind == 'ipdt':
                return fr.ipdt(self.gain, self.dead_time)
            if self.kind == 'fopdt':
                return fr.fopdt(self.gain, self.time_constant, self.dead_time)
            num, den = self.numerator_denominator()
            return fr.rational(num, den, self.dead_time)
        if self.kind == 'ipdt':
            return fr.ipdt_zoh(self.gain, self.dead_time, sample_time)
        if self.kind == 'fopdt':
            return fr.fopdt_zoh(self.gain, self.time_constant, self.dead_time, sample_time)
        num, den = self.numerator_denominator()
        return fr.rational_zoh(num, den, self.dead_time, sample_time)

    def state_space(self, sample_time: float) -> fr.ZohStateSpace:
        """The exact ZOH state-space model at ``sample_time`` [s] (for simulation)."""
        self.check()
        num, den = self.numerator_denominator()
        return fr.zoh_state_space(num, den, self.dead_time, sample_time)

    # ------------------------------------------------------------------------ features
    @property
    def lag(self) -> float:
        """The time constant of the FOPDT of the same kind: T (FOPDT), T1 + T2 (SOPDT: the sum
        of the lags, the apparent time constant of the same mean residence time), inf (IPDT)."""
        if self.kind == 'ipdt':
            return math.inf
        return self.time_constant + (self.time_constant2 if self.kind == 'sopdt' else 0.0)

    @property
    def normalised_dead_time(self) -> float:
        """``τ = L/(L + T)`` (004 eq. 3.4.6) with T = :attr:`lag`; 0 for IPDT's limit T → ∞."""
        lag = self.lag
        if math.isinf(lag):
            return 0.0
        return self.dead_time / (self.dead_time + lag)

    def ultimate_point(self) -> fr.UltimatePoint:
        """``(ku, tu, wu)`` of the continuous model (SPEC §1.2)."""
        return fr.ultimate_point(self.response())

    def describe(self) -> str:
        """``'fopdt K=0.05 T=10 s L=3 s'`` and the like."""
        if self.kind == 'ipdt':
            return f'ipdt k1={self.gain:.6g} 1/s L={self.dead_time:.6g} s'
        if self.kind == 'fopdt':
            return f'fopdt K={self.gain:.6g} T={self.time_constant:.6g} s L={self.dead_time:.6g} s'
        return (f'sopdt K={self.gain:.6g} T1={self.time_constant:.6g} s '
                f'T2={self.time_constant2:.6g} s L={self.dead_time:.6g} s')

    def as_dict(self) -> dict[str, Any]:
        return {'kind': self.kind, 'gain': self.gain, 'time_constant': self.time_constant,
                'time_constant2': self.time_constant2, 'dead_time': self.dead_time}


def from_identified(model: Any) -> ProcessModel:
    """The :class:`ProcessModel` of an identified ``FopdtModel`` (order 1 or 2) or
    ``IpdtModel`` of ``core/tuning/identification.py``."""
    if getattr(model, 'kind', None) == 'ipdt':
        return ProcessModel('ipdt', abs(float(model.gain)), float(model.dead_time))
    if getattr(model, 'order', 1) == 2:
        return ProcessModel('sopdt', abs(float(model.gain)), float(model.dead_time),
                            float(model.time_constant), float(model.time_constant))
    return ProcessModel('fopdt', abs(float(model.gain)), float(model.dead_time),
                        float(model.time_constant))


def from_plant(kind: str, config: Any) -> ProcessModel | None:
    """The model of a plant kind's configuration (``core/plants``): ``fopdt`` and ``ipdt``
    exactly, a second-order plant by its ``time_constant``/``time_constant2`` (or
    ``time_constant1``) fields; None for other plants (the mixing tank is not SISO)."""
    gain = getattr(config, 'gain', None)
    dead = getattr(config, 'dead_time', None)
    if gain is None or dead is None or gain == 0:
        return None
    if kind == 'ipdt':
        return ProcessModel('ipdt', abs(gain), dead)
    t1 = getattr(config, 'time_constant', getattr(config, 'time_constant1', None))
    t2 = getattr(config, 'time_constant2', None)
    if t1 is None or t1 <= 0:
        return None
    if t2 is not None and t2 > 0:
        return ProcessModel('sopdt', abs(gain), dead, max(t1, t2), min(t1, t2))
    return ProcessModel('fopdt', abs(gain), dead, t1)


class DiscretePlant:
    """Simulation of :class:`ProcessModel` with the exact ZOH at ``sample_time`` [s]:
    ``outputs()`` is y(k) (deviation from the rest state), ``step(u)`` holds ``u`` (the plant
    input, load disturbance included) over one sample. Equal to the project's exact plants
    (``core/plants``) sampled at the same instants."""

    def __init__(self, model: ProcessModel, sample_time: float) -> None:
        self._ss = model.state_space(sample_time)
        m = self._ss.phi.shape[0]
        self._x = np.zeros((m, 1))
        self._inputs = [0.0] * (self._ss.delay_samples + 2)   # u(k), u(k−1), …, u(k−d−1)

    def output(self) -> float:
        return float((self._ss.c @ self._x)[0, 0])

    def step(self, u: float) -> None:
        self._inputs = [float(u)] + self._inputs[:-1]
        d = self._ss.delay_samples
        self._x = (self._ss.phi @ self._x + self._ss.gamma0 * self._inputs[d]
                   + self._ss.gamma1 * self._inputs[d + 1])

