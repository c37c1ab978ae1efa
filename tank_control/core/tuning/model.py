"""Process models for tuning and loop analysis: FOPDT, IPDT and SOPDT with exact dead time.

* ``fopdt``: ``K/(T·s + 1)·e^(−L·s)`` ([DeadTimeNotes] eq. 6.14, [Precup2013] eq. 3.3.11);
* ``ipdt``: ``k1/s·e^(−L·s)`` ([Viteckova] eq. 1; ``gain`` = k1 per second);
* ``sopdt``: ``K/((T1·s + 1)(T2·s + 1))·e^(−L·s)`` ([Precup2013] eq. 3.5.8 with real poles; T2 ≤ T1).

Gains in output units per input unit (IPDT: per second), times in s, frequencies in rad/s.
:meth:`ProcessModel.response` gives the continuous response or, with a sample time, the exact
ZOH model the implemented discrete loop sees (``core/analysis/frequency.py``);
:meth:`ProcessModel.magnitude` / :meth:`ProcessModel.phase` the continuous response in closed
form; :meth:`ProcessModel.plant` the project's plant of the model (``core/plants``), which
:class:`DiscretePlant` samples for simulation. The gain is taken positive (a reverse-acting
process is run with ``direct_action``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tank_control.core.analysis import frequency as fr
from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
from tank_control.core.plants.ipdt import Ipdt, IpdtConfig
from tank_control.core.plants.siso import DeadTimePlant
from tank_control.core.plants.sopdt import Sopdt, SopdtConfig

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

    def plant(self) -> DeadTimePlant:
        """The project's exact plant of this model at rest (``core/plants``: ``Fopdt``,
        ``Ipdt``, ``Sopdt``), its input history long enough for the dead time."""
        self.check()
        common = {'gain': self.gain, 'dead_time': self.dead_time,
                  'max_dead_time': max(self.dead_time, 100.0)}
        if self.kind == 'ipdt':
            return Ipdt(IpdtConfig(**common))
        if self.kind == 'fopdt':
            return Fopdt(FopdtConfig(time_constant=self.time_constant, **common))
        return Sopdt(SopdtConfig(form='time_constants', time_constant_1=self.time_constant,
                                 time_constant_2=self.time_constant2, **common))

    # --------------------------------------------------------- closed-form response
    @property
    def lags(self) -> tuple[float, ...]:
        """The time constants of the delay-free part: () IPDT, (T,) FOPDT, (T1, T2) SOPDT."""
        return {'ipdt': (), 'fopdt': (self.time_constant,),
                'sopdt': (self.time_constant, self.time_constant2)}[self.kind]

    @property
    def static_gain(self) -> float:
        """G(0): K, or inf for IPDT."""
        return math.inf if self.kind == 'ipdt' else self.gain

    def magnitude(self, w: float) -> float:
        """``|G(jω)|`` at ``w`` > 0 [rad/s] (the dead time leaves it unchanged)."""
        m = self.gain / w if self.kind == 'ipdt' else self.gain
        for lag in self.lags:
            m /= math.sqrt(1.0 + (w * lag) ** 2)
        return m

    def phase(self, w: float) -> float:
        """Continuous phase of ``G(jω)`` [rad] from its ω → 0+ limit (0, or −π/2 for IPDT),
        the exact dead time's −ω·L included ([DeadTimeNotes] eq. 6.4)."""
        p = -math.pi / 2 if self.kind == 'ipdt' else 0.0
        return p - sum(math.atan(w * lag) for lag in self.lags) - w * self.dead_time

    def corners(self) -> list[float]:
        """The corner frequencies [rad/s]: 1/T of each lag and 1/L; [gain] when there are
        none (an IPDT without dead time), to anchor a frequency grid."""
        out = [1.0 / t for t in (*self.lags, self.dead_time) if t > 0.0]
        return out or [self.gain]

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
        """``τ = L/(L + T)`` ([Precup2013] eq. 3.4.6) with T = :attr:`lag`; 0 for IPDT's limit T → ∞."""
        lag = self.lag
        if math.isinf(lag):
            return 0.0
        return self.dead_time / (self.dead_time + lag)

    def ultimate_point(self) -> fr.UltimatePoint:
        """``(ku, tu, wu)`` of the continuous model ([Checks] §1)."""
        return fr.ultimate_point(self.response())

    def describe(self) -> str:
        """``'fopdt K=0.05 T=10 s L=3 s'`` and the like."""
        if self.kind == 'ipdt':
            return f'ipdt k1={self.gain:.6g} 1/s L={self.dead_time:.6g} s'
        if self.kind == 'fopdt':
            return f'fopdt K={self.gain:.6g} T={self.time_constant:.6g} s L={self.dead_time:.6g} s'
        return (f'sopdt K={self.gain:.6g} T1={self.time_constant:.6g} s '
                f'T2={self.time_constant2:.6g} s L={self.dead_time:.6g} s')

    def tune_arguments(self) -> dict[str, Any]:
        """The process arguments of ``tune`` (``core/tuning/rules.py``) for this model."""
        args: dict[str, Any] = {'model': self.kind, 'gain': self.gain,
                                'dead_time': self.dead_time}
        for name, lag in zip(('time_constant', 'time_constant2'), self.lags):
            args[name] = lag
        return args

    def as_dict(self) -> dict[str, Any]:
        return {'kind': self.kind, 'gain': self.gain, 'time_constant': self.time_constant,
                'time_constant2': self.time_constant2, 'dead_time': self.dead_time}


def from_identified(model: Any) -> ProcessModel:
    """The :class:`ProcessModel` of an identified ``FopdtModel`` (order 1 or 2), ``IpdtModel``
    or ``SopdtModel`` (real poles; ζ in [0.98, 1) is taken as the double lag √(a/c), below
    ValueError; T2 < 0.1 % of T1 is an FOPDT) of ``core/tuning/identification.py``."""
    if getattr(model, 'kind', None) == 'ipdt':
        return ProcessModel('ipdt', abs(float(model.gain)), float(model.dead_time))
    if getattr(model, 'kind', None) == 'sopdt':
        if not model.damping >= 0.98:
            raise ValueError(f'model: the SOPDT through the two points is underdamped (ζ = '
                             f'{model.damping:.3g}); the tuning rules take real lags only')
        if model.damping < 1.0:    # measurement error puts a double lag on either side of ζ = 1
            t1 = t2 = math.sqrt(model.a / model.c)
        else:
            t1, t2 = float(model.time_constant), float(model.time_constant2)
        if t2 < 1e-3 * t1:                    # a ≈ 0: the points are those of a first order
            return ProcessModel('fopdt', abs(float(model.gain)), float(model.dead_time), t1)
        return ProcessModel('sopdt', abs(float(model.gain)), float(model.dead_time), t1, t2)
    if getattr(model, 'order', 1) == 2:
        return ProcessModel('sopdt', abs(float(model.gain)), float(model.dead_time),
                            float(model.time_constant), float(model.time_constant))
    return ProcessModel('fopdt', abs(float(model.gain)), float(model.dead_time),
                        float(model.time_constant))


class DiscretePlant:
    """:meth:`ProcessModel.plant` sampled every ``sample_time`` [s]: ``output()`` is y(k)
    (deviation from the rest state), ``step(u)`` holds ``u`` (the plant input, load
    disturbance included) over one sample — the exact ZOH model of the loop's analysis."""

    def __init__(self, model: ProcessModel, sample_time: float) -> None:
        self._plant = model.plant()
        self._h = float(sample_time)

    def output(self) -> float:
        return float(self._plant.outputs()[0])

    def step(self, u: float) -> None:
        self._plant.step((u,), (), self._h)
