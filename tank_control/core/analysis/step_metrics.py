"""Step-response and error-integral metrics of recorded (sampled) signals.

``t`` in s (strictly increasing), signals in the units of the measured output; noisy data and
steps in either direction are accepted (responses are normalised by the signed step size).
:func:`iae` ∫|e| dt [unit·s] and :func:`ise` ∫e² dt [unit²·s] (trapezoidal rule);
:func:`noise_std` the white measurement noise of a record, estimated robustly;
:func:`step_metrics` overshoot [%], 10–90 % rise time [s], ±2 % settling time [s],
steady-state error, peak, read through that noise (docs/harness.md, "Measurement noise");
:func:`deviation_metrics` for an error that should stay at 0 (a load change, a coupling):
peak error and time, IAE, ∫e dt ([Viteckova] eq. 10 for a load step), recovery time into ±2 % of the
peak, final and initial error.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


def _as_arrays(t, *signals) -> tuple[np.ndarray, ...]:
    t = np.asarray(t, dtype=float).reshape(-1)
    out = [t]
    for s in signals:
        arr = np.asarray(s, dtype=float).reshape(-1)
        if arr.shape != t.shape:
            raise ValueError(f'signal has {arr.size} samples, t has {t.size}')
        out.append(arr)
    if t.size < 2:
        raise ValueError(f't: need at least 2 samples, got {t.size}')
    if np.any(np.diff(t) <= 0):
        raise ValueError('t: sample times must be strictly increasing')
    return tuple(out)


def _trapz(t: np.ndarray, f: np.ndarray) -> float:
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))


def iae(t, e) -> float:
    """Integral of the absolute error ∫|e(t)| dt [unit·s] (trapezoidal)."""
    t, e = _as_arrays(t, e)
    return _trapz(t, np.abs(e))


def ise(t, e) -> float:
    """Integral of the squared error ∫e(t)² dt [unit²·s] (trapezoidal)."""
    t, e = _as_arrays(t, e)
    return _trapz(t, e * e)


#: Normal consistency factor of the median absolute deviation (σ = 1.4826 · MAD).
_MAD_TO_STD = 1.482602218505602
#: Smoothed noise (σ_s) allowed inside the settling band: band ≥ SETTLE_K · σ_s.
SETTLE_K = 4.0


def noise_std(y) -> float:
    """Standard deviation [unit] of white measurement noise on the record ``y``, estimated from
    its second differences d_k = y_{k+1} − 2 y_k + y_{k−1}: for white noise of σ they have
    σ·√6, while a smooth response adds only its curvature (≈ 0 between its rare kinks).
    σ̂ = 1.4826 · median|d − median d| / √6, so a step or a kink in a few samples does not
    count. 0 for fewer than 5 finite samples or a noise-free record."""
    y = np.asarray(y, dtype=float).reshape(-1)
    y = y[np.isfinite(y)]
    if y.size < 5:
        return 0.0
    d = y[2:] - 2.0 * y[1:-1] + y[:-2]
    return float(_MAD_TO_STD * np.median(np.abs(d - np.median(d))) / math.sqrt(6.0))


#: The moving average spans at most this fraction of the raw first-crossing 10–90 % rise time.
CAP_FRACTION = 0.25


def _first_rise(t: np.ndarray, z: np.ndarray) -> float:
    """Time from the first sample at or beyond 0.1 to the first at or beyond 0.9 (noise makes
    both early, so it does not overstate the rise); 0 if 0.9 is never reached."""
    above10 = np.nonzero(z >= 0.1)[0]
    above90 = np.nonzero(z >= 0.9)[0]
    if above90.size == 0:
        return 0.0
    return float(t[above90[0]] - t[above10[0]])


def _smooth(z: np.ndarray, w: int) -> np.ndarray:
    """Centred moving average over ``w`` (odd) samples; the window shrinks at the ends."""
    if w <= 1:
        return z
    half = w // 2
    c = np.concatenate(([0.0], np.cumsum(z)))
    i = np.arange(z.size)
    lo = np.maximum(i - half, 0)
    hi = np.minimum(i + half + 1, z.size)
    return (c[hi] - c[lo]) / (hi - lo)


class _Metrics:
    def as_dict(self) -> dict[str, float]:
        """The metrics by field name."""
        return asdict(self)  # type: ignore[call-overload]


@dataclass(frozen=True)
class StepMetrics(_Metrics):
    """Metrics of a response to a setpoint step (units in the field comments).

    ``overshoot``: (peak beyond the final setpoint) / |step| · 100 [%], ≥ 0.
    ``rise_time``: time from 10 % to 90 % of the step [s]; NaN if 90 % is never reached.
    ``settling_time``: time after the step after which the response stays within
    ``band``·|step| of the final setpoint [s]; NaN if it never settles.
    ``steady_state_error``: final setpoint − mean output over the final window [unit].
    ``peak``: extreme output in the step direction [unit]; ``peak_time`` [s] after the step.
    ``noise``: the measurement noise σ the metrics allowed for [unit] (0: none);
    ``smoothing``: samples of the moving average read (1: the raw record);
    ``band``: the settling band used, as a fraction of |step| (≥ the band asked for).
    """

    overshoot: float
    rise_time: float
    settling_time: float
    steady_state_error: float
    peak: float
    peak_time: float
    noise: float = 0.0
    smoothing: int = 1
    band: float = 0.02


def _interp(t: np.ndarray, z: np.ndarray, level: float, i: int) -> float:
    """Time where z crosses ``level`` between samples i-1 and i (linear)."""
    if i <= 0:
        return float(t[0])
    z0, z1 = z[i - 1], z[i]
    if z1 == z0:
        return float(t[i])
    return float(t[i - 1] + (level - z0) / (z1 - z0) * (t[i] - t[i - 1]))


def _level_time(t: np.ndarray, z: np.ndarray, level: float, i_peak: int) -> float:
    """Time the rising part (up to the peak) of z passes ``level``: the mean of
    the first upward crossing and the last crossing before the peak (equal for
    noise-free data; an unbiased estimate under symmetric noise). NaN if never."""
    rising = z[:i_peak + 1]
    above = np.nonzero(rising >= level)[0]
    if above.size == 0:
        return math.nan
    first = _interp(t, z, level, int(above[0]))
    below = np.nonzero(rising < level)[0]
    if below.size == 0:
        return first
    last = _interp(t, z, level, int(below[-1]) + 1)
    return 0.5 * (first + last)


def step_metrics(t, y, r_final: float, y0: float | None = None, t_step: float | None = None,
                 band: float = 0.02, final_window: float = 0.1,
                 noise: float = 0.0) -> StepMetrics:
    """Step-response metrics of output ``y`` for a setpoint change to ``r_final``.

    t, y: samples [s], [unit]. ``t_step``: instant of the setpoint change
    (default ``t[0]``); samples before it are ignored. ``y0``: output before
    the step (default: ``y`` at ``t_step``). ``band``: settling band as a
    fraction of |r_final − y0| (default 2 %). ``final_window``: fraction of
    the record after the step averaged for the steady state (default 10 %).
    ``noise``: σ of white measurement noise on ``y`` [unit] (e.g. :func:`noise_std`
    of the whole record; default 0: read the raw record).

    The response is normalised as z = (y − y0)/(r_final − y0), so steps in
    either direction are handled alike. Each of the 10 % and 90 % instants is
    the mean of the first and the last crossing of that level before the peak,
    so noise that wanders across a level does not bias the rise time.

    With noise of relative size n = σ/|step| above band/SETTLE_K, the metrics are read
    on z smoothed by a centred moving average of w samples, w the smallest with
    SETTLE_K·n/√w ≤ band, but spanning at most a quarter of the time from the first
    sample beyond 10 % to the first beyond 90 % (so the average does not flatten the
    response); the smoothed noise is σ_s = n/√w. The overshoot is the peak of the
    smoothed z above 1, counted only when it exceeds σ_s·√(2 ln(N/w)) (N samples: the
    level that noise alone stays below); the settling band is max(band, SETTLE_K·σ_s).
    Without noise (w = 1, σ_s = 0) these are the raw-record definitions.
    """
    t, y = _as_arrays(t, y)
    t_step = float(t[0]) if t_step is None else float(t_step)
    keep = t >= t_step - 1e-12
    if keep.sum() < 2:
        raise ValueError(f't_step: {t_step} leaves fewer than 2 samples')
    t, y = t[keep], y[keep]
    y0 = float(y[0]) if y0 is None else float(y0)
    step = float(r_final) - y0
    if step == 0.0 or not math.isfinite(step):
        raise ValueError(f'r_final: {r_final} gives no step from y0 = {y0}')
    if not (math.isfinite(noise) and noise >= 0.0):
        raise ValueError(f'noise: {noise} must be finite and >= 0')
    z = (y - y0) / step
    n_final = max(1, int(round(final_window * len(y))))
    sse = float(r_final - np.mean(y[-n_final:]))

    rel = noise / abs(step)
    w = 1
    if rel * SETTLE_K > band:
        w = math.ceil((SETTLE_K * rel / band) ** 2)
        dt = float(np.median(np.diff(t)))
        cap = int(CAP_FRACTION * _first_rise(t, z) / dt) or len(z) // 20
        w = max(1, min(w, cap, len(z)))
        w -= 1 - w % 2                      # odd: centred
    zs = _smooth(z, w)
    sigma_s = rel / math.sqrt(w)

    i_peak = int(np.argmax(zs))
    beyond = float(zs[i_peak]) - 1.0
    # the universal threshold: m independent samples of noise σ_s stay below σ_s·√(2 ln m)
    threshold = sigma_s * math.sqrt(2.0 * math.log(max(len(zs) / w, 2.0)))
    overshoot = beyond * 100.0 if beyond > threshold else 0.0

    t10 = _level_time(t, zs, 0.1, i_peak)
    t90 = _level_time(t, zs, 0.9, i_peak)
    rise = t90 - t10

    band_used = max(band, SETTLE_K * sigma_s)
    outside = np.nonzero(np.abs(zs - 1.0) > band_used)[0]
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == len(zs) - 1:
        settling = math.nan
    else:
        settling = float(t[outside[-1] + 1] - t_step)
    return StepMetrics(overshoot=overshoot, rise_time=rise, settling_time=settling,
                       steady_state_error=sse,
                       peak=float(y[i_peak] if w == 1 else y0 + step * zs[i_peak]),
                       peak_time=float(t[i_peak] - t_step), noise=float(noise), smoothing=w,
                       band=band_used)


@dataclass(frozen=True)
class DeviationMetrics(_Metrics):
    """Response of an error e = r − y to an event that should leave it at 0.

    ``peak_error``: max |e| [unit]; ``peak_signed``: e at that instant (e > 0: output
    below its setpoint); ``peak_time``: when, after ``t[0]`` [s].
    ``iae`` ∫|e| dt and ``integral_error`` ∫e dt [unit·s] (trapezoidal).
    ``recovery_time``: time after ``t[0]`` after which |e| stays within
    ``band``·peak_error [s]; 0 if e never leaves it, NaN if it has not by the end.
    ``final_error``: mean e over the final window [unit]; ``initial_error``: e at ``t[0]``
    [unit] (an output still moving from an earlier event carries that into the window).
    """

    peak_error: float
    peak_signed: float
    peak_time: float
    iae: float
    integral_error: float
    recovery_time: float
    final_error: float
    initial_error: float


def deviation_metrics(t, e, band: float = 0.02, final_window: float = 0.1,
                      noise: float = 0.0) -> DeviationMetrics:
    """Peak, integrals and recovery of the error ``e`` [unit] over ``t`` [s] (from ``t[0]``,
    the event). ``band``: recovery band as a fraction of the peak |e| (default 2 %, the
    settling band of :func:`step_metrics`); ``final_window``: fraction of the record
    averaged for ``final_error``; ``noise``: σ of white measurement noise on e [unit]: the
    recovery band is max(band·peak, SETTLE_K·noise) (read on the raw record)."""
    t, e = _as_arrays(t, e)
    i = int(np.argmax(np.abs(e)))
    peak = float(abs(e[i]))
    outside = np.nonzero(np.abs(e) > max(band * peak, SETTLE_K * noise))[0]
    if outside.size == 0:
        recovery = 0.0
    elif outside[-1] == len(e) - 1:
        recovery = math.nan
    else:
        recovery = float(t[outside[-1] + 1] - t[0])
    n_final = max(1, int(round(final_window * len(e))))
    return DeviationMetrics(peak_error=peak, peak_signed=float(e[i]), peak_time=float(t[i] - t[0]),
                            iae=_trapz(t, np.abs(e)), integral_error=_trapz(t, e),
                            recovery_time=recovery, final_error=float(np.mean(e[-n_final:])),
                            initial_error=float(e[0]))
