"""Root of a bracketed scalar function and maximum of a unimodal one, without scipy.

The frequency analysis (``core/analysis/frequency.py``: crossovers, Ms) runs in every
controller node when it first reports its loop's margins, while the graph starts; importing
``scipy.optimize`` for it cost each controller process about 0.25 s of CPU (a quiet 2-core
machine), more than the node's own imports. These two routines do that analysis's work in a
few lines of numpy-free Python.

* :func:`bracketed_root`: regula falsi with the Illinois modification [DowellJarratt1971]
  (the retained end's function value halved when the same end is kept twice, so both ends
  converge), with a bisection step whenever three steps did not halve the bracket: at most
  four evaluations per halving on any function, superlinear on smooth ones.
* :func:`bounded_max`: golden-section search [Kiefer1953] on ``[lo, hi]``.

Both stop on the bracket width, as ``scipy.optimize.brentq``/``minimize_scalar(method=
'bounded')`` do on their tolerances, so a result equals scipy's to within those tolerances.
"""
from __future__ import annotations

import math
from collections.abc import Callable

_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0     # 1/φ of the golden section


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


def bounded_max(f: Callable[[float], float], lo: float, hi: float, xatol: float = 1e-12
                ) -> tuple[float, float]:
    """``(x, f(x))`` of the largest value found on ``[lo, hi]`` by golden-section search,
    narrowed until the bracket is at most ``xatol`` wide; for ``f`` unimodal on the interval
    that is its maximum. [Kiefer1953]"""
    lo, hi = float(lo), float(hi)
    c = hi - _INV_PHI * (hi - lo)
    d = lo + _INV_PHI * (hi - lo)
    fc, fd = float(f(c)), float(f(d))
    while hi - lo > xatol:
        if fc >= fd:                    # the maximum is in [lo, d]
            hi, d, fd = d, c, fc
            c = hi - _INV_PHI * (hi - lo)
            fc = float(f(c))
        else:                           # in [c, hi]
            lo, c, fc = c, d, fd
            d = lo + _INV_PHI * (hi - lo)
            fd = float(f(d))
    return (c, fc) if fc >= fd else (d, fd)
