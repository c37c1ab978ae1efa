"""Robustness and predicted response of the implemented loop on a process model.

The loop is the one that runs: the exact ZOH model of the process at the controller's
sample time (``core/tuning/model.py``, fractional dead time included) in feedback with the
transfer function of ``Pid2Dof`` (``frequency.pid_feedback_discrete``: forward-Euler integral,
backward-difference filtered derivative, [Viteckova] eqs. 13, 19). :func:`loop_report` gives the
Nyquist stability with the exact delay, gain and phase margins, Ms, Mt, delay margin and
crossovers ([Checks] §2; [Ikonen]); :func:`predict` simulates the same loop on the model for a unit
setpoint step and a unit load step at the plant input ([Viteckova] Fig. 1) and gives overshoot,
IAE and settling time. :func:`response_report` does the same analysis for any controller's
discrete response (the lead-lag's, the Smith predictor's equivalent controller,
:func:`smith_report`). Units: margins as ratios, phase in degrees, frequencies in rad/s,
times in s, IAE in output units·s per unit step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.step_metrics import iae, step_metrics
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.tuning.model import DiscretePlant, ProcessModel

if TYPE_CHECKING:
    from tank_control.core.analysis.linear import LinearModel


@dataclass(frozen=True)
class LoopReport:
    """Robustness of the loop: ``stable`` (Nyquist count, exact delay), ``gain_margin``
    (inf: the phase never reaches −180°), ``phase_margin`` [deg] (NaN: |L| never crosses 1),
    ``ms``, ``mt``, ``delay_margin`` [s], ``wc`` (gain crossover) and ``w180`` [rad/s],
    ``setpoint_peak`` = max|Y/R| with the setpoint weights; ``model`` its description."""

    stable: bool
    gain_margin: float
    phase_margin: float
    ms: float
    mt: float
    delay_margin: float
    wc: float
    w180: float
    setpoint_peak: float
    model: str


def response_report(model: LinearModel, controller: fr.FrequencyResponse,
                    setpoint: fr.FrequencyResponse | None = None,
                    characteristic: fr.FrequencyResponse | None = None) -> LoopReport:
    """:class:`LoopReport` of any implemented controller on ``model``: ``controller`` is its
    discrete response −U/Y (its ``sample_time`` is the loop's), ``setpoint`` its U/R (default
    the same: one degree of freedom); ``characteristic``: a loop with the same closed-loop
    poles for the Nyquist count (default the loop itself)."""
    rep = fr.controller_report(controller, model.response(controller.sample_time), setpoint,
                               characteristic)
    return LoopReport(stable=bool(rep['stable']), gain_margin=rep['gain_margin'],
                      phase_margin=rep['phase_margin'], ms=rep['ms'], mt=rep['mt'],
                      delay_margin=rep['delay_margin'], wc=rep['wc'], w180=rep['w180'],
                      setpoint_peak=rep['setpoint_peak'], model=model.describe())


def loop_report(model: ProcessModel, config: PidConfig) -> LoopReport:
    """:class:`LoopReport` of ``Pid2Dof(config)`` on ``model`` sampled at
    ``config.sample_time`` (the gain magnitude is used: a reverse-acting process runs with
    ``direct_action``)."""
    h, kp = config.sample_time, abs(config.kp)
    return response_report(
        model, fr.pid_feedback_discrete(kp, config.ti, config.td, config.n, sample_time=h),
        fr.pid_setpoint_discrete(kp, config.ti, config.td, config.n, config.b, config.c,
                                 sample_time=h))


def smith_responses(model: ProcessModel, primary: PidConfig
                    ) -> tuple[fr.FrequencyResponse, fr.FrequencyResponse, fr.FrequencyResponse]:
    """``(C_eq, R_eq, C·Gm0)`` of the Smith predictor ([Precup2013] §3.6.1) with the discrete PI
    ``primary`` (td = c = 0) and the internal model ``model`` as implemented at its sample
    time ``h`` (exact ZOH, fractional dead time; a negative ``kp`` acts on the positive
    ``model`` with the opposite sign): the equivalent feedback controller
    ``C_eq = C/(1 + C·(Gm0 − Gm))`` (−U/Y), its setpoint path ``R_eq = C_r/(1 + C·(Gm0 − Gm))``
    (U/R, weight b) and the delay-free loop ``C·Gm0`` whose closed-loop poles are the loop's
    when the plant equals the model ([Precup2013] eq. 3.6.5)."""
    h, kp = primary.sample_time, abs(primary.kp)
    sign = -1.0 if primary.kp < 0 else 1.0       # kp < 0 on a positive model: positive feedback
    c = fr.pid_feedback_discrete(kp, primary.ti, 0.0, primary.n, sample_time=h) * sign
    cr = fr.pid_setpoint_discrete(kp, primary.ti, 0.0, primary.n, primary.b, 0.0,
                                  sample_time=h) * sign
    gm = model.response(h)
    gm0 = replace(model, dead_time=0.0).response(h)

    def delta(z: np.ndarray) -> np.ndarray:              # Gm0 − Gm on z (delay included)
        return gm0.at(z) - gm.at(z)

    # C_eq has C's integrator unless C·(Gm0 − Gm) has one too (ipdt: Gm0 − Gm is a finite sum
    # with a non-zero value at z = 1; fopdt: it vanishes at z = 1).
    integrators = c.integrators if model.kind != 'ipdt' else 0

    def coefficients(law: fr.FrequencyResponse
                     ) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """``law/(1 + C·(Gm0 − Gm))`` over one denominator, ``Gm = nm/(dm·z^d)``."""
        if law.coefficients is None or c.coefficients is None or gm0.coefficients is None \
                or gm.coefficients is None:
            return None
        (nf, df), (nc, dc) = law.coefficients, c.coefficients
        (n0, d0), (nm, dm) = gm0.coefficients, gm.coefficients
        zd = np.polymul(dm, [1.0] + [0.0] * int(round(gm.dead_time / h)))      # dm·z^d
        common = np.polymul(np.polymul(dc, d0), zd)
        den = np.polyadd(common, np.polymul(nc, np.polysub(np.polymul(n0, zd),
                                                          np.polymul(nm, d0))))
        return tuple(np.polymul(nf, common)), tuple(np.polymul(df, den))

    def equivalent(law: fr.FrequencyResponse) -> fr.FrequencyResponse:
        f, g = law.rational, c.rational
        return fr.FrequencyResponse(lambda z: f(z) / (1.0 + g(z) * delta(z)), 0.0, h,
                                    integrators, 0, c.corners + gm.corners, coefficients(law))
    return equivalent(c), equivalent(cr), c * gm0


def smith_report(model: ProcessModel, primary: PidConfig) -> LoopReport:
    """:class:`LoopReport` of the Smith predictor on its own internal model (plant = model):
    margins, Ms, Mt and crossovers of ``L = C_eq·Gm`` (:func:`smith_responses`, exact dead
    time and ZOH), stability from the delay-free loop ``C·Gm0``."""
    ceq, req, free = smith_responses(model, primary)
    return response_report(model, ceq, req, characteristic=free)


@dataclass(frozen=True)
class Prediction:
    """Simulated response of the loop on the model (deviation variables, from rest).

    ``t`` [s]; ``setpoint``: y after a unit setpoint step at t = 0; ``load``: y after a unit
    step of the load disturbance at the plant input at t = 0. ``overshoot`` [%] and
    ``settling_time`` [s] (2 % band) of the setpoint response; ``iae_setpoint``,
    ``iae_load`` over the whole horizon [y units·s per unit step]."""

    t: np.ndarray
    setpoint: np.ndarray
    load: np.ndarray
    overshoot: float
    settling_time: float
    iae_setpoint: float
    iae_load: float

    def iae_setpoint_within(self, window: float) -> float:
        """IAE of the unit setpoint response over [0, window] [s]."""
        keep = self.t <= window + 1e-9
        return iae(self.t[keep], 1.0 - self.setpoint[keep]) if keep.sum() > 1 else 0.0

    def as_dict(self) -> dict[str, float]:
        return {'overshoot': self.overshoot, 'settling_time': self.settling_time,
                'iae_setpoint': self.iae_setpoint, 'iae_load': self.iae_load}


def horizon(model: ProcessModel, config: PidConfig) -> float:
    """Simulated time [s] for :func:`predict`: long enough for the loop to settle — 12 times
    the slowest of the ultimate period, the integral time and the model's lag, at most
    20 000 samples."""
    tu = model.ultimate_point().tu if model.dead_time > 0 or model.kind == 'sopdt' else 0.0
    slow = max(tu, config.ti if math.isfinite(config.ti) else 0.0,
               model.lag if math.isfinite(model.lag) else 0.0, 10 * config.sample_time)
    return min(12.0 * slow, 20_000 * config.sample_time)


def _simulate(model: ProcessModel, config: PidConfig, steps: int, r: float,
              v: float) -> np.ndarray:
    unlimited = replace(config, kp=abs(config.kp), direct_action=False, u_min=-1e12, u_max=1e12,
                        du_max=math.inf)
    pid = Pid2Dof(unlimited)
    pid.reset(0.0, 0.0, 0.0)
    plant = DiscretePlant(model, config.sample_time)
    y = np.empty(steps)
    for k in range(steps):
        y[k] = plant.output()
        plant.step(pid.update(r, y[k]) + v)
    return y


def predict(model: ProcessModel, config: PidConfig, duration: float | None = None) -> Prediction:
    """Simulate ``Pid2Dof(config)`` (without output limits) on the exact ZOH ``model``:
    a unit setpoint step and, separately, a unit load step at the plant input, both at
    t = 0 from rest; ``duration`` [s] defaults to :func:`horizon`."""
    h = config.sample_time
    duration = horizon(model, config) if duration is None else duration
    steps = max(int(round(duration / h)) + 1, 3)
    t = h * np.arange(steps)
    ys = _simulate(model, config, steps, 1.0, 0.0)
    yl = _simulate(model, config, steps, 0.0, 1.0)
    sm = step_metrics(t, ys, 1.0, y0=0.0, t_step=0.0)
    return Prediction(t=t, setpoint=ys, load=yl, overshoot=float(sm.overshoot),
                      settling_time=float(sm.settling_time), iae_setpoint=iae(t, 1.0 - ys),
                      iae_load=iae(t, yl))


def pid_key(config: PidConfig) -> tuple[Any, ...]:
    """The settings of a ``PidConfig`` that :func:`loop_report` depends on."""
    return (abs(config.kp), config.ti, config.td, config.n, config.sample_time, config.b,
            config.c)


class RobustnessMonitor:
    """The report of the running loop, recomputed only when the model or the loop's settings
    change: ``analyse(model, config)`` (default :func:`loop_report`, the PID) keyed by
    ``key(config)`` (default :func:`pid_key`)."""

    def __init__(self, analyse: Callable[[ProcessModel, Any], LoopReport] = loop_report,
                 key: Callable[[Any], Any] = pid_key) -> None:
        self._analyse, self._key_of = analyse, key
        self._key: Any = None
        self._report: LoopReport | None = None

    def report(self, model: ProcessModel | None, config: Any) -> LoopReport | None:
        if model is None:
            return None
        key = (model, self._key_of(config))
        if key != self._key:
            self._report = self._analyse(model, config)
            self._key = key
        return self._report


def finite_or(value: float, default: float = 0.0) -> float:
    """``value`` if finite, else ``default`` (parameters hold no inf/NaN: 0 = none)."""
    return float(value) if math.isfinite(value) else default
