"""Root of a bracketed scalar function and maximum of a unimodal one, without scipy.

The frequency analysis (``core/analysis/frequency.py``: crossovers, Ms) runs in every
controller node when it first reports its loop's margins, while the graph starts; importing
``scipy.optimize`` for it cost each controller process about 0.25 s of CPU (a quiet 2-core
machine), more than the node's own imports. These two routines do that analysis's work in a
few lines.

* :func:`bracketed_root`: regula falsi with the Illinois modification [DowellJarratt1971]
  (the retained end's function value halved when the same end is kept twice, so both ends
  converge), with a bisection step whenever three steps did not halve the bracket: at most
  four evaluations per halving on any function, superlinear on smooth ones.
* :func:`bounded_max`: the largest of a vectorised function's values on a grid, refined
  around the best point until the bracket is ``xatol`` wide.

Both stop on the bracket width, as ``scipy.optimize.brentq``/``minimize_scalar(method=
'bounded')`` do on their tolerances, so a result equals scipy's to within those tolerances.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def bracketed_root(f: Callable[[float], float], a: float, b: float, xtol: float = 2e-12,
                   rtol: float = 8.9e-16, maxiter: int = 500) -> float:
    """``x`` in ``[a, b]`` with ``f(x) = 0`` to within ``xtol + rtol·|x|`` (the root lies in
    the final bracket, whose end with the smaller ``|f|`` is returned); ``f(a)`` and ``f(b)``
    must differ in sign (``ValueError`` otherwise, or for a non-finite value).
    [DowellJarratt1971]"""
    fa, fb = float(f(a)), float(f(b))
    if not (math.isfinite(fa) and math.isfinite(fb)):
        raise ValueError(f'f is not finite at the bracket ends: f({a!r}) = {fa}, f({b!r}) = {fb}')
    if fa == 0.0:
        return float(a)
    if fb == 0.0:
        return float(b)
    if (fa > 0.0) == (fb > 0.0):
        raise ValueError(f'f({a!r}) = {fa} and f({b!r}) = {fb} have the same sign')
    a, b = float(a), float(b)
    ga, gb = fa, fb            # the values the secant uses (Illinois: halved when kept)
    kept = 0                   # +1: a was kept last step, -1: b was kept
    widths = [abs(b - a)]
    for _ in range(maxiter):
        if abs(b - a) <= xtol + rtol * min(abs(a), abs(b)):
            break
        if len(widths) >= 4 and widths[-1] > 0.5 * widths[-4]:
            c = 0.5 * (a + b)                      # three steps did not halve it: bisect
            kept = 0
            ga, gb = fa, fb
        else:
            c = (a * gb - b * ga) / (gb - ga)
            if not min(a, b) < c < max(a, b):      # rounding put it on an end
                c = 0.5 * (a + b)
        fc = float(f(c))
        if fc == 0.0:
            return c
        if not math.isfinite(fc):
            raise ValueError(f'f({c!r}) = {fc} is not finite')
        if (fc > 0.0) == (fa > 0.0):               # the root is in [c, b]: a moves
            a, fa, ga = c, fc, fc
            if kept == -1:
                gb *= 0.5
            kept = -1
        else:                                      # the root is in [a, c]: b moves
            b, fb, gb = c, fc, fc
            if kept == 1:
                ga *= 0.5
            kept = 1
        widths.append(abs(b - a))
    return a if abs(fa) <= abs(fb) else b


def bounded_max(f: Callable[[np.ndarray], np.ndarray], lo: float, hi: float,
                xatol: float = 1e-12, points: int = 33) -> tuple[float, float]:
    """``(x, f(x))`` of the largest value on ``[lo, hi]``: ``f`` (vectorised: an array of
    abscissae in, one of values out) on ``points`` equally spaced points, then the same on
    the two intervals beside the best one, until they are at most ``xatol`` wide (each round
    narrows the bracket ``(points − 1)/2``-fold: about ten calls from 0.1 to 1e-12). For ``f``
    unimodal on the interval that is its maximum; one vectorised call costs about what one
    point does, and a scalar golden-section search needs about 55 calls for the same width."""
    lo, hi = float(lo), float(hi)
    best_x, best = lo, -math.inf
    while True:
        x = np.linspace(lo, hi, points)
        values = np.asarray(f(x), dtype=float)
        i = int(np.argmax(values))
        if values[i] > best:
            best_x, best = float(x[i]), float(values[i])
        if hi - lo <= xatol:
            return best_x, best
        lo, hi = float(x[max(i - 1, 0)]), float(x[min(i + 1, points - 1)])
