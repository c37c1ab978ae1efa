"""Identification from a relay (on-off) experiment: ultimate point and low-order models.

Pure functions on recorded samples ``t`` [s], ``u`` (plant input, zero-order hold) and ``y``
(plant output), as deviations from the operating point; plant gain assumed positive. Sources:
[DeadTimeNotes] §1.3 (eqs. 6.16–6.22), [Precup2013] §3.2–3.3 and §3.6 (eqs. 3.2.1, 3.3.1–3.3.21, 3.6.1–3.6.2).
Estimates: describing function ``ku = 4·d/(π·a)``; first harmonic ``G(jωc) = Y1/U1``, corrected
to the −180° point along a local model through ``G(jωc)`` and ``G(j3ωc)``
(:func:`anchored_ultimate_point`). Method: docs/tuning.md; accuracy: bench/RESULTS.md.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from tank_control.core.scipy_lazy import brentq, least_squares, lfilter, minimize_scalar

# --------------------------------------------------------------------------- models


@dataclass(frozen=True)
class FopdtModel:
    """``G(s) = gain/(time_constant·s + 1)^order · e^(−dead_time·s)`` ([Precup2013] eq. 3.6.1;
    [DeadTimeNotes] eq. 6.14).

    ``gain`` in output units per input unit, times in seconds, ``order`` 1 or 2.
    """

    gain: float
    time_constant: float
    dead_time: float
    order: int = 1
    kind: str = field(default='fopdt', init=False)

    def frequency_response(self, omega: float) -> complex:
        """``G(jω)`` at ``omega`` [rad/s]."""
        s = 1j * omega
        return self.gain / (self.time_constant * s + 1.0) ** self.order * np.exp(-self.dead_time * s)

    def lag_frequency(self, lag: float) -> float:
        """The frequency [rad/s] where the model lags by ``lag`` [rad]:
        ``ω·L + n·arctan(ω·T) = lag``."""
        n, tc, dt = self.order, self.time_constant, self.dead_time

        def phase_gap(w: float) -> float:
            return w * dt + n * math.atan(w * tc) - lag

        hi = 1.0
        while phase_gap(hi) < 0.0:
            hi *= 2.0
            if hi > 1e12:
                raise ValueError(f'no frequency with a lag of {math.degrees(lag):g}° found')
        return brentq(phase_gap, 0.0, hi, xtol=1e-14, rtol=1e-13)

    def ultimate_point(self) -> tuple[float, float]:
        """Exact ``(ku, tu)``: solve ``ω·L + n·arctan(ω·T) = π``, ``ku = 1/|G(jωu)|`` ([Checks] §1)."""
        if self.dead_time <= 0.0 and self.order == 1:
            raise ValueError('dead_time: a first-order plant without dead time has no ultimate point')
        wu = self.lag_frequency(math.pi)
        return 1.0 / abs(self.frequency_response(wu)), 2.0 * math.pi / wu

    def as_dict(self) -> dict[str, float | str | int]:
        return {'kind': self.kind, 'gain': self.gain, 'time_constant': self.time_constant,
                'dead_time': self.dead_time, 'order': self.order}


@dataclass(frozen=True)
class IpdtModel:
    """``G(s) = gain/s · e^(−dead_time·s)`` ([Viteckova] eq. 1; ``gain`` = k1 [output units per input unit per s])."""

    gain: float
    dead_time: float
    kind: str = field(default='ipdt', init=False)

    def frequency_response(self, omega: float) -> complex:
        s = 1j * omega
        return self.gain / s * np.exp(-self.dead_time * s)

    def ultimate_point(self) -> tuple[float, float]:
        """Exact ``ku = π/(2·k1·To)``, ``tu = 4·To`` ([Checks] §1)."""
        if self.dead_time <= 0.0:
            raise ValueError('dead_time: an integrator without dead time has no ultimate point')
        return math.pi / (2.0 * self.gain * self.dead_time), 4.0 * self.dead_time

    def as_dict(self) -> dict[str, float | str]:
        return {'kind': self.kind, 'gain': self.gain, 'dead_time': self.dead_time}


Model = FopdtModel | IpdtModel


def fopdt_from_ultimate(ku: float, tu: float, gain: float, order: int = 1) -> FopdtModel:
    """FOPDT (order 1) or SOPDT (order 2) through the ultimate point and a known static gain ([Precup2013] eq. 3.6.2).

    ``T = (1/ωu)·√((kP·ku)^(2/n) − 1)``, ``L = (π − n·arctan(ωu·T))/ωu`` with ``ωu = 2π/tu``.
    """
    if order not in (1, 2):
        raise ValueError(f'order: {order} is not allowed; allowed 1 or 2')
    if not (ku > 0 and tu > 0 and gain > 0):
        raise ValueError('ku, tu, gain: must be positive')
    if gain * ku <= 1.0:
        raise ValueError(f'gain: kP·ku = {gain * ku:g} must exceed 1 for [Precup2013] eq. 3.6.2')
    wu = 2.0 * math.pi / tu
    tc = math.sqrt((gain * ku) ** (2.0 / order) - 1.0) / wu
    dead = (math.pi - order * math.atan(wu * tc)) / wu
    return FopdtModel(gain=gain, time_constant=tc, dead_time=max(dead, 0.0), order=order)


def ipdt_from_ultimate(ku: float, tu: float) -> IpdtModel:
    """IPDT through the ultimate point, exact for IPDT: ``To = tu/4``, ``k1 = π/(2·ku·To)`` ([Checks] §1)."""
    if not (ku > 0 and tu > 0):
        raise ValueError('ku, tu: must be positive')
    dead = tu / 4.0
    return IpdtModel(gain=math.pi / (2.0 * ku * dead), dead_time=dead)


# --------------------------------------------------------------- record analysis


def crossing_times(t: np.ndarray, x: np.ndarray, level: float = 0.0, rising: bool = True) -> np.ndarray:
    """Instants [s] where ``x`` crosses ``level`` upwards (``rising``) or downwards, linearly interpolated."""
    t = np.asarray(t, float)
    x = np.asarray(x, float) - level
    if rising:
        idx = np.nonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))[0]
    else:
        idx = np.nonzero((x[:-1] > 0.0) & (x[1:] <= 0.0))[0]
    frac = x[idx] / (x[idx] - x[idx + 1])
    return t[idx] + frac * (t[idx + 1] - t[idx])


def switching_indices(u: np.ndarray, u0: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices where a relay output ``u`` (ZOH) switches above / below ``u0``.

    Returns ``(to_high, to_low)``: index ``k`` such that ``u[k-1]`` and ``u[k]`` are on
    opposite sides of ``u0``; the switch happened at ``t[k]``.
    """
    high = np.asarray(u, float) > u0
    change = np.nonzero(high[1:] != high[:-1])[0] + 1
    return change[high[change]], change[~high[change]]


@dataclass(frozen=True)
class RelayCycle:
    """One period between two switches in the same direction ([Precup2013] Fig. 3.4).

    ``start``/``end`` are sample indices; ``period``, ``high_time`` (Tu1, u above u0) and
    ``low_time`` (Tu2) in seconds; ``y_max``/``y_min`` extremes of ``y`` within the cycle;
    ``y1`` the amplitude of the first harmonic of ``y`` over this cycle.
    """

    start: int
    end: int
    period: float
    high_time: float
    low_time: float
    y_max: float
    y_min: float
    y1: float


def relay_cycles(t: np.ndarray, u: np.ndarray, y: np.ndarray, u0: float) -> list[RelayCycle]:
    """Split a relay record into whole cycles, each starting at a switch in the direction of the first switch.

    The part before the first switch (the start of the relay from rest) is never part of a cycle.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    to_high, to_low = switching_indices(u, u0)
    if len(to_high) == 0 or len(to_low) == 0:
        return []
    starts, others = (to_high, to_low) if to_high[0] < to_low[0] else (to_low, to_high)
    start_is_high = starts is to_high
    cycles = []
    for a, b in zip(starts[:-1], starts[1:]):
        mid = others[(others > a) & (others < b)]
        if len(mid) != 1:
            continue
        m = int(mid[0])
        first, second = t[m] - t[a], t[b] - t[m]
        high_time, low_time = (first, second) if start_is_high else (second, first)
        seg = y[a:b + 1]
        w = 2.0 * math.pi / (t[b] - t[a])
        y1 = 2.0 * abs(_fourier_samples(t[a:b + 1], seg - seg.mean(), w)) / (t[b] - t[a])
        cycles.append(RelayCycle(int(a), int(b), float(t[b] - t[a]), float(high_time), float(low_time),
                                 float(seg.max()), float(seg.min()), float(y1)))
    return cycles


def stationary_cycles(cycles: Sequence[RelayCycle], count: int, tolerance: float,
                      period_slack: float = 0.0) -> list[RelayCycle] | None:
    """The last ``count`` cycles if they are stationary, else ``None``.

    Stationary: every period within ``tolerance·mean + period_slack`` [s] of the mean
    period (``period_slack`` absorbs the ±1-sample quantisation of a sampled relay) and
    every first-harmonic amplitude within ``tolerance`` (relative) of their mean ([Precup2013] §3.3:
    at least four stationary periods).
    """
    if count < 1 or len(cycles) < count:
        return None
    tail = list(cycles[-count:])
    periods = np.array([c.period for c in tail])
    amps = np.array([c.y1 for c in tail])
    if np.any(np.abs(periods - periods.mean()) > tolerance * periods.mean() + period_slack):
        return None
    if amps.mean() <= 0.0 or np.any(np.abs(amps - amps.mean()) > tolerance * amps.mean()):
        return None
    return tail


# ------------------------------------------------------------- Fourier analysis


def _fourier_samples(t: np.ndarray, x: np.ndarray, omega: float) -> complex:
    """Trapezoidal ``∫ x(t)·e^(−jωt) dt`` over the sampled window ``t[0] … t[-1]``."""
    f = x * np.exp(-1j * omega * t)
    return complex(np.trapezoid(f, t))


def _fourier_zoh(t: np.ndarray, x: np.ndarray, omega: float) -> complex:
    """Exact ``∫ x(t)·e^(−jωt) dt`` over ``t[0] … t[-1]`` of a ZOH signal (``x[k]`` held on ``[t[k], t[k+1])``)."""
    e = np.exp(-1j * omega * t)
    return complex(np.sum(x[:-1] * (e[:-1] - e[1:])) / (1j * omega))


def harmonic_response(t: np.ndarray, u: np.ndarray, y: np.ndarray, start: int, end: int,
                      periods: int, harmonics: Sequence[int] = (1, 3)) -> tuple[float, dict[int, complex]]:
    """Plant frequency response at the odd harmonics of a stationary relay oscillation
    ([Precup2013] eqs. 3.3.19–3.3.21).

    ``start``/``end`` are sample indices spanning exactly ``periods`` whole periods. Returns
    ``(ωc, {k: G(j·k·ωc)})`` with ``ωc = 2π·periods/(t[end] − t[start])`` [rad/s] and
    ``G = Y_k/U_k``: ``U_k`` integrated exactly as a ZOH signal, ``Y_k`` by the trapezoidal
    sum of the samples of ``y`` (exact at the sample instants). Means are removed first.
    """
    t = np.asarray(t, float)[start:end + 1]
    u = np.asarray(u, float)[start:end + 1]
    y = np.asarray(y, float)[start:end + 1]
    width = t[-1] - t[0]
    wc = 2.0 * math.pi * periods / width
    u = u - np.average(u[:-1], weights=np.diff(t))
    y = y - np.trapezoid(y, t) / width
    result = {}
    for k in harmonics:
        uk = _fourier_zoh(t, u, k * wc)
        yk = _fourier_samples(t, y, k * wc)
        result[k] = yk / uk
    return wc, result


def static_gain(t: np.ndarray, u: np.ndarray, y: np.ndarray, start: int, end: int,
                u0: float, y0: float) -> float | None:
    """Static gain from a biased relay, ``kP = ∫(y − y0) dt / ∫(u − u0) dt`` over whole periods ([Precup2013] 3.3.13).

    ``None`` when the relay is (nearly) symmetric, i.e. ``|∫(u − u0)|`` is below 2 % of
    ``∫|u − u0|`` and the ratio would be noise.
    """
    t = np.asarray(t, float)[start:end + 1]
    du = np.asarray(u, float)[start:end + 1] - u0
    dy = np.asarray(y, float)[start:end + 1] - y0
    iu = float(np.sum(du[:-1] * np.diff(t)))
    if abs(iu) < 0.02 * float(np.sum(np.abs(du[:-1]) * np.diff(t))):
        return None
    return float(np.trapezoid(dy, t)) / iu


def fit_first_order_delay(omega: float, g1: complex, g3: complex | None = None,
                          gain: float | None = None, kind: str = 'auto') -> Model:
    """``k·e^(−L·s)/(s + α)`` through the measured point ``g1 = G(jω)`` (FOPDT if α > 0, IPDT if α = 0).

    The pole: from a known static gain ``kP = k/α`` ([Precup2013] eq. 3.6.2, n = 1:
    ``α = ω·|g1|/√(kP² − |g1|²)``), otherwise from the magnitude ratio at ω and 3ω:
    ``α² = ω²·(9|g3|² − |g1|²)/(|g1|² − |g3|²)`` (α = 0 when that is ≤ 0, i.e. integrating).
    Then ``k = |g1|·√(ω² + α²)`` and ``L = (−arg g1 − arctan(ω/α))/ω`` (arg in (−2π, 0]).
    ``kind``: 'auto', 'fopdt' or 'ipdt' (forces α = 0).
    """
    if kind not in ('auto', 'fopdt', 'ipdt'):
        raise ValueError(f"kind: {kind!r} is not a choice; allowed one of auto, fopdt, ipdt")
    m1 = abs(g1)
    alpha2 = 0.0
    if kind != 'ipdt':
        if gain is not None and gain > m1:
            alpha2 = (omega * m1) ** 2 / (gain ** 2 - m1 ** 2)
        elif g3 is not None and m1 > abs(g3):
            m3 = abs(g3)
            alpha2 = max(omega ** 2 * (9.0 * m3 ** 2 - m1 ** 2) / (m1 ** 2 - m3 ** 2), 0.0)
    alpha = math.sqrt(alpha2)
    if kind == 'fopdt' and alpha == 0.0:
        raise ValueError('kind: fopdt requested but the data show an integrating plant (no finite static gain)')
    k = m1 * math.sqrt(omega ** 2 + alpha2)
    phase = math.atan2(g1.imag, g1.real)
    if phase > 0.0:
        phase -= 2.0 * math.pi
    lag = math.atan2(omega, alpha)  # = π/2 for the integrator
    dead = max((-phase - lag) / omega, 0.0)
    if alpha == 0.0:
        return IpdtModel(gain=k, dead_time=dead)
    return FopdtModel(gain=k / alpha, time_constant=1.0 / alpha, dead_time=dead)


def simulate_first_order_delay(u: np.ndarray, sample_time: float, gain: float, alpha: float,
                               dead_time: float) -> np.ndarray:
    """Exact sampled response of ``gain·e^(−L·s)/(s + α)`` to a ZOH input, zero initial state.

    ``u[k]`` is held on ``[k·Ts, (k+1)·Ts)`` and was 0 before; returns ``x`` at ``k·Ts``.
    With ``L = d·Ts + δ`` (0 ≤ δ < Ts) the delayed input is ``u[m−d−1]`` on
    ``[t_m, t_m + δ)`` and ``u[m−d]`` on ``[t_m + δ, t_m+1)`` (modified z-transform):
    ``x[m+1] = φ·x[m] + b0·u[m−d] + b1·u[m−d−1]``, ``φ = e^(−α·Ts)``.
    """
    ts = sample_time
    d = int(math.floor(dead_time / ts))
    delta = dead_time - d * ts
    if alpha > 1e-12:
        phi = math.exp(-alpha * ts)
        b0 = gain / alpha * (1.0 - math.exp(-alpha * (ts - delta)))
        b1 = gain / alpha * (math.exp(-alpha * (ts - delta)) - phi)
    else:
        phi, b0, b1 = 1.0, gain * (ts - delta), gain * delta
    num = np.zeros(d + 3)
    num[d + 1], num[d + 2] = b0, b1
    return lfilter(num, [1.0, -phi], np.asarray(u, float))


def fit_time_domain(t: np.ndarray, u: np.ndarray, y: np.ndarray, start: int, end: int,
                    u0: float, initial: Model, kind: str = 'auto') -> Model:
    """Least-squares refinement of ``k·e^(−L·s)/(s + α)`` on the recorded samples (output-error fit).

    The model is simulated exactly (:func:`simulate_first_order_delay`) from the first
    sample of the record (the relay start, loop at rest at ``u0``) with the recorded ZOH
    input ``u − u0 − b``; the residual ``y − c − x`` is minimised over samples
    ``start … end`` (the stationary cycles) for ``k, α ≥ 0, L ≥ 0`` and the nuisance
    input bias ``b`` and output level ``c``. Sampling must be uniform. Unlike the
    harmonic ratio, this is exact however few samples a period has (no aliasing of the
    corners of ``y``); noise averages out over all samples.
    """
    t = np.asarray(t, float)
    ts = float(np.median(np.diff(t)))
    du = np.asarray(u, float) - u0
    y = np.asarray(y, float)
    seg = slice(start, end + 1)
    if isinstance(initial, IpdtModel):
        k0, a0 = initial.gain, 0.0
    else:
        k0, a0 = initial.gain / initial.time_constant, 1.0 / initial.time_constant
    period = (t[end] - t[start])
    scale = max(float(np.std(y[seg])), 1e-12)
    c0 = float(np.mean(y[seg]))
    force_ipdt = kind == 'ipdt'

    def model_output(p: np.ndarray) -> np.ndarray:
        k, a, dead, b, c = p
        a = 0.0 if force_ipdt else max(a, 0.0)
        return c + simulate_first_order_delay(du - b, ts, k, a, max(dead, 0.0))[seg]

    def residual(p: np.ndarray) -> np.ndarray:
        return (y[seg] - model_output(p)) / scale

    p0 = np.array([k0, a0, initial.dead_time, 0.0, c0])
    lower = [0.0, 0.0, 0.0, -np.inf, -np.inf]
    upper = [np.inf, np.inf, period, np.inf, np.inf]
    p0 = np.clip(p0, [1e-300, 0.0, 0.0, -np.inf, -np.inf], [np.inf, np.inf, period, np.inf, np.inf])
    x_scale = [max(k0, 1e-12), max(a0, 1.0 / period), max(ts, initial.dead_time), 1.0, scale]
    fit = least_squares(residual, p0, bounds=(lower, upper), x_scale=x_scale, method='trf',
                        xtol=1e-10, ftol=1e-10, max_nfev=200)
    k, a, dead = float(fit.x[0]), float(fit.x[1]), float(fit.x[2])
    if force_ipdt or a * period < 1e-6:
        return IpdtModel(gain=k, dead_time=dead)
    return FopdtModel(gain=k / a, time_constant=1.0 / a, dead_time=dead)


# --------------------------------------------------------- describing function


def ku_describing_function(relay_amplitude: float, amplitude: float, hysteresis: float = 0.0) -> float:
    """Ultimate gain by the describing function, ``ku = 4·d/(π·a)`` ([DeadTimeNotes] eq. 6.22, [Precup2013] eq. 3.2.1).

    With hysteresis ε the relay's describing function is
    ``N(a) = 4d/(πa)·(√(1 − (ε/a)²) − j·ε/a)``; ``−1/N`` is then not on the negative real
    axis. The corrected estimate takes the gain that moves that point onto the axis,
    ``ku = 4·d/(π·√(a² − ε²))`` (still an approximation: ``ωc`` is not ``ωu``).
    """
    if relay_amplitude <= 0 or amplitude <= 0:
        raise ValueError('relay_amplitude, amplitude: must be positive')
    if hysteresis >= amplitude:
        raise ValueError(f'hysteresis: {hysteresis:g} must be below the output amplitude {amplitude:g}')
    return 4.0 * relay_amplitude / (math.pi * math.sqrt(amplitude ** 2 - hysteresis ** 2))


# ---------------------------------------------------- [Precup2013] §3.3 B, biased relay


@dataclass(frozen=True)
class RelayLimitCycle:
    """Exact limit cycle of FOPDT under a biased relay with hysteresis ([Precup2013] eq. 3.3.12).

    Relay output ``u0 + (μ + μ0)`` while the error exceeds ``+ε``, ``u0 − (μ − μ0)`` below ``−ε``.
    ``a_up``/``a_down``: output excursions above/below ``y0``; ``t_high`` (Tu1) / ``t_low`` (Tu2).
    """

    a_up: float
    a_down: float
    t_high: float
    t_low: float


def fopdt_relay_limit_cycle(model: FopdtModel, mu: float, mu0: float, hysteresis: float) -> RelayLimitCycle:
    """[Precup2013] eq. 3.3.12 (derived: ``y`` moves exponentially towards ``kP·u`` for ``L`` after each switch)."""
    kp, tc, tau, eps = model.gain, model.time_constant, model.dead_time / model.time_constant, hysteresis
    e = math.exp(-tau)
    a_up = (mu + mu0) * kp * (1 - e) + eps * e
    a_down = (mu - mu0) * kp * (1 - e) + eps * e
    t_high = tc * math.log((2 * mu * kp / e - (mu - mu0) * kp + eps) / ((mu + mu0) * kp - eps))
    t_low = tc * math.log((2 * mu * kp / e - (mu + mu0) * kp + eps) / ((mu - mu0) * kp - eps))
    return RelayLimitCycle(a_up, a_down, t_high, t_low)


def fopdt_from_biased_relay(mu: float, mu0: float, hysteresis: float, a_up: float,
                            t_high: float, gain: float) -> FopdtModel:
    """FOPDT from a biased hysteresis relay ([Precup2013] eqs. 3.3.14–3.3.17) given kP (3.3.13 or known).

    Normalised dead time ``τ = L/T = ln(((μ+μ0)·kP − ε)/((μ+μ0)·kP − A_u))`` (3.3.15),
    ``T = Tu1 / ln((2μ·kP·e^τ − (μ−μ0)·kP + ε)/((μ+μ0)·kP − ε))`` (3.3.17), ``L = τ·T`` (3.3.16).
    """
    hi = (mu + mu0) * gain
    if not (hi > a_up > hysteresis):
        raise ValueError('a_up: must lie between the hysteresis and (μ+μ0)·kP for [Precup2013] eq. 3.3.15')
    tau = math.log((hi - hysteresis) / (hi - a_up))
    tc = t_high / math.log((2 * mu * gain * math.exp(tau) - (mu - mu0) * gain + hysteresis) / (hi - hysteresis))
    return FopdtModel(gain=gain, time_constant=tc, dead_time=tau * tc)


# -------------------------------------- [Precup2013] §3.3 A, frequency points from the transient


def transient_response(t: np.ndarray, u: np.ndarray, y: np.ndarray, u0: float, y0: float,
                       omegas: Sequence[float], alpha: float, horizon: float,
                       smoothing: float = 0.0, integrating: bool = False) -> np.ndarray:
    """``G(jω)`` at ``omegas`` [rad/s] from one record of a test that starts at rest (``u0``,
    ``y0``), e.g. a relay test from its first switch to its stationary cycles ([Precup2013] eqs.
    3.3.1–3.3.10, Wang 1997).

    Both deviations are weighted by ``e^(−α·t)`` (3.3.1–3.3.2, ``alpha`` [1/s]) so that they
    have Fourier transforms; their DFTs (zero-padded to twice the record, so that the circular
    convolution is the linear one) give ``G(α + jω)`` at the bins (3.3.7), whose inverse DFT is
    the weighted pulse response ``e^(−α·k·Te)·h(k·Te)`` (3.3.8); ``h`` is unweighted (3.3.9) and
    cut after ``horizon`` [s] — the unweighting amplifies late errors, so keep it to where the
    true pulse response has died out — and transformed at ``omegas`` (3.3.10). The sampled
    record relates the held input to the sampled output; the hold's ``e^(−jωTe/2)·sinc(ωTe/2)``
    is divided out. ``t`` uniform [s].

    Ours (the document gives neither): ``smoothing`` [s] > 0 multiplies ``G(α + jω)`` by the
    Gaussian ``e^(−(ω·s)²/2)`` before 3.3.8 — a Gaussian lag window of standard deviation ``s``
    on the weighted pulse response, which removes the high-frequency noise that the division by
    the relay's ``1/ω`` spectrum amplifies — and divides the result by that window's exact
    transform at ``α − jω`` (so it costs no bias before the cut). ``integrating``: the output is
    differenced first (its pulse response then dies out after the dead time although the
    process integrates) and the result divided by ``1 − e^(−jωTe)``."""
    t = np.asarray(t, float)
    te = float(t[1] - t[0])
    if not (alpha > 0.0 and horizon > te and len(t) > 8 and smoothing >= 0.0):
        raise ValueError('transient_response: alpha > 0, horizon > one sample, smoothing >= 0 '
                         'and a record of more than 8 samples are needed')
    weight = np.exp(-alpha * (t - t[0]))
    yd = np.asarray(y, float) - y0
    if integrating:
        yd = np.diff(yd, prepend=0.0)
    du = (np.asarray(u, float) - u0) * weight
    dy = yd * weight
    n = 2 * len(t)
    uf, yf = np.fft.fft(du, n), np.fft.fft(dy, n)
    if np.min(np.abs(uf)) <= 1e-12 * np.max(np.abs(uf)):
        raise ValueError('transient_response: the weighted input has no energy at some '
                         'frequency (choose another alpha)')
    gf = yf / uf                                                        # 3.3.7
    m = 0
    if smoothing > 0.0:
        window = np.exp(-0.5 * (2.0 * np.pi * np.fft.fftfreq(n, te) * smoothing) ** 2)
        gf = gf * window
        kernel = np.real(np.fft.ifft(window))
        m = min(int(math.ceil(6.0 * smoothing / te)), n // 4)           # kernel's support
    h_weighted = np.real(np.fft.ifft(gf))                               # 3.3.8
    k = np.arange(-m, min(int(horizon / te) + 1, n // 2))               # negative lags: window
    h = h_weighted[k % n] * np.exp(alpha * k * te)                      # 3.3.9
    w = np.asarray(omegas, float)
    g = np.exp(-1j * np.outer(w, k) * te) @ h                           # 3.3.10
    if smoothing > 0.0:
        j = np.arange(-m, m + 1)
        g = g / (np.exp(np.outer(alpha - 1j * w, j) * te) @ kernel[j % n])
    if integrating:
        g = g / (1.0 - np.exp(-1j * w * te))
    hold = np.exp(-0.5j * w * te) * np.sinc(w * te / (2.0 * np.pi))
    return g / hold


# ------------------------------------------------- [DeadTimeNotes] §1.2.1, open-loop step test

STEP_METHODS = ('tangent', 'two_point')


def fopdt_from_step(t: np.ndarray, y: np.ndarray, y0: float, step: float,
                    method: str = 'tangent') -> FopdtModel:
    """FOPDT ``K·e^(−τ·s)/(T·s + 1)`` from an open-loop step response ([DeadTimeNotes] eq. 6.14).

    ``t`` [s] from the step (``t[0]`` = 0, uniform samples), ``y`` the response, ``y0`` the
    output at rest before the step, ``step`` the input change Δu. K = (final − y0)/Δu with the
    final value the mean of the last 10 % of the record. ``method``:

    * ``tangent`` ([DeadTimeNotes] eq. 6.15, Fig. 1.6): the tangent of steepest slope (slopes by least squares
      over a sliding window of 1 % of the record, at least 5 samples, against noise) meets the
      initial level at τ; its slope is K/T, so T = K/slope and a = slope·τ (per unit step);
    * ``two_point``: the times at 28.3 % and 63.2 % of the final change give
      T = 1.5·(t63 − t28), τ = t63 − T (Smith's two-point method for an FOPDT).

    Raises ``ValueError`` when the response did not move or has no rising part."""
    t = np.asarray(t, float)
    z = (np.asarray(y, float) - y0) / step            # unit-step response
    n = len(t)
    if n < 10 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(z))):
        raise ValueError('step record: at least 10 finite samples are needed')
    if method not in STEP_METHODS:
        raise ValueError(f'method: {method!r} is not a step method; allowed ' + ', '.join(STEP_METHODS))
    gain = float(np.mean(z[-max(n // 10, 1):]))
    if not gain > 0.0 or abs(gain * step) <= 0.0:
        raise ValueError('step record: the output did not move in the direction of the step')
    if method == 'two_point':
        def crossing(level: float) -> float:
            above = np.nonzero(z >= level * gain)[0]
            if len(above) == 0 or above[0] == 0:
                raise ValueError(f'step record: no crossing of {100 * level:.1f} % of the change')
            k = int(above[0])
            return float(t[k - 1] + (level * gain - z[k - 1]) / (z[k] - z[k - 1]) * (t[k] - t[k - 1]))
        t28, t63 = crossing(0.283), crossing(0.632)
        tc = 1.5 * (t63 - t28)
        return FopdtModel(gain=gain, time_constant=tc, dead_time=max(t63 - tc, 0.0))
    m = max(5, n // 100)
    kernel = np.arange(m) - 0.5 * (m - 1)
    dt = float(t[1] - t[0])
    slopes = np.convolve(z, kernel[::-1], mode='valid') / (dt * float(np.sum(kernel ** 2)))
    k = int(np.argmax(slopes))
    slope = float(slopes[k])
    if not slope > 0.0:
        raise ValueError('step record: no rising part for the tangent ([DeadTimeNotes] eq. 6.15)')
    centre = k + 0.5 * (m - 1)
    t_c = float(t[0] + centre * dt)
    z_c = float(np.mean(z[k:k + m]))
    tau = max(t_c - z_c / slope, 0.0)
    return FopdtModel(gain=gain, time_constant=gain / slope, dead_time=tau)


def step_identification(model: FopdtModel, step: float, method: str
                        ) -> 'RelayIdentification':
    """A step test's result in the form of a relay test's: the ultimate point and the responses
    at ωu and 3ωu are the model's (``model_method`` ``step_<method>``)."""
    ku, tu = model.ultimate_point()
    w = 2.0 * math.pi / tu
    return RelayIdentification(
        ku=ku, tu=tu, ku_model=ku, tu_model=tu, local_model=None, ku_df=ku, tu_df=tu,
        ku_fh=ku, tu_fh=tu, omega=w, g1=model.frequency_response(w),
        g3=model.frequency_response(3.0 * w), amplitude=0.0, relay_amplitude=abs(step),
        hysteresis=0.0, cycles=0, model=model, model_harmonic=model,
        model_method=f'step_{method}', static_gain=model.gain)


# ----------------------------------------------- [Precup2013] §3.5.2, SOPDT from two points


@dataclass(frozen=True)
class SopdtModel:
    """``G(s) = e^(−Tm·s)/(a·s² + b·s + c)`` ([Precup2013] eq. 3.5.8): static gain 1/c, ``dead_time``
    Tm [s], ``a`` [s²], ``b`` [s], ``c`` [-] per output unit/input unit. ``time_constant`` ≥
    ``time_constant2`` are the lags of ``a·s² + b·s + c = c·(T1·s + 1)(T2·s + 1)`` when its poles
    are real (NaN when they are complex: ``damping`` < 1)."""

    a: float
    b: float
    c: float
    dead_time: float
    kind: str = field(default='sopdt', init=False)

    @property
    def gain(self) -> float:
        return 1.0 / self.c

    @property
    def damping(self) -> float:
        """ζ = b/(2·√(a·c)) (infinite for a = 0: first order)."""
        root = math.sqrt(self.a * self.c)
        return self.b / (2.0 * root) if root > 0.0 else math.inf

    def _lags(self) -> tuple[float, float]:
        p, q = self.b / self.c, self.a / self.c          # T1 + T2, T1·T2
        disc = p * p - 4.0 * q
        if disc < 0.0:
            return math.nan, math.nan
        root = math.sqrt(disc)
        return 0.5 * (p + root), 0.5 * (p - root)

    @property
    def time_constant(self) -> float:
        return self._lags()[0]

    @property
    def time_constant2(self) -> float:
        return self._lags()[1]

    def frequency_response(self, omega: float) -> complex:
        s = 1j * omega
        return complex(np.exp(-self.dead_time * s) / (self.a * s * s + self.b * s + self.c))

    def as_dict(self) -> dict[str, float | str]:
        return {'kind': self.kind, 'gain': self.gain, 'time_constant': self.time_constant,
                'time_constant2': self.time_constant2, 'dead_time': self.dead_time,
                'a': self.a, 'b': self.b, 'c': self.c, 'damping': self.damping}


def sopdt_from_two_points(omega_1: float, g_1: complex, omega_2: float, g_2: complex
                          ) -> SopdtModel:
    """The SOPDT of [Precup2013] eq. 3.5.8 through two measured points ``G(jω1) = g_1``,
    ``G(jω2) = g_2`` ([Precup2013] §3.5.2, Wang 1999), frequencies in rad/s.

    With ``Z_i = e^(−jω_i·Tm)/G(jω_i) = c − a·ω_i² + j·b·ω_i``, Tm is the smallest positive root
    of ``Im Z_1/ω_1 = Im Z_2/ω_2`` and then ``b = Im Z_i/ω_i``,
    ``a = (Re Z_1 − Re Z_2)/(ω_2² − ω_1²)``, ``c = Re Z_1 + a·ω_1²``. At the document's two
    points (arg G = −π at ω_c, −π/2 at ω_b) these are eqs. 3.5.10–3.5.14 (Tm from
    ``sin(ω_c·Tm)/(ω_c·|G_c|) = cos(ω_b·Tm)/(ω_b·|G_b|)``); any two points of a true SOPDT
    return it exactly. Raises ``ValueError`` when no positive Tm below the smaller point's
    half period exists or the coefficients are not those of a stable, causal lag (a, b, c ≥ 0,
    b, c > 0)."""
    w1, w2 = float(omega_1), float(omega_2)
    if not (w1 > 0.0 and w2 > 0.0 and w1 != w2 and g_1 != 0 and g_2 != 0):
        raise ValueError('sopdt_from_two_points: two different positive frequencies with '
                         'non-zero responses are needed')

    def z(w: float, g: complex, tm: float) -> complex:
        return complex(np.exp(-1j * w * tm)) / g

    def gap(tm: float) -> float:
        return z(w1, g_1, tm).imag / w1 - z(w2, g_2, tm).imag / w2

    hi = math.pi / max(w1, w2)              # the rational part lags by less than π
    grid = np.linspace(0.0, hi, 400)
    values = np.array([gap(x) for x in grid])
    tm = None
    for k in range(1, len(grid)):
        if values[k - 1] * values[k] <= 0.0:
            tm = brentq(gap, grid[k - 1], grid[k], xtol=1e-14, rtol=1e-13)
            break
    if tm is None:
        # A first-order process makes Tm a double root (the gap touches zero: its linear
        # terms in Tm are equal at both points), so measurement error can lift the touching
        # point just above zero: take the closest approach if it is within 2 % of b.
        k = int(np.argmin(np.abs(values)))
        found = minimize_scalar(lambda x: abs(gap(x)), method='bounded',
                                bounds=(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]),
                                options={'xatol': 1e-12})
        tm = float(found.x)
        scale = abs(z(w1, g_1, tm).imag / w1)
        if not abs(gap(tm)) <= 0.02 * scale:
            raise ValueError('sopdt_from_two_points: no dead time fits both points '
                             '([Precup2013] eq. 3.5.10)')
    z1, z2 = z(w1, g_1, tm), z(w2, g_2, tm)
    b = 0.5 * (z1.imag / w1 + z2.imag / w2)
    a = (z1.real - z2.real) / (w2 * w2 - w1 * w1)
    c = z1.real + a * w1 * w1
    if c > 0.0 and -0.01 * b * b / c < a < 0.0:
        a = 0.0              # a first-order process measured with a little error
    if not (a >= 0.0 and b > 0.0 and c > 0.0):
        raise ValueError(f'sopdt_from_two_points: a = {a:.4g}, b = {b:.4g}, c = {c:.4g} are not '
                         'those of a stable second-order lag ([Precup2013] eq. 3.5.8)')
    return SopdtModel(a=a, b=b, c=c, dead_time=tm)


# ------------------------------------------------------------ whole analysis


@dataclass(frozen=True)
class LocalModel:
    """``G(s) = gain·e^(−dead_time·s)/(s + alpha)^order`` with a real ``order`` > 0.

    Used only to bridge the short distance from the relay frequency to the −180°
    point (:func:`anchored_ultimate_point`); ``alpha`` = 0 is an n-fold integrator.
    """

    gain: float
    alpha: float
    dead_time: float
    order: float
    kind: str = field(default='local', init=False)

    def frequency_response(self, omega: float) -> complex:
        s = 1j * omega
        return self.gain / (s + self.alpha) ** self.order * np.exp(-self.dead_time * s)

    def lag(self, omega: float) -> float:
        """Phase lag ``−arg G(jω)`` [rad], continuous in ω."""
        return self.order * math.atan2(omega, self.alpha) + omega * self.dead_time


def fit_local_model(omega: float, g1: complex, g3: complex) -> LocalModel | None:
    """``k·e^(−L·s)/(s + α)^n`` (n real) through both measured points ``G(jω)``, ``G(j3ω)`` ([Precup2013] eq. 3.3.19).

    Four real equations, four unknowns. With ``x = α/ω`` and ``R = |g1|/|g3|``:
    ``n = 2·ln R / ln((9 + x²)/(1 + x²))`` (magnitudes) and
    ``n·(arctan(3/x) − 3·arctan(1/x)) = 3·arg g1 − arg g3`` (phases; the dead time cancels,
    the 2π ambiguity of ``arg g3`` is resolved by taking the combination in (−2π, 0], i.e.
    n ≤ 2 in the lag-dominated limit). Then ``L = (−arg g1 − n·arctan(1/x))/ω`` and
    ``k = |g1|·(ω² + α²)^(n/2)``. Returns ``None`` when no root with 0.3 < n < 4 and
    L ≥ 0 exists (the caller then bridges with the FOPDT/IPDT fit); the limit
    ``x → 0`` gives the integrator ``α = 0``, ``n = ln R/ln 3``.
    """
    m1, m3 = abs(g1), abs(g3)
    if not (m1 > m3 > 0.0):
        return None
    ratio = math.log(m1 / m3)
    p1 = math.atan2(g1.imag, g1.real)
    if p1 > 0.0:
        p1 -= 2.0 * math.pi
    combo = 3.0 * p1 - math.atan2(g3.imag, g3.real)
    combo = combo - 2.0 * math.pi * math.ceil(combo / (2.0 * math.pi))     # into (−2π, 0]

    def order(x: float) -> float:
        return 2.0 * ratio / math.log((9.0 + x * x) / (1.0 + x * x))

    def gap(x: float) -> float:
        return order(x) * (math.atan(3.0 / x) - 3.0 * math.atan(1.0 / x)) - combo

    candidates: list[tuple[float, float]] = []
    xs = np.logspace(-4.0, 4.0, 161)
    gaps = [gap(x) for x in xs]
    for i in range(len(xs) - 1):
        if gaps[i] == 0.0 or gaps[i] * gaps[i + 1] < 0.0:
            x = brentq(gap, xs[i], xs[i + 1], xtol=1e-14, rtol=1e-12)
            candidates.append((x, order(x)))
    if not candidates and ratio > 0.0:
        candidates.append((0.0, ratio / math.log(3.0)))      # integrating limit
    best = None
    for x, n in candidates:
        lag = n * (math.pi / 2.0 if x == 0.0 else math.atan(1.0 / x))
        dead = (-p1 - lag) / omega
        if 0.3 < n < 4.0 and dead >= -1e-9 and (best is None or abs(n - 1.0) < abs(best[1] - 1.0)):
            best = (x, n, max(dead, 0.0))
    if best is None:
        return None
    x, n, dead = best
    alpha = x * omega
    return LocalModel(gain=m1 * (omega ** 2 + alpha ** 2) ** (n / 2.0), alpha=alpha, dead_time=dead, order=n)


def _lag(model: Model | LocalModel, omega: float) -> float:
    if isinstance(model, LocalModel):
        return model.lag(omega)
    if isinstance(model, IpdtModel):
        return math.pi / 2.0 + omega * model.dead_time
    return model.order * math.atan(omega * model.time_constant) + omega * model.dead_time


def anchored_ultimate_point(model: Model | LocalModel, omega: float, g1: complex) -> tuple[float, float]:
    """Ultimate point of the true plant, using ``model`` only to bridge from ``ωc`` to ``ωu``.

    The measured ``g1 = G(jωc)`` is exact for any linear plant; the model supplies the
    local shape: with ``Δφ = arg g1 − arg G_M(jωc)`` and ``ρ = |g1|/|G_M(jωc)|`` (both 0/1
    when the model passes through ``g1``), ``ωu`` solves ``arg G_M(jω) + Δφ = −π`` and
    ``ku = 1/(ρ·|G_M(jωu)|)``, ``tu = 2π/ωu``.
    """
    gm = model.frequency_response(omega)
    dphi = math.remainder(math.atan2(g1.imag, g1.real) - math.atan2(gm.imag, gm.real), 2.0 * math.pi)
    rho = abs(g1) / abs(gm)

    def gap(w: float) -> float:
        return _lag(model, w) - dphi - math.pi

    lo, hi = omega, omega
    while gap(lo) > 0.0 and lo > 1e-9 * omega:
        lo *= 0.5
    while gap(hi) < 0.0 and hi < 1e9 * omega:
        hi *= 2.0
    if gap(lo) > 0.0 or gap(hi) < 0.0:
        raise ValueError('model: no phase crossover near the relay frequency')
    wu = brentq(gap, lo, hi, xtol=1e-14 * omega, rtol=1e-13)
    return float(1.0 / (rho * abs(model.frequency_response(wu)))), float(2.0 * math.pi / wu)


@dataclass(frozen=True)
class RelayIdentification:
    """Result of :func:`identify_relay`.

    ``ku``/``tu``: the accurate ultimate point (first harmonic, corrected to the −180°
    point along ``local_model``, or along ``model`` when the local fit has no solution);
    ``ku_model``/``tu_model``: the same correction along ``model``; ``ku_df``/``tu_df``:
    describing function (with the hysteresis correction) and mean period;
    ``ku_fh``/``tu_fh``: the uncorrected first-harmonic point ``1/|G(jωc)|``, ``2π/ωc``.
    ``omega`` = ωc [rad/s], ``g1``/``g3`` = ``G(jωc)``, ``G(j3ωc)``; ``amplitude``: mean
    half peak-to-peak of ``y``; ``relay_amplitude``: half the span of ``u``; ``model``:
    the FOPDT/IPDT for model-based tuning, by ``model_method``: ``'eq_3_3_15'`` (a biased
    relay with a static gain: [Precup2013] eqs. 3.3.14–3.3.17 from the asymmetric limit cycle),
    ``'eq_3_6_2'`` (a static gain is known: [Precup2013] eq. 3.6.2 through ``ku``, ``tu``) or
    ``'time_domain'`` (:func:`fit_time_domain`); ``model_harmonic``: from ``g1``, ``g3``/kP
    only (its start); ``static_gain``: kP supplied or from [Precup2013] eq. 3.3.13 (biased relay), else
    ``None``; ``relay_bias``: μ0, the mean of the two relay outputs minus ``u0`` (0 for a
    symmetric relay); ``point_2``: a second measured point ``(ω, G(jω))`` — the relay with an
    integrator's or the additional relay's 0.5·ωc (set by the auto-tuner).
    """

    ku: float
    tu: float
    ku_model: float
    tu_model: float
    local_model: LocalModel | None
    ku_df: float
    tu_df: float
    ku_fh: float
    tu_fh: float
    omega: float
    g1: complex
    g3: complex
    amplitude: float
    relay_amplitude: float
    hysteresis: float
    cycles: int
    model: Model | SopdtModel        # the relay tuner's two-point SOPDT replaces the FOPDT
    model_harmonic: Model
    model_method: str
    static_gain: float | None
    relay_bias: float = 0.0
    point_2: tuple[float, complex] | None = None


def _integrating(model: Model, period: float) -> Model:
    """An FOPDT whose time constant exceeds 50 periods is reported as the IPDT it behaves like."""
    if isinstance(model, FopdtModel) and model.time_constant > 50.0 * period:
        return IpdtModel(gain=model.gain / model.time_constant, dead_time=model.dead_time)
    return model


def identify_relay(t: np.ndarray, u: np.ndarray, y: np.ndarray, u0: float, y0: float,
                   hysteresis: float = 0.0, cycles: Sequence[RelayCycle] | None = None,
                   gain: float | None = None, kind: str = 'auto',
                   refine: bool = True) -> RelayIdentification:
    """Ultimate point and model from a relay record ([DeadTimeNotes] §1.3; [Precup2013] §3.2–3.3, 3.6).

    Steps: ``G(jωc)``, ``G(j3ωc)`` by Fourier over the cycles; FOPDT/IPDT through them
    (:func:`fit_first_order_delay`), refined on the samples (:func:`fit_time_domain`);
    ``ku``, ``tu`` by :func:`anchored_ultimate_point` along :func:`fit_local_model`
    (or the refined model when the local one has no solution); with a static gain the
    reported FOPDT is [Precup2013] eq. 3.6.2 through ``ku``, ``tu``.

    ``t, u, y``: the record from the relay start (loop at rest at ``u0``, ``y0``),
    uniformly sampled. ``cycles``: the stationary cycles to use (consecutive, from
    :func:`relay_cycles`); default: all complete cycles after the first one. ``gain``:
    known static gain kP (else [Precup2013] eq. 3.3.13 if the relay is biased). ``kind``:
    'auto', 'fopdt' or 'ipdt'. ``refine``: run the time-domain fit.
    Raises ``ValueError`` with a reason when the record cannot be analysed.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise ValueError('record: non-finite samples')
    if cycles is None:
        found = relay_cycles(t, u, y, u0)
        cycles = found[1:] if len(found) > 1 else found
    if not cycles:
        raise ValueError('record: no complete relay cycle')
    start, end, n = cycles[0].start, cycles[-1].end, len(cycles)
    wc, g = harmonic_response(t, u, y, start, end, n, (1, 3))
    seg_u = u[start:end]
    relay_amp = 0.5 * (float(seg_u.max()) - float(seg_u.min()))
    amp = float(np.mean([0.5 * (c.y_max - c.y_min) for c in cycles]))
    eps = min(hysteresis, 0.99 * amp)
    kp = gain if gain is not None else static_gain(t, u, y, start, end, u0, y0)
    if kp is not None and kp <= 0:
        kp = None
    period = 2.0 * math.pi / wc
    keep = (lambda m: m) if kind == 'fopdt' else (lambda m: _integrating(m, period))  # noqa: E731
    harmonic = keep(fit_first_order_delay(wc, g[1], g[3], kp, kind))
    model, method = harmonic, 'harmonic'
    if refine:
        model, method = keep(fit_time_domain(t, u, y, start, end, u0, harmonic, kind)), 'time_domain'
    ku_model, tu_model = anchored_ultimate_point(model, wc, g[1])
    local = fit_local_model(wc, g[1], g[3])
    ku, tu = anchored_ultimate_point(local, wc, g[1]) if local is not None else (ku_model, tu_model)
    mu, mu0 = 0.5 * (float(seg_u.max()) - float(seg_u.min())), \
        0.5 * (float(seg_u.max()) + float(seg_u.min())) - u0
    biased = abs(mu0) > 0.02 * mu
    if kp is not None and kind != 'ipdt' and isinstance(harmonic, FopdtModel) and biased:
        a_up = float(np.mean([c.y_max for c in cycles])) - y0
        t_high = float(np.mean([c.high_time for c in cycles]))
        model, method = fopdt_from_biased_relay(mu, mu0, eps, a_up, t_high, kp), 'eq_3_3_15'
    elif kp is not None and kind != 'ipdt' and kp * ku > 1.0:
        model, method = fopdt_from_ultimate(ku, tu, kp, order=1), 'eq_3_6_2'
    return RelayIdentification(
        ku=ku, tu=tu, ku_model=ku_model, tu_model=tu_model, local_model=local,
        ku_df=ku_describing_function(relay_amp, amp, eps),
        tu_df=float(np.mean([c.period for c in cycles])),
        ku_fh=1.0 / abs(g[1]), tu_fh=period, omega=wc, g1=g[1], g3=g[3],
        amplitude=amp, relay_amplitude=relay_amp, hysteresis=hysteresis, cycles=n,
        model=model, model_harmonic=harmonic, model_method=method, static_gain=kp,
        relay_bias=mu0 if biased else 0.0)
