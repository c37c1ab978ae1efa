"""What a kind says about itself for the loop analysis: a plant's linear model, a controller's
discrete transfer function (pure numpy/scipy).

A plant kind with a linear description sets ``PlantKind.linear(config)`` → a
:class:`LinearModel` (or None for a configuration that has none); a controller kind sets
``ControllerKind.linear(settings)`` → a :class:`LinearController` (or None). Every SISO loop
whose two kinds answer is analysed the same way — ``tank-control analyze``, ``analysis.png``,
the metrics' ``loop_analysis`` and the dashboard's robustness panel
(``core/scenario_loops.py``) — with no list of kind names anywhere.

Sign convention: the analysis closes ``L = C·G`` with negative feedback. A plant kind gives
its model with the magnitude of its gain (a reverse-acting process runs with
``direct_action``), a controller kind its law for such a plant (``C = −U/Y`` of the
implemented discrete law at its sample time, exact dead time and ZOH on the plant side).
Frequencies in rad/s, times in s.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.robustness import LoopReport, response_report


@runtime_checkable
class LinearModel(Protocol):
    """A SISO linear plant model (``core.tuning.model.ProcessModel`` is one,
    :class:`RationalModel` another)."""

    @property
    def dead_time(self) -> float:
        """[s]"""

    def describe(self) -> str:
        """One line, e.g. ``fopdt K=0.05 T=10 s L=3 s``."""

    def response(self, sample_time: float | None = None) -> fr.FrequencyResponse:
        """Continuous response (``sample_time`` None), or the exact ZOH model sampled every
        ``sample_time`` [s] (fractional dead time included)."""


@dataclass(frozen=True)
class RationalModel:
    """``num(s)/den(s)·e^(−dead_time·s)`` (coefficients highest power first, strictly
    proper; the denominator may be unstable)."""

    num: tuple[float, ...]
    den: tuple[float, ...]
    dead_time: float = 0.0
    name: str = 'transfer function'

    def describe(self) -> str:
        def poly(p: tuple[float, ...]) -> str:
            return '[' + ', '.join(f'{c:.6g}' for c in p) + ']'
        return f'{self.name} {poly(self.num)}/{poly(self.den)} L={self.dead_time:.6g} s'

    def response(self, sample_time: float | None = None) -> fr.FrequencyResponse:
        if sample_time is None:
            return fr.rational(self.num, self.den, self.dead_time)
        return fr.rational_zoh(self.num, self.den, self.dead_time, sample_time)


def frequency_scale(model: LinearModel) -> float:
    """[rad/s] a frequency that sets the plots' grid: the model's ultimate (phase −180°)
    frequency, else its slowest corner, else 1."""
    continuous = model.response()
    try:
        return float(fr.ultimate_point(continuous).wu)
    except (ValueError, ArithmeticError):
        corners = [c for c in continuous.corners if c > 0 and math.isfinite(c)]
        return min(corners) if corners else 1.0


Characteristic = Callable[[fr.FrequencyResponse], fr.FrequencyResponse]
"""Given the plant's discrete response ``G``, a loop with the same closed-loop poles as
``C·G`` and no hidden unstable open-loop poles (a Smith predictor's ``C·(Gm0 − Gm + G)``)."""


@dataclass(frozen=True)
class LinearController:
    """A controller kind's linear description: ``feedback`` = −U/Y and ``setpoint`` = U/R
    (None: the same, one degree of freedom) of the implemented discrete law, ``describe`` one
    line of its settings, ``characteristic`` (see :data:`Characteristic`; None: the Nyquist
    count on ``C·G`` with ``feedback``'s own unstable poles), ``models``: the models the
    controller carries, each ``(source, model)`` (e.g. ``('tuning.*', model)``), analysed
    beside the plant's. Valid in the linear range (no limits, auto mode)."""

    feedback: fr.FrequencyResponse
    describe: str
    setpoint: fr.FrequencyResponse | None = None
    characteristic: Characteristic | None = None
    models: tuple[tuple[str, LinearModel], ...] = field(default=())

    @property
    def sample_time(self) -> float:
        """[s]"""
        return self.feedback.sample_time

    def report(self, model: LinearModel) -> LoopReport:
        """Stability, margins, Ms, Mt, delay margin of this controller on ``model``."""
        plant = model.response(self.sample_time)
        characteristic = (None if self.characteristic is None
                          else self.characteristic(plant))
        return response_report(model, self.feedback, self.setpoint, characteristic)


class PidGains(Protocol):
    """What the PID's description reads of a ``PidConfig`` (times in s)."""

    @property
    def kp(self) -> float: ...

    @property
    def ti(self) -> float: ...

    @property
    def td(self) -> float: ...

    @property
    def n(self) -> float: ...

    @property
    def b(self) -> float: ...

    @property
    def c(self) -> float: ...

    @property
    def sample_time(self) -> float: ...


def pid_description(config: PidGains) -> str:
    """``PID kp …, ti … s, td … s, n …, b …, c …`` of a ``PidConfig``."""
    c = config
    ti = 'inf' if not math.isfinite(c.ti) else f'{c.ti:.4g}'
    return (f'PID kp {abs(c.kp):.4g}, ti {ti} s, td {c.td:.4g} s, '
            f'n {c.n:g}, b {c.b:g}, c {c.c:g}')


def pid_controller(config: PidGains, models: tuple[tuple[str, LinearModel | None], ...] = ()
                   ) -> LinearController:
    """The description of ``Pid2Dof(config)`` (a ``PidConfig``; gain magnitude): feedback
    ``frequency.pid_feedback_discrete``, setpoint ``pid_setpoint_discrete``."""
    c = config
    h, kp = c.sample_time, abs(c.kp)
    return LinearController(
        fr.pid_feedback_discrete(kp, c.ti, c.td, c.n, sample_time=h),
        pid_description(c),
        fr.pid_setpoint_discrete(kp, c.ti, c.td, c.n, c.b, c.c, sample_time=h),
        models=tuple((source, m) for source, m in models if m is not None))


def model_sum(terms: tuple[tuple[float, fr.FrequencyResponse], ...], integrators: int,
              unstable_poles: int) -> fr.FrequencyResponse:
    """``Σ sign·G`` of discrete responses with the same sample time (each delay included),
    with the sum's ``integrators`` and ``unstable_poles`` as the caller knows them (terms may
    cancel: a Smith predictor's ``Gm0 − Gm``)."""
    h = terms[0][1].sample_time
    parts = [(float(sign), g) for sign, g in terms]

    def rational(z: np.ndarray) -> np.ndarray:
        return sum((sign * g.at(z) for sign, g in parts), np.zeros_like(z, dtype=complex))
    return fr.FrequencyResponse(rational, 0.0, h, integrators, unstable_poles,
                                tuple(c for _, g in parts for c in g.corners))
