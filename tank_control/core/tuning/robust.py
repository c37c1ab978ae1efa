"""Ms-constrained PI/PID design: the kappa-tau idea ([Precup2013] §3.4.2) done by optimisation.

Kappa-tau (Åström & Hägglund, *PID Controllers: Theory, Design and Tuning*, 2nd ed., 1995;
[Precup2013] eq. 3.4.7) fitted tables to the settings that maximise the integral gain ``ki = kp/ti``
— the load-disturbance criterion: a unit load step at the plant input gives
``∫e dt = 1/ki`` ([Viteckova] eq. 10) — subject to a bound on the sensitivity peak
``Ms = max|1/(1 + C·G)|``. [Precup2013]'s copy lost the tables; here the optimisation itself is
solved on the given model (Åström, Panagopoulos & Hägglund, "Design of PI controllers based
on non-convex optimization", Automatica 34(5), 1998: for a fixed kp every frequency excludes
an interval of ki, so the largest admissible ki follows from a quadratic per frequency).

* PI: maximise ki subject to ``Ms ≤ ms`` (and ``Mt = max|T| ≤ mt`` when given).
* PID: the same with the derivative gain bounded, ``kd ≤ kp²/(4·ki)`` (``td ≤ ti/4``: the
  PID's zeros stay real; Garpinger & Hägglund's constant Ti/Td-ratio constraint), searched
  over td; the derivative filter ``Tf = td/n`` ([Viteckova] eq. 13–14) is part of the design.
* With ``sample_time`` the loop is the implemented discrete one — the exact ZOH model of the
  plant (fractional dead time included) and the transfer function of ``Pid2Dof`` (forward
  Euler integral, backward-difference filtered derivative) — so the realised Ms of the
  running loop is the target; without it the continuous loop.
* Setpoint weights as in kappa-tau: ``b`` the largest value in [0, 1] for which the setpoint
  response has no resonance peak (``max|Y/R| ≤ 1``), ``c = 0`` (derivative on the measurement).

Gains in controller-output units per measured unit, times in s, frequencies in rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from tank_control.core.scipy_lazy import brentq, minimize_scalar

from tank_control.core.analysis import frequency as fr
from tank_control.core.tuning.model import ProcessModel

TD_RATIO = 0.25
"""Largest td/ti of the PID design (real PID zeros)."""
_W_POINTS = 500
_KP_POINTS = 60
_ZOOMS = 3
_ZOOM_POINTS = 21
_TD_POINTS = 12


@dataclass(frozen=True)
class MsDesign:
    """Result of :func:`ms_design`: the gains (``ti`` [s], ``td`` [s], ``b``, ``c``), the
    integral gain ``ki`` [1/s per unit], and the realised ``ms``, ``mt`` of the designed loop."""

    kp: float
    ti: float
    td: float
    b: float
    c: float
    ki: float
    ms: float
    mt: float


def _disks(ms: float, mt: float | None) -> list[tuple[complex, float]]:
    """``(centre, radius)`` of the disks the loop L(jω) must avoid: ``|1 + L| < 1/Ms`` and
    ``|L/(1 + L)| > Mt`` (a circle centred at ``−Mt²/(Mt² − 1)``, radius ``Mt/(Mt² − 1)``)."""
    disks = [(-1.0 + 0j, 1.0 / ms)]
    if mt is not None and mt > 1.0:
        disks.append((complex(-mt * mt / (mt * mt - 1.0)), mt / (mt * mt - 1.0)))
    return disks


class _Loop:
    """``L = kp·A(ω) + ki·H(ω)`` on a frequency grid for a fixed td (and filter n)."""

    def __init__(self, plant: fr.FrequencyResponse, w: np.ndarray, td: float, n: float,
                 sample_time: float | None) -> None:
        g = plant(w)
        if sample_time:
            z = np.exp(1j * w * sample_time)
            d = (n * (td / (td + n * sample_time)) * (z - 1.0)
                 / (z - td / (td + n * sample_time))) if td > 0 else 0.0
            integ = sample_time / (z - 1.0)
        else:
            s = 1j * w
            d = td * s / (td / n * s + 1.0) if td > 0 else 0.0
            integ = 1.0 / s
        self.a = g * (1.0 + d)
        self.h = g * integ

    def kp_limit(self, disks: list[tuple[complex, float]]) -> float:
        """The largest kp from 0 for which ``kp·A`` (ki → 0) stays outside every disk."""
        best = math.inf
        for centre, radius in disks:
            a2 = np.abs(self.a) ** 2
            b = -2.0 * (np.conj(self.a) * centre).real
            c = abs(centre) ** 2 - radius ** 2
            disc = b * b - 4 * a2 * c
            ok = disc >= 0
            roots = (-b[ok] - np.sqrt(disc[ok])) / (2 * a2[ok])
            roots = roots[roots > 0]
            if roots.size:
                best = min(best, float(roots.min()))
        return best

    def ki_max(self, kp: np.ndarray, disks: list[tuple[complex, float]]) -> np.ndarray:
        """The largest ki ≥ 0 per kp such that L stays outside every disk on the grid
        (0 where ki → 0 is already inside one)."""
        kp = np.atleast_1d(np.asarray(kp, float))[:, None]
        h2 = np.abs(self.h) ** 2
        out = np.full(kp.shape[0], np.inf)
        for centre, radius in disks:
            p = kp * self.a[None, :] - centre
            b = 2.0 * (np.conj(self.h)[None, :] * p).real
            c = np.abs(p) ** 2 - radius ** 2
            inside = np.any(c < 0, axis=1)
            disc = b * b - 4 * h2[None, :] * c
            bound = np.where((disc >= 0) & (b < 0), (-b - np.sqrt(np.maximum(disc, 0.0)))
                             / (2 * h2[None, :]), np.inf)
            out = np.minimum(out, bound.min(axis=1))
            out[inside] = 0.0
        return out


def _grid(plant: fr.FrequencyResponse, model: ProcessModel,
          sample_time: float | None) -> tuple[np.ndarray, float]:
    """Design frequencies [rad/s] around the ultimate frequency ωu of the model (or of the
    sampled loop), and ωu."""
    try:
        wu = fr.ultimate_point(plant).wu
    except ValueError:
        corners = [c for c in plant.corners if c > 0]
        wu = max(corners) if corners else 1.0
    hi = 200.0 * wu
    if sample_time:
        hi = min(hi, math.pi / sample_time * (1 - 1e-9))
    return np.logspace(math.log10(wu / 300.0), math.log10(hi), _W_POINTS), wu


def _best_ki(loop: _Loop, disks: list[tuple[complex, float]],
             td: float) -> tuple[float, float]:
    """``(kp, ki)`` maximising ki on the first connected feasible kp interval from 0 (the
    stable region: the loop reaches an unstable region only through a disk), with
    ``ki ≤ kp·TD_RATIO/td`` for a PID."""
    limit = loop.kp_limit(disks)
    if not math.isfinite(limit) or limit <= 0:
        raise ValueError('model: no stabilising gain found on the frequency grid')

    def ki_of(kp: np.ndarray) -> np.ndarray:
        ki = loop.ki_max(kp, disks)
        if td > 0:
            ki = np.minimum(ki, np.asarray(kp) * TD_RATIO / td)
        return ki
    kps = np.linspace(limit * 1e-3, limit * (1 - 1e-6), _KP_POINTS)
    kis = ki_of(kps)
    feasible = kis > 0
    stop = int(np.argmin(feasible)) if not feasible.all() else kps.size
    if stop == 0:
        raise ValueError('model: no admissible gains for this Ms target')
    kps, kis = kps[:stop], kis[:stop]
    for _ in range(_ZOOMS):                   # zoom in on the maximum (vectorised)
        i = int(np.argmax(kis))
        lo, hi = kps[max(i - 1, 0)], kps[min(i + 1, kps.size - 1)]
        if not hi > lo:
            break
        kps = np.linspace(lo, hi, _ZOOM_POINTS)
        kis = ki_of(kps)
    i = int(np.argmax(kis))
    return float(kps[i]), float(kis[i])


def _loop_response(plant: fr.FrequencyResponse, kp: float, ti: float, td: float, n: float,
                   sample_time: float | None) -> fr.FrequencyResponse:
    if sample_time:
        return fr.pid_feedback_discrete(kp, ti, td, n, sample_time=sample_time) * plant
    return fr.pid_feedback(kp, ti, td, n) * plant


def _setpoint_weight(plant: fr.FrequencyResponse, kp: float, ti: float, td: float, n: float,
                     sample_time: float | None, w: np.ndarray) -> float:
    """The largest b in [0, 1] (steps of 0.01) with ``max|Y/R| ≤ 1`` (c = 0), else 0."""
    ctrl = (fr.pid_feedback_discrete(kp, ti, td, n, sample_time=sample_time) if sample_time
            else fr.pid_feedback(kp, ti, td, n))
    g, cv = plant(w), ctrl(w)
    s = 1.0 / (1.0 + g * cv)
    integ = (sample_time / (np.exp(1j * w * sample_time) - 1.0) if sample_time
             else 1.0 / (1j * w))
    ki_part = kp / ti * integ * g * s
    p_part = kp * g * s
    best = 0.0
    for b in np.linspace(0.0, 1.0, 101):
        if np.max(np.abs(b * p_part + ki_part)) <= 1.0 + 1e-6:
            best = float(b)
        else:
            break
    return best


def ms_design(model: ProcessModel, kind: str, ms: float = 1.4, mt: float | None = None,
              sample_time: float | None = None, n: float = 10.0) -> MsDesign:
    """Maximise the integral gain of a PI (``kind`` 'pi') or PID ('pid') subject to
    ``Ms ≤ ms`` (and ``Mt ≤ mt``) on ``model`` — the implemented discrete loop when
    ``sample_time`` [s] is given (see the module docstring). ``n``: derivative filter
    ratio td/Tf. Raises ``ValueError`` naming the argument when no design exists."""
    if kind not in ('pi', 'pid'):
        raise ValueError(f"kind: {kind!r} is not available for the Ms design; allowed pi, pid")
    if not (isinstance(ms, (int, float)) and 1.0 < ms < 10.0):
        raise ValueError(f'ms: {ms!r} is out of range; allowed (1, 10)')
    if mt is not None and mt and not 1.0 < mt < 10.0:
        raise ValueError(f'mt: {mt!r} is out of range; allowed (1, 10) or none')
    model.check()
    plant = model.response(sample_time)
    w, wu = _grid(plant, model, sample_time)
    disks = _disks(ms, mt or None)
    if kind == 'pi':
        td = 0.0
        kp, ki = _best_ki(_Loop(plant, w, 0.0, n, sample_time), disks, 0.0)
    else:
        tu = 2 * math.pi / wu

        def solve(td: float) -> tuple[float, float]:
            try:
                return _best_ki(_Loop(plant, w, td, n, sample_time), disks, td)
            except ValueError:
                return 0.0, 0.0
        tds = np.linspace(0.0, 0.5 * tu, _TD_POINTS)
        kis = [solve(x)[1] for x in tds]
        j = int(np.argmax(kis))
        lo, hi = tds[max(j - 1, 0)], tds[min(j + 1, tds.size - 1)]
        res = minimize_scalar(lambda x: -solve(x)[1], bounds=(lo, hi), method='bounded',
                              options={'xatol': 1e-4 * tu})
        td = float(res.x) if -res.fun >= kis[j] else float(tds[j])
        kp, ki = solve(td)
        if ki <= 0:
            raise ValueError('model: no admissible PID gains for this Ms target')
    ti = kp / ki
    kp, ki = _exact(plant, kp, ti, td, n, sample_time, ms, mt)
    ti = kp / ki
    loop = _loop_response(plant, kp, ti, td, n, sample_time)
    m = fr.margins(loop)
    if not fr.closed_loop_stable(loop):
        raise ValueError('model: the Ms design gave an unstable loop')
    b = _setpoint_weight(plant, kp, ti, td, n, sample_time, w)
    return MsDesign(kp=kp, ti=ti, td=td, b=b, c=0.0, ki=ki, ms=m.ms, mt=m.mt)


def _exact(plant: fr.FrequencyResponse, kp: float, ti: float, td: float, n: float,
           sample_time: float | None, ms: float, mt: float | None) -> tuple[float, float]:
    """Scale (kp, ki) together (ti, td fixed) so the exact Ms (on the refined grid of
    ``frequency.margins``) does not exceed the target between the design grid's points."""
    def excess(scale: float) -> float:
        m = fr.margins(_loop_response(plant, kp * scale, ti, td, n, sample_time))
        over = m.ms / ms - 1.0
        if mt:
            over = max(over, m.mt / mt - 1.0)
        return over
    if excess(1.0) <= 1e-4:
        return kp, kp / ti
    lo = 0.5
    while excess(lo) > 0 and lo > 1e-3:
        lo *= 0.5
    scale = brentq(lambda x: excess(x) - 1e-5, lo, 1.0, xtol=1e-10)
    return kp * scale, kp * scale / ti
