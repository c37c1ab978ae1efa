"""Control performance indices from routine closed-loop data (pure numpy; no rclpy).

* :func:`harris_index` — the minimum-variance benchmark [Harris1989] [Desborough1992]: an AR
  model of the control error, its first ``b`` impulse-response terms (``b`` = the loop's dead time
  in samples) give the variance no controller could remove; index = that variance over the
  mean-square error (offset included), in [0, 1], 1 = minimum variance.
* :func:`oscillation` — regularity of the zero crossings of the autocorrelation function
  [Thornhill2003]: ``r = mean(Tp) / (3·std(Tp))`` of the periods ``Tp`` read from successive
  zero crossings; a regular oscillation has ``r > 1``.
* :func:`load_disturbances` — Hägglund's IAE between zero crossings of the error, counted with
  forgetting [Hagglund1995] (with an acceptable amplitude and the integral time given).
* :func:`stiction` — the cross-correlation test of [Horch1999]: in a loop oscillating because of
  a sticky valve (integrating controller, self-regulating process) the cross-correlation of the
  controller output and the process output is odd (zero at lag 0); in one oscillating because
  of tuning or an external disturbance it is even (extreme at lag 0). Index
  ``1 − |r_uy(0)| / max|r_uy(τ)|`` over ``|τ| <= period/2``: 1 odd, 0 even.
* :func:`saturation_pct`, :func:`setpoint_iae` — plain counts and integrals.

Every function takes 1-D arrays of equal length, sampled every ``sample_time`` [s], finite
values only (the caller drops the rest: :func:`finite_rows`).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np


def finite_rows(*columns: np.ndarray) -> tuple[np.ndarray, ...]:
    """The rows where every column is finite."""
    arrays = [np.asarray(c, dtype=float) for c in columns]
    keep = np.ones(len(arrays[0]), dtype=bool)
    for a in arrays:
        keep &= np.isfinite(a)
    return tuple(a[keep] for a in arrays)


def regulatory_segments(t: np.ndarray, r: np.ndarray, settle: float, min_length: int = 20,
                        tol: float = 1e-9, start_is_change: bool = False) -> list[slice]:
    """The stretches of constant setpoint, each without its first ``settle`` [s] after a change
    (the setpoint response is not regulation); stretches shorter than ``min_length`` samples are
    dropped. The start of the record is not a change (data taken from a running loop), unless
    ``start_is_change`` (the loop's own start: its first response is not regulation either)."""
    if t.size == 0:
        return []
    scale = max(float(np.max(np.abs(r))), 1.0)
    changes = np.flatnonzero(np.abs(np.diff(r)) > tol * scale) + 1
    bounds = [0, *changes.tolist(), t.size]
    out = []
    for n, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        start = (a if n == 0 and not start_is_change
                 else int(np.searchsorted(t, t[a] + settle - 1e-9)))
        if b - start >= min_length:
            out.append(slice(start, b))
    return out


def dead_time_samples(dead_time: float, sample_time: float) -> int:
    """``b``: the samples before the control action can affect the output, the dead time
    ``floor(L/Ts)`` plus the one sample of the zero-order hold."""
    return int(math.floor(max(dead_time, 0.0) / sample_time + 1e-9)) + 1


def ar_fit(x: np.ndarray | list[np.ndarray], order: int) -> tuple[np.ndarray, float]:
    """Least-squares AR(order) ``x_k = Σ a_i·x_{k−i} + ε_k`` of the mean-removed ``x`` (or of
    several records, each mean-removed, fitted jointly): coefficients ``a`` and the innovation
    variance."""
    parts = [x] if isinstance(x, np.ndarray) else list(x)
    blocks, targets = [], []
    for part in parts:
        p = np.asarray(part, dtype=float) - float(np.mean(part))
        n = p.size
        if n <= order:
            continue
        blocks.append(np.column_stack([p[order - i - 1:n - i - 1] for i in range(order)]))
        targets.append(p[order:])
    rows, target = np.vstack(blocks), np.concatenate(targets)
    # the normal equations (an SVD least squares costs ~100x more on a long window, live)
    try:
        a = np.linalg.solve(rows.T @ rows, rows.T @ target)
    except np.linalg.LinAlgError:
        a, *_ = np.linalg.lstsq(rows, target, rcond=None)
    resid = target - rows @ a
    return a, float(np.mean(resid ** 2))


def impulse_response(a: np.ndarray, length: int) -> np.ndarray:
    """The first ``length`` terms ψ of ``1/(1 − Σ a_i q^−i)`` (ψ_0 = 1)."""
    psi = np.zeros(length)
    psi[0] = 1.0
    for k in range(1, length):
        m = min(k, a.size)
        psi[k] = float(np.dot(a[:m], psi[k - 1::-1][:m]))
    return psi


#: innovation variance / mean square of the error below which it is taken as deterministic
DETERMINISTIC = 1e-5


def harris_index(error: np.ndarray | list[np.ndarray], b: int, order: int = 20
                 ) -> float | None:
    """Minimum-variance variance over mean-square error, in [0, 1] ([Desborough1992]), of one
    record or several (stretches of constant setpoint: one AR model fitted to them all); None
    with fewer than ``10·order`` samples, a constant error, or one predictable a sample ahead
    (innovation variance below ``DETERMINISTIC`` × its mean square: no random disturbance in
    the data, e.g. a noise-free simulation, which no benchmark of variance applies to)."""
    parts = [np.asarray(p, dtype=float) for p in
             ([error] if isinstance(error, np.ndarray) else error) if len(p) > order + 1]
    if not parts:
        return None
    e = np.concatenate(parts)
    if e.size < max(10 * order, 50):
        return None
    mse = float(np.mean(e ** 2))
    if mse <= 1e-300 or float(np.var(e)) <= 1e-12 * mse:
        return None
    a, sigma2 = ar_fit(parts, order)
    if sigma2 < DETERMINISTIC * mse:
        return None
    psi = impulse_response(a, max(b, 1))
    mv = sigma2 * float(np.sum(psi ** 2))
    return float(min(max(mv / mse, 0.0), 1.0))


def acf(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Autocorrelation of the mean-removed ``x`` at lags 0..max_lag (biased estimate)."""
    x = np.asarray(x, dtype=float) - float(np.mean(x))
    n = x.size
    var = float(np.dot(x, x))
    if var <= 0.0:
        return np.zeros(max_lag + 1)
    spec = np.fft.rfft(x, 2 * n)
    full = np.fft.irfft(spec * np.conj(spec), 2 * n)[:max_lag + 1]
    return full / var


def ccf(u: np.ndarray, y: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Cross-correlation ``r_uy(τ) = Σ u_{k}·y_{k+τ} / (n·σ_u·σ_y)`` for τ in
    −max_lag..max_lag (mean-removed): lags and values."""
    u = np.asarray(u, dtype=float) - float(np.mean(u))
    y = np.asarray(y, dtype=float) - float(np.mean(y))
    n = u.size
    norm = math.sqrt(float(np.dot(u, u)) * float(np.dot(y, y)))
    lags = np.arange(-max_lag, max_lag + 1)
    if norm <= 0.0:
        return lags, np.zeros(lags.size)
    values = np.array([float(np.dot(u[max(0, -k):n - max(0, k)], y[max(0, k):n - max(0, -k)]))
                       for k in range(-max_lag, max_lag + 1)]) / norm
    return lags, values


def oscillation(x: np.ndarray, sample_time: float, regularity_limit: float = 1.0,
                peak_limit: float = 0.2, min_intervals: int = 4) -> dict[str, Any]:
    """Regular oscillation of ``x`` by the ACF zero crossings [Thornhill2003]:
    ``detected`` (regularity above ``regularity_limit``, a period of at least 4 samples and the
    ACF's first peak after lag 0, ``acf_peak``, above ``peak_limit``: a filtered noise's ACF
    crosses zero regularly too, but its peaks are small), ``period`` [s], ``amplitude``
    (√2·standard deviation: the equivalent sinusoid's), ``regularity`` r. Needs
    ``min_intervals`` intervals between crossings."""
    x = np.asarray(x, dtype=float)
    out: dict[str, Any] = {'detected': False, 'period': None, 'amplitude': None,
                           'regularity': None, 'acf_peak': None}
    if x.size < 20 or float(np.std(x)) <= 0.0:
        return out
    r = acf(x, x.size // 2)
    sign = np.signbit(r)
    crossings = np.flatnonzero(sign[1:] != sign[:-1]) + 1
    crossings = crossings[:min_intervals + 3]
    if crossings.size < min_intervals + 1:
        return out
    # interpolated crossing lags
    z = np.array([c - 1 + r[c - 1] / (r[c - 1] - r[c]) for c in crossings])
    periods = 2.0 * np.diff(z)
    mean, std = float(np.mean(periods)), float(np.std(periods))
    regularity = mean / (3.0 * std) if std > 0.0 else math.inf
    peak = float(np.max(r[crossings[1]:crossings[2] + 1]))   # between 2nd and 3rd crossing
    out['regularity'] = float(min(regularity, 1e6))
    out['acf_peak'] = peak
    out['period'] = mean * sample_time
    out['amplitude'] = math.sqrt(2.0) * float(np.std(x))
    out['detected'] = bool(regularity > regularity_limit and mean >= 4.0 and peak > peak_limit)
    return out


def load_disturbances(e: np.ndarray, sample_time: float, amplitude: float, ti: float,
                      n_lim: float = 10.0) -> dict[str, Any]:
    """Hägglund's load-disturbance counting [Hagglund1995]: the IAE of the error between
    successive zero crossings; one above ``IAE_lim = 2a/ω_u`` (acceptable amplitude ``a``,
    ``ω_u ≈ 2π/Ti``) is a load disturbance; counted with exponential forgetting over
    ``T_sup = 50·Ti``, more than ``n_lim`` means an oscillation. ``count`` (in the record),
    ``rate`` (the forgetting counter at its end), ``detected`` (the counter exceeded ``n_lim``
    at some time); all None/False when ``a`` or ``Ti`` is 0."""
    out: dict[str, Any] = {'count': None, 'rate': None, 'detected': False}
    if amplitude <= 0.0 or ti <= 0.0 or e.size < 2:
        return out
    iae_lim = amplitude * ti / math.pi                 # 2a/ω_u with ω_u = 2π/Ti
    gamma = 1.0 - sample_time / (50.0 * ti)
    sign = np.signbit(e)
    crossings = np.flatnonzero(sign[1:] != sign[:-1]) + 1
    iae = np.add.reduceat(np.abs(e), np.r_[0, crossings]) * sample_time
    ends = np.r_[crossings, e.size]                  # the sample closing each half-wave
    hits = ends[1:-1][iae[1:-1] > iae_lim]           # whole half-waves only
    counter, last, peak = 0.0, 0, 0.0
    for k in hits:
        counter = counter * gamma ** (k - last) + 1.0
        last = int(k)
        peak = max(peak, counter)
    out['count'] = int(hits.size)
    out['rate'] = float(counter * gamma ** (e.size - last))
    out['detected'] = bool(peak > n_lim)
    return out


def stiction(u: np.ndarray, y: np.ndarray, period_samples: float) -> float | None:
    """Horch's odd/even test as an index in [0, 1] ([Horch1999]): ``1 − |r_uy(0)| /
    max|r_uy(τ)|`` over ``|τ| <= period/2``; near 1 (odd) suggests stiction, near 0 (even)
    tuning or an external oscillation. None without a period or with a constant signal."""
    if not period_samples or not math.isfinite(period_samples):
        return None
    half = max(int(round(period_samples / 2.0)), 1)
    if u.size < 4 * half or float(np.std(u)) <= 0.0 or float(np.std(y)) <= 0.0:
        return None
    lags, values = ccf(u, y, half)
    peak = float(np.max(np.abs(values)))
    if peak <= 0.0:
        return None
    return float(1.0 - abs(values[half]) / peak)


def saturation_pct(u: np.ndarray, u_min: float, u_max: float) -> float | None:
    """Percentage of samples at or beyond a limit (within 1e-6 of its magnitude, at least
    1e-6); a limit of magnitude 1e11 or more (the parameters' "no limit", 1e12) counts as none;
    None without a limit."""
    lows = [lim for lim in (u_min,) if math.isfinite(lim) and abs(lim) < NO_LIMIT]
    highs = [lim for lim in (u_max,) if math.isfinite(lim) and abs(lim) < NO_LIMIT]
    if not (lows or highs) or u.size == 0:
        return None
    at = np.zeros(u.shape, dtype=bool)
    for lim in lows:
        at |= u <= lim + 1e-6 * max(abs(lim), 1.0)
    for lim in highs:
        at |= u >= lim - 1e-6 * max(abs(lim), 1.0)
    return 100.0 * float(np.mean(at))


NO_LIMIT = 1e11
"""[input units] a limit this large or larger is the parameters' way of saying "none"."""


def setpoint_iae(t: np.ndarray, r: np.ndarray, y: np.ndarray, tol: float = 1e-9
                 ) -> list[dict[str, float]]:
    """Per setpoint change: its time [s], ``from``/``to`` and the IAE of ``r − y`` from it to
    the next change (or the end) [output units·s]. Consecutive moving samples (a ramp) are one
    change."""
    if t.size < 2:
        return []
    scale = max(float(np.max(np.abs(r))), 1.0)
    moved = np.abs(np.diff(r)) > tol * scale
    starts = [i + 1 for i in np.flatnonzero(moved) if i == 0 or not moved[i - 1]]
    out = []
    e = np.abs(r - y)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
    for n, start in enumerate(starts):
        stop = starts[n + 1] if n + 1 < len(starts) else t.size
        out.append({'time': float(t[start]), 'from': float(r[start - 1]), 'to': float(r[stop - 1]),
                    'iae': float(np.sum(e[start:stop] * dt[start:stop]))})
    return out
