"""PID by fitting a desired closed loop in the frequency domain ([Precup2013] §3.5.1, Wang 1997/2002).

The desired closed loop is second order with the process dead time Tm ([Precup2013] eq. 3.5.1)::

    H_wd(s) = ωn²·e^(−Tm·s)/(s² + 2ζ·ωn·s + ωn²),   H_0d = H_wd/(1 − H_wd)   (eq. 3.5.4)

and the PID ``H_R(s) = kR·(1 + 1/(Ti·s) + Td·s)`` is the least-squares solution of
``H_P(jωi)·[1, 1/(jωi), jωi]·x = H_0d(jωi)``, x = [kR, kR/Ti, kR·Td] (eqs. 3.5.5–3.5.6), over
points ωi up to just above the phase crossover of H_0d, split into real and imaginary parts.
The fit is accepted when ``max_i |H_R·H_P − H_0d|/|H_0d| ≤ ε`` (eq. 3.5.7; the document's
normalisation is lost, relative error is ours). The document's starting values ζ = 0.707,
ωn·Tm = 2 give 4.3 % overshoot, 60.3° phase margin and gain margin 2.26 on the target
([Precup2013] §3.5.1). Frequencies in rad/s, times in s.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Response = Callable[[np.ndarray], np.ndarray]


def desired_open_loop(zeta: float, wn: float, dead_time: float) -> Response:
    """``H_0d(jω)`` of [Precup2013] eq. 3.5.4 for the target of eq. 3.5.1."""
    def h0d(w: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(w, float)
        hwd = wn * wn * np.exp(-dead_time * s) / (s * s + 2.0 * zeta * wn * s + wn * wn)
        return hwd / (1.0 - hwd)
    return h0d


def phase_crossover(h0d: Response, w_max: float) -> float:
    """The lowest frequency where ``h0d`` crosses the negative real axis (below ``w_max``)."""
    w = np.geomspace(w_max * 1e-4, w_max, 4000)
    g = h0d(w)
    cross = np.nonzero((g.imag[:-1] < 0.0) & (g.imag[1:] >= 0.0) & (g.real[1:] < 0.0))[0]
    if len(cross) == 0:
        raise ValueError('loop_fit: the desired open loop has no phase crossover')
    lo, hi = float(w[cross[0]]), float(w[cross[0] + 1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if h0d(np.array([mid]))[0].imag < 0.0 else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class LoopFit:
    """``kp``, ``ti`` [s], ``td`` [s] of the ideal PID, ``error`` the largest relative misfit
    of eq. 3.5.7 over the points, ``omegas`` the points used [rad/s]."""

    kp: float
    ti: float
    td: float
    error: float
    omegas: np.ndarray


def fit_pid(omegas: np.ndarray, process: np.ndarray, target: np.ndarray,
            kind: str = 'pid') -> LoopFit:
    """Least-squares PI/PID of [Precup2013] eq. 3.5.5 through measured or modelled ``process`` =
    ``H_P(jωi)`` and ``target`` = ``H_0d(jωi)``; raises ``ValueError`` when the solution has
    no positive gain or integral time."""
    w = np.asarray(omegas, float)
    hp, h0 = np.asarray(process, complex), np.asarray(target, complex)
    columns = [hp, hp / (1j * w)] + ([hp * 1j * w] if kind == 'pid' else [])
    a = np.column_stack(columns)
    x, *_ = np.linalg.lstsq(np.vstack([a.real, a.imag]), np.concatenate([h0.real, h0.imag]),
                            rcond=None)
    kp, ki = float(x[0]), float(x[1])
    kd = float(x[2]) if kind == 'pid' else 0.0
    if not (kp > 0.0 and ki > 0.0):
        raise ValueError(f'loop_fit: the fit gives kp {kp:.4g}, kp/Ti {ki:.4g}; no PI/PID with '
                         'positive gains realises the target ([Precup2013] eq. 3.5.5)')
    td = max(kd, 0.0) / kp
    hr = kp * (1.0 + 1.0 / (kp / ki * 1j * w) + td * 1j * w)
    error = float(np.max(np.abs(hr * hp - h0) / np.abs(h0)))
    return LoopFit(kp, kp / ki, td, error, w)


def design(process: Response, dead_time: float, kind: str = 'pid', zeta: float = 0.707,
           wn_tm: float = 2.0, points: int = 20, tolerance: float = 0.5) -> LoopFit:
    """PI/PID for a process with frequency response ``process`` and dead time ``dead_time``
    [s]: ωn = ``wn_tm``/Tm, ``points`` frequencies geometrically from ωp/20 to 1.2·ωp (ωp the
    phase crossover of H_0d; the document asks for the last one above it), accepted when the
    misfit is at most ``tolerance`` (else ``ValueError``: relax the target or use a
    higher-order controller, as [Precup2013] says)."""
    if not dead_time > 0.0:
        raise ValueError('loop_fit: the target needs the process dead time Tm > 0 ([Precup2013] eq. 3.5.1)')
    if not (0.0 < zeta and wn_tm > 0.0 and points >= 2):
        raise ValueError('loop_fit: zeta and wn_tm must be > 0, points >= 2')
    wn = wn_tm / dead_time
    h0d = desired_open_loop(zeta, wn, dead_time)
    wp = phase_crossover(h0d, 20.0 * wn)
    w = np.geomspace(wp / 20.0, 1.2 * wp, points)
    fit = fit_pid(w, process(w), h0d(w), kind)
    if fit.error > tolerance:
        raise ValueError(f'loop_fit: the {kind} misses the target by {100 * fit.error:.0f} % '
                         f'([Precup2013] eq. 3.5.7 allows {100 * tolerance:.0f} %); relax zeta/wn_tm or '
                         'use another controller')
    return fit
