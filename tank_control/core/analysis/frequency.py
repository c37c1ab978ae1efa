"""Frequency-domain analysis with exact dead time ([DeadTimeNotes] §1.1 eqs. 6.4–6.7,
[Ikonen], [Precup2013] §3.4; [Checks] §2).

A :class:`FrequencyResponse` is a rational part times the exact dead time ``e^(−L·s)``
(continuous) or ``z^(−d)`` (discrete, sampled loop with ZOH, also fractional dead time); no
Padé approximation anywhere. Models: plants (:func:`ipdt`, :func:`fopdt`, :func:`rational`),
the 2-DOF PID of [Viteckova] eq. 19 and [Ikonen]'s compensators, the discrete transfer functions of the
implemented ``Pid2Dof``, exact ZOH models of any strictly proper rational plant with dead time
(:func:`rational_zoh`). Analysis: :func:`ultimate_point`, :func:`margins`,
:func:`closed_loop_poles_unstable`, :func:`gang_of_four`, :func:`tuning_report`. Units: ω in
rad/s, times in s, phases in degrees at the API (continuous, from the ω → 0+ limit), gains as
ratios. Overview and the documents' tunings: README, "Frequency-domain analysis (core)".
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from tank_control.core.scalar_search import bounded_max, bracketed_root

Rational = Callable[[np.ndarray], np.ndarray]

_POINTS_PER_DECADE = 60
_SPAN = 1e3              # default grid: lowest corner / 1e3 … highest corner · 1e3
_REFINE_ROUNDS = 16
_MAX_POINTS = 400_000


# --------------------------------------------------------------------- checks
def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f'{name} = {value!r} is not a number')
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'{name} = {value!r} must be finite')
    return value


def _positive(name: str, value: Any, allow_inf: bool = False) -> float:
    if allow_inf and isinstance(value, (int, float)) and value == math.inf:
        return math.inf
    value = _finite(name, value)
    if value <= 0.0:
        rng = '(0, inf]' if allow_inf else '(0, inf)'
        raise ValueError(f'{name} = {value!r} must be > 0; allowed {rng}')
    return value


def _non_negative(name: str, value: Any) -> float:
    value = _finite(name, value)
    if value < 0.0:
        raise ValueError(f'{name} = {value!r} must be >= 0; allowed [0, inf)')
    return value


def _nonzero(name: str, value: Any) -> float:
    value = _finite(name, value)
    if value == 0.0:
        raise ValueError(f'{name} must be non-zero; allowed (-inf, 0) or (0, inf)')
    return value


def _filter_n(n: Any) -> float:
    n = _finite('n', n)
    if n <= 0.0:
        raise ValueError(f'n = {n!r} must be > 0 ([Viteckova] eq. 14 recommends 5…20); allowed (0, inf)')
    return n


# ---------------------------------------------------------------- the object
@dataclass(frozen=True)
class FrequencyResponse:
    """``G = rational · e^(−dead_time·s)`` (continuous) or ``rational(z) · z^(−d)``
    with ``d = dead_time/sample_time`` (discrete, [DeadTimeNotes] eq. 6.7).

    ``rational`` maps complex ``s`` (or ``z`` when ``sample_time > 0``) to complex
    values, elementwise. ``integrators``: net number of poles at s = 0 (z = 1);
    ``unstable_poles``: poles in Re s > 0 (|z| > 1), for the Nyquist count;
    ``corners``: characteristic frequencies [rad/s] that set the default grid;
    ``coefficients``: ``(num, den)`` of ``rational`` in s (or z), highest power first, when the
    response is built from them (None: given by its values only; a product keeps them when
    both factors have them). Call it with ``w`` [rad/s] to get the complex ``G(jω)``
    (``G(e^(jωTs))``). Multiply responses (``C * G``) to form a loop (same ``sample_time``).
    """

    rational: Rational
    dead_time: float = 0.0
    sample_time: float = 0.0
    integrators: int = 0
    unstable_poles: int = 0
    corners: tuple[float, ...] = field(default=())
    coefficients: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    @property
    def discrete(self) -> bool:
        return self.sample_time > 0.0

    @property
    def nyquist_frequency(self) -> float:
        """π/Ts [rad/s] for a discrete response, ``inf`` for a continuous one."""
        return math.pi / self.sample_time if self.discrete else math.inf

    def at(self, p: np.ndarray | complex) -> np.ndarray:
        """Value at complex ``s`` (continuous) or ``z`` (discrete), delay included."""
        p = np.asarray(p, dtype=complex)
        if self.discrete:
            d = int(round(self.dead_time / self.sample_time))
            return self.rational(p) * p ** (-d)
        return self.rational(p) * np.exp(-self.dead_time * p)

    def point(self, w: np.ndarray | float) -> np.ndarray:
        """The point on the imaginary axis (``jω``) or the unit circle (``e^(jωTs)``)."""
        w = np.asarray(w, dtype=float)
        return np.exp(1j * w * self.sample_time) if self.discrete else 1j * w

    def __call__(self, w: np.ndarray | float) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        self._check_w(w)
        return self.rational(self.point(w)) * np.exp(-1j * w * self.dead_time)

    def _check_w(self, w: np.ndarray) -> None:
        if self.discrete and np.any(w > self.nyquist_frequency * (1 + 1e-12)):
            raise ValueError(f'w: a discrete response is defined up to the Nyquist frequency '
                             f'π/Ts = {self.nyquist_frequency:.6g} rad/s')

    def __mul__(self, other: FrequencyResponse | float) -> FrequencyResponse:
        if not isinstance(other, FrequencyResponse):
            k = _nonzero('gain', other)
            f = self.rational
            return FrequencyResponse(lambda p: k * f(p), self.dead_time,
                                     self.sample_time, self.integrators, self.unstable_poles,
                                     self.corners, None if self.coefficients is None else
                                     (tuple(k * np.asarray(self.coefficients[0])),
                                      self.coefficients[1]))
        if not math.isclose(self.sample_time, other.sample_time, rel_tol=1e-12, abs_tol=0.0):
            raise ValueError(f'sample_time: cannot combine responses with sample_time '
                             f'{self.sample_time} s and {other.sample_time} s')
        f, g = self.rational, other.rational
        both = None
        if self.coefficients is not None and other.coefficients is not None:
            both = (tuple(np.polymul(self.coefficients[0], other.coefficients[0])),
                    tuple(np.polymul(self.coefficients[1], other.coefficients[1])))
        return FrequencyResponse(lambda p: f(p) * g(p), self.dead_time + other.dead_time,
                                 self.sample_time, self.integrators + other.integrators,
                                 self.unstable_poles + other.unstable_poles,
                                 self.corners + other.corners, both)

    __rmul__ = __mul__


# ------------------------------------------------------------- continuous models
def _poly(name: str, coefficients: ArrayLike) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(coefficients, dtype=float))
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ValueError(f'{name}: need a non-empty 1-D array of finite coefficients '
                         '(highest power first)')
    nz = np.flatnonzero(arr)
    if nz.size == 0:
        raise ValueError(f'{name}: all coefficients are zero')
    return arr[nz[0]:]


def _trailing_zeros(p: np.ndarray) -> int:
    nz = np.flatnonzero(p)
    return int(p.size - 1 - nz[-1])


def _root_corners(p: np.ndarray) -> tuple[float, ...]:
    r = np.abs(np.roots(np.trim_zeros(p, 'b'))) if np.trim_zeros(p, 'b').size > 1 else []
    return tuple(float(x) for x in r if x > 0 and math.isfinite(x))


def _delay_corner(dead_time: float) -> tuple[float, ...]:
    return (1.0 / dead_time,) if dead_time > 0 else ()


def rational(num: ArrayLike, den: ArrayLike, dead_time: float = 0.0) -> FrequencyResponse:
    """``num(s)/den(s) · e^(−dead_time·s)``; coefficients highest power first
    (numpy ``polyval`` order), ``dead_time`` [s] ≥ 0. Must be proper
    (deg num ≤ deg den). General form of [DeadTimeNotes] eq. 6.5 (H_N1(s)·e^(−sτ))."""
    num, den = _poly('num', num), _poly('den', den)
    if num.size > den.size:
        raise ValueError(f'num: degree {num.size - 1} exceeds den degree {den.size - 1}; '
                         'allowed: a proper transfer function')
    dead_time = _non_negative('dead_time', dead_time)
    den_trimmed = np.trim_zeros(den, 'b')
    unstable = int(np.sum(np.roots(den_trimmed).real > 0)) if den_trimmed.size > 1 else 0
    return FrequencyResponse(lambda s: np.polyval(num, s) / np.polyval(den, s), dead_time, 0.0,
                             _trailing_zeros(den) - _trailing_zeros(num), unstable,
                             _root_corners(num) + _root_corners(den) + _delay_corner(dead_time),
                             (tuple(num), tuple(den)))


def ipdt(gain: float, dead_time: float) -> FrequencyResponse:
    """IPDT ``k1/s · e^(−To·s)`` ([Viteckova] eq. 1, [Viteckova] eq. 1): ``gain`` = k1 [1/s],
    ``dead_time`` = To [s]."""
    k1 = _nonzero('gain', gain)
    to = _non_negative('dead_time', dead_time)
    return FrequencyResponse(lambda s: k1 / s, to, 0.0, 1, 0, _delay_corner(to) or (abs(k1),))


def fopdt(gain: float, time_constant: float, dead_time: float) -> FrequencyResponse:
    """FOPDT ``K/(T·s + 1) · e^(−L·s)`` ([DeadTimeNotes] eq. 6.14, [Precup2013] eq. 3.3.11, [Checks] §1):
    ``gain`` K, ``time_constant`` T [s] (0: pure gain with delay), ``dead_time`` L [s]."""
    k = _nonzero('gain', gain)
    t = _non_negative('time_constant', time_constant)
    dead = _non_negative('dead_time', dead_time)
    corners = ((1.0 / t,) if t > 0 else ()) + _delay_corner(dead)
    return FrequencyResponse(lambda s: k / (t * s + 1.0), dead, 0.0, 0, 0, corners or (1.0,))


def plant_response(config: Any) -> FrequencyResponse:
    """The response of a plant configuration of ``core.plants`` (``IpdtConfig``:
    gain, dead_time; ``FopdtConfig``: gain, time_constant, dead_time;
    ``TransferFunctionConfig``: num, den, dead_time), of a plant
    object with such a ``config``, or of an identified model of
    ``core.tuning.identification`` (``FopdtModel`` with ``order`` 1 or 2:
    ``K/(T·s + 1)^n·e^(−L·s)``, [Precup2013] eq. 3.6.1; ``IpdtModel``)."""
    config = getattr(config, 'config', config)
    if hasattr(config, 'num') and hasattr(config, 'den'):        # TransferFunctionConfig
        return rational(config.num, config.den, config.dead_time)
    order = getattr(config, 'order', 1)
    if hasattr(config, 'time_constant') and order != 1:
        if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
            raise ValueError(f'order = {order!r} must be an integer >= 1')
        t = _positive('time_constant', config.time_constant)
        den = np.array([1.0])
        for _ in range(int(order)):
            den = np.convolve(den, [t, 1.0])
        return rational([_nonzero('gain', config.gain)], den, config.dead_time)
    if hasattr(config, 'time_constant'):
        return fopdt(config.gain, config.time_constant, config.dead_time)
    if hasattr(config, 'gain') and hasattr(config, 'dead_time'):
        return ipdt(config.gain, config.dead_time)
    raise ValueError(f'config: {type(config).__name__} is not an IPDT or FOPDT configuration')


# --------------------------------------------------------- continuous controllers
def _pid_args(kp: float, ti: float, td: float, n: float) -> tuple[float, float, float, float]:
    kp = _nonzero('kp', kp)
    ti = _positive('ti', ti, allow_inf=True)
    td = _non_negative('td', td)
    n = _filter_n(n)
    return kp, ti, td, n


def _pid_corners(ti: float, td: float, n: float) -> tuple[float, ...]:
    out = ()
    if math.isfinite(ti):
        out += (1.0 / ti,)
    if td > 0:
        out += (1.0 / td, n / td)
    return out


def _pid_law(kp: float, ti: float, td: float, n: float, b: float, c: float) -> Rational:
    def law(s: np.ndarray) -> np.ndarray:
        out = np.full(np.shape(s), b, dtype=complex)
        if math.isfinite(ti):
            out = out + 1.0 / (ti * s)
        if td > 0:
            out = out + c * td * s / (td / n * s + 1.0)
        return kp * out
    return law


def pid_feedback(kp: float, ti: float = math.inf, td: float = 0.0, n: float = 10.0) -> FrequencyResponse:
    """Feedback part of the 2-DOF PID ([Viteckova] eq. 19, filter eq. 13–14, [Viteckova] eqs. 13–19):
    ``C(s) = kp·(1 + 1/(ti·s) + td·s/(td/n·s + 1))``, ``U = Cr·W − C·Y``.
    ``ti`` [s] (``inf``: no integral), ``td`` [s] (0: PI), ``n`` = td/Tf."""
    kp, ti, td, n = _pid_args(kp, ti, td, n)
    return FrequencyResponse(_pid_law(kp, ti, td, n, 1.0, 1.0), 0.0, 0.0,
                             int(math.isfinite(ti)), 0, _pid_corners(ti, td, n))


def _weight(name: str, value: Any) -> float:
    value = _finite(name, value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f'{name} = {value!r} is a setpoint weight; allowed [0, 1]')
    return value


def pid_setpoint(kp: float, ti: float = math.inf, td: float = 0.0, n: float = 10.0,
                 b: float = 1.0, c: float = 1.0) -> FrequencyResponse:
    """Setpoint part of the 2-DOF PID ([Viteckova] eq. 19):
    ``Cr(s) = kp·(b + 1/(ti·s) + c·td·s/(td/n·s + 1))``; ``b``, ``c`` in [0, 1]."""
    kp, ti, td, n = _pid_args(kp, ti, td, n)
    b, c = _weight('b', b), _weight('c', c)
    return FrequencyResponse(_pid_law(kp, ti, td, n, b, c), 0.0, 0.0,
                             int(math.isfinite(ti)), 0, _pid_corners(ti, td, n))


def pi(kp: float, ti: float) -> FrequencyResponse:
    """PI ``kp·(1 + 1/(ti·s))`` ([DeadTimeNotes] Table 6.1/6.2, [Ikonen] §1.3), ``ti`` [s]."""
    return pid_feedback(kp, ti)


def lead(kp: float, td: float, n: float = 10.0) -> FrequencyResponse:
    """[Ikonen]'s PD / phase-lead compensator ``kp·(td·s + 1)/(td/n·s + 1)`` ([Ikonen] §1.2,
    filter ten times faster: n = 10). Maximum phase lead ``asin((n−1)/(n+1))``
    at ``ω_max = √n/td`` [rad/s]."""
    kp = _nonzero('kp', kp)
    td = _positive('td', td)
    n = _filter_n(n)
    tf = td / n
    return FrequencyResponse(lambda s: kp * (td * s + 1.0) / (tf * s + 1.0), 0.0, 0.0, 0, 0,
                             (1.0 / td, n / td))


def series_pid(kp: float, ti: float, td: float, n: float = 10.0) -> FrequencyResponse:
    """[Ikonen]'s series (interacting) PID, PI × lead ([Ikonen] §1.4):
    ``kp·(1 + 1/(ti·s))·(td·s + 1)/(td/n·s + 1)``, ``ti``, ``td`` [s]."""
    return pi(kp, ti) * lead(1.0, td, n)


# ------------------------------------------------------------- discrete models
def _sample_time(sample_time: float) -> float:
    return _positive('sample_time', sample_time)


def _split_delay(dead_time: float, h: float) -> tuple[int, float]:
    """``L = d·h + θ`` with integer ``d`` and ``0 ≤ θ < h`` ([DeadTimeNotes] eq. 6.6: d = τ/T)."""
    d = math.floor(dead_time / h + 1e-9)
    theta = max(0.0, dead_time - d * h)
    if theta < 1e-9 * h:
        theta = 0.0
    return d, theta


def ipdt_zoh(gain: float, dead_time: float, sample_time: float) -> FrequencyResponse:
    """Exact ZOH (step-invariant) model of the IPDT ``k1/s·e^(−To·s)``:
    ``k1·z^(−d)·((h − θ)·z + θ)/(z·(z − 1))`` with ``To = d·h + θ``, ``h`` = Ts [s]
    ([DeadTimeNotes] eq. 6.7 for θ = 0: ``k1·h·z^(−d)/(z − 1)``)."""
    k1 = _nonzero('gain', gain)
    to = _non_negative('dead_time', dead_time)
    h = _sample_time(sample_time)
    d, theta = _split_delay(to, h)
    return FrequencyResponse(lambda z: k1 * ((h - theta) * z + theta) / (z * (z - 1.0)), d * h, h,
                             1, 0, _delay_corner(to) or (abs(k1),),
                             ((k1 * (h - theta), k1 * theta), (1.0, -1.0, 0.0)))


def fopdt_zoh(gain: float, time_constant: float, dead_time: float, sample_time: float) -> FrequencyResponse:
    """Exact ZOH model of ``K/(T·s+1)·e^(−L·s)`` with ``L = d·h + θ`` (0 ≤ θ < h):
    ``K·z^(−d)·(b1·z + b2)/(z·(z − a))``, ``a = e^(−h/T)``,
    ``b1 = 1 − e^(−(h−θ)/T)``, ``b2 = e^(−(h−θ)/T) − a`` ([DeadTimeNotes] eq. 6.7, [Checks] §2)."""
    k = _nonzero('gain', gain)
    t = _positive('time_constant', time_constant)
    dead = _non_negative('dead_time', dead_time)
    h = _sample_time(sample_time)
    d, theta = _split_delay(dead, h)
    a = math.exp(-h / t)
    e = math.exp(-(h - theta) / t)
    b1, b2 = 1.0 - e, e - a
    return FrequencyResponse(lambda z: k * (b1 * z + b2) / (z * (z - a)), d * h, h, 0, 0,
                             (1.0 / t,) + _delay_corner(dead), ((k * b1, k * b2), (1.0, -a, 0.0)))


@dataclass(frozen=True)
class ZohStateSpace:
    """Exact ZOH model of a strictly proper ``num(s)/den(s)·e^(−L·s)`` at sample time ``h``
    with ``L = d·h + θ`` (0 ≤ θ < h): ``x(k+1) = Φ·x(k) + Γ0·u(k−d) + Γ1·u(k−d−1)``,
    ``y(k) = C·x(k)``; ``Φ = e^(A·h)``, ``Γ0 = ∫_0^(h−θ) e^(A·s) ds·B``,
    ``Γ1 = e^(A·(h−θ))·∫_0^θ e^(A·s) ds·B`` ([DeadTimeNotes] eq. 6.7 generalised)."""

    phi: np.ndarray
    gamma0: np.ndarray
    gamma1: np.ndarray
    c: np.ndarray
    delay_samples: int
    sample_time: float


def zoh_state_space(num: ArrayLike, den: ArrayLike, dead_time: float,
                    sample_time: float) -> ZohStateSpace:
    """:class:`ZohStateSpace` of ``num(s)/den(s)·e^(−L·s)`` (``dead_time`` L [s],
    ``sample_time`` h [s]); the state space of num/den is scipy's controllable form."""
    from scipy.linalg import expm
    num, den = _poly('num', num), _poly('den', den)
    if num.size >= den.size:
        raise ValueError('num: an exact ZOH model needs a strictly proper num(s)/den(s)')
    dead = _non_negative('dead_time', dead_time)
    h = _sample_time(sample_time)
    d, theta = _split_delay(dead, h)
    m = den.size - 1                         # controllable canonical form of num/den
    a = np.zeros((m, m))
    a[0, :] = -den[1:] / den[0]
    a[1:, :-1] = np.eye(m - 1)
    b = np.zeros((m, 1))
    b[0, 0] = 1.0
    c = np.zeros((1, m))
    c[0, m - num.size:] = num / den[0]

    def hold(tau: float) -> tuple[np.ndarray, np.ndarray]:
        """(e^(A·τ), ∫_0^τ e^(A·s) ds·B) from one matrix exponential (Van Loan)."""
        big = np.zeros((m + 1, m + 1))
        big[:m, :m], big[:m, m:] = a * tau, b * tau
        e = expm(big)
        return e[:m, :m], e[:m, m:]
    phi, _ = hold(h)
    phi_a, gamma0 = hold(h - theta)
    _, int_theta = hold(theta)
    return ZohStateSpace(phi, gamma0, phi_a @ int_theta, np.asarray(c, float), d, h)


def rational_zoh(num: ArrayLike, den: ArrayLike, dead_time: float,
                 sample_time: float) -> FrequencyResponse:
    """Exact ZOH (step-invariant) model of the strictly proper ``num(s)/den(s)·e^(−L·s)``,
    also with a fractional dead time (:class:`ZohStateSpace`; [DeadTimeNotes] eq. 6.7 generalised,
    [Checks] §2): ``G(z) = z^(−d)·C·(z·I − Φ)^(−1)·(Γ0 + Γ1/z)``. :func:`fopdt_zoh` and
    :func:`ipdt_zoh` are its closed forms. Times in s."""
    ss = zoh_state_space(num, den, dead_time, sample_time)
    m = ss.phi.shape[0]
    big_a = np.zeros((m + 1, m + 1))             # state (x, u(k−d−1)), input u(k−d)
    big_a[:m, :m], big_a[:m, m:] = ss.phi, ss.gamma1
    big_b = np.vstack([ss.gamma0, [[1.0]]])
    big_c = np.hstack([ss.c, [[0.0]]])
    zd = np.real(np.poly(big_a))                 # C·(zI − A)⁻¹·B = (det(zI − A + B·C) − det(zI − A))/det(zI − A)
    zn = np.real(np.poly(big_a - big_b @ big_c)) - zd
    zn[np.abs(zn) < 1e-12 * max(float(np.max(np.abs(zn))), 1e-300)] = 0.0
    return rational_discrete(zn, zd, ss.sample_time, ss.delay_samples)


def rational_discrete(num: ArrayLike, den: ArrayLike, sample_time: float,
                      delay_samples: int = 0) -> FrequencyResponse:
    """``num(z)/den(z) · z^(−d)``, coefficients in z highest power first,
    ``d = delay_samples`` ≥ 0 ([DeadTimeNotes] eq. 6.7), ``sample_time`` [s]."""
    num, den = _poly('num', num), _poly('den', den)
    h = _sample_time(sample_time)
    if isinstance(delay_samples, bool) or not isinstance(delay_samples, (int, np.integer)) \
            or delay_samples < 0:
        raise ValueError(f'delay_samples = {delay_samples!r} must be an integer >= 0')
    if num.size > den.size:
        raise ValueError(f'num: degree {num.size - 1} exceeds den degree {den.size - 1}; '
                         'allowed: a causal (proper) transfer function')
    roots_den = np.roots(den) if den.size > 1 else np.array([])
    roots_num = np.roots(num) if num.size > 1 else np.array([])
    at_one = int(np.sum(np.abs(roots_den - 1.0) < 1e-7)) - int(np.sum(np.abs(roots_num - 1.0) < 1e-7))
    unstable = int(np.sum(np.abs(roots_den) > 1.0 + 1e-12))
    corners = tuple(float(abs(np.log(complex(r))) / h)
                    for r in np.concatenate([roots_den, roots_num])
                    if r != 0 and abs(np.log(complex(r))) > 1e-12)
    return FrequencyResponse(lambda z: np.polyval(num, z) / np.polyval(den, z), delay_samples * h, h,
                             at_one, unstable, corners + _delay_corner(delay_samples * h),
                             (tuple(num), tuple(den)))


def _pid_law_discrete(kp: float, ti: float, td: float, n: float, b: float, c: float,
                      h: float) -> Rational:
    beta = td / (td + n * h)           # Tf/(Tf + h), Tf = td/n

    def law(z: np.ndarray) -> np.ndarray:
        out = np.full(np.shape(z), b, dtype=complex)
        if math.isfinite(ti):
            out = out + h / (ti * (z - 1.0))
        if td > 0:
            out = out + c * n * beta * (z - 1.0) / (z - beta)
        return kp * out
    return law


def _pid_coefficients_discrete(kp: float, ti: float, td: float, n: float, b: float, c: float,
                               h: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(num, den)`` in z of :func:`_pid_law_discrete`'s law (its terms over a common
    denominator)."""
    beta = td / (td + n * h)
    num, den = np.array([b]), np.array([1.0])
    terms = []
    if math.isfinite(ti):
        terms.append((np.array([h / ti]), np.array([1.0, -1.0])))
    if td > 0:
        terms.append((c * n * beta * np.array([1.0, -1.0]), np.array([1.0, -beta])))
    for t_num, t_den in terms:                          # num/den + t_num/t_den
        num, den = (np.polyadd(np.polymul(num, t_den), np.polymul(t_num, den)),
                    np.polymul(den, t_den))
    return tuple(kp * num), tuple(den)


def pid_feedback_discrete(kp: float, ti: float = math.inf, td: float = 0.0, n: float = 10.0,
                          sample_time: float = 1.0) -> FrequencyResponse:
    """Transfer function −U/Y of the implemented ``Pid2Dof`` (core/control/pid.py):
    ``C(z) = kp·(1 + h/(ti·(z − 1)) + n·β·(z − 1)/(z − β))``, ``β = Tf/(Tf + h)``,
    ``Tf = td/n``: forward-Euler integral and the backward-difference
    discretisation of ``td·s/(td/n·s + 1)`` ([Viteckova] eq. 13, 19), whose gain at low
    frequency is exactly ``td·s``; ``h`` = ``sample_time`` [s]."""
    kp, ti, td, n = _pid_args(kp, ti, td, n)
    h = _sample_time(sample_time)
    return FrequencyResponse(_pid_law_discrete(kp, ti, td, n, 1.0, 1.0, h), 0.0, h,
                             int(math.isfinite(ti)), 0, _pid_corners(ti, td, n),
                             _pid_coefficients_discrete(kp, ti, td, n, 1.0, 1.0, h))


def pid_setpoint_discrete(kp: float, ti: float = math.inf, td: float = 0.0, n: float = 10.0,
                          b: float = 1.0, c: float = 1.0, sample_time: float = 1.0) -> FrequencyResponse:
    """Transfer function U/R of the implemented ``Pid2Dof``:
    ``kp·(b + h/(ti·(z − 1)) + c·n·β·(z − 1)/(z − β))`` ([Viteckova] eq. 19)."""
    kp, ti, td, n = _pid_args(kp, ti, td, n)
    b, c = _weight('b', b), _weight('c', c)
    h = _sample_time(sample_time)
    return FrequencyResponse(_pid_law_discrete(kp, ti, td, n, b, c, h), 0.0, h,
                             int(math.isfinite(ti)), 0, _pid_corners(ti, td, n),
                             _pid_coefficients_discrete(kp, ti, td, n, b, c, h))


# ------------------------------------------------------------------- the grid
def default_grid(g: FrequencyResponse, points_per_decade: int = _POINTS_PER_DECADE) -> np.ndarray:
    """Log grid [rad/s] from the lowest corner/1000 to the highest corner·1000
    (to π/Ts for a discrete response)."""
    corners = [c for c in g.corners if c > 0 and math.isfinite(c)] or [1.0]
    lo, hi = min(corners) / _SPAN, max(corners) * _SPAN
    if g.discrete:
        hi = g.nyquist_frequency
        lo = min(lo, hi / _SPAN ** 2)
    decades = math.log10(hi / lo)
    return np.logspace(math.log10(lo), math.log10(hi), max(int(decades * points_per_decade), 50) + 1)


def _low_frequency_phase(g: FrequencyResponse, w0: float) -> float:
    """Limit of the rational part's phase as ω → 0+ [rad]: −k·π/2, −π more for a
    negative static gain."""
    eps = w0 * 1e-3
    p = np.exp(eps * g.sample_time) if g.discrete else eps
    x = complex(g.rational(np.asarray([p], dtype=complex))[0])
    scale = (p - 1.0) if g.discrete else p
    k0 = (x * scale ** g.integrators).real
    return (0.0 if k0 > 0 else -math.pi) - g.integrators * math.pi / 2


def _rational_phase(g: FrequencyResponse, w: np.ndarray) -> np.ndarray:
    """Continuous phase [rad] of the rational part on the increasing grid ``w``."""
    raw = np.unwrap(np.angle(g.rational(g.point(w))))
    target = _low_frequency_phase(g, float(w[0]))
    return raw + 2 * math.pi * round((target - raw[0]) / (2 * math.pi))


def _phase_on(g: FrequencyResponse, w: np.ndarray) -> np.ndarray:
    return _rational_phase(g, w) - w * g.dead_time


def _refined(g: FrequencyResponse) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Default grid refined until the phase changes by < 0.2 rad between points
    wherever |G| > 0.3 (so crossings of −180° and of |G| = 1 are not missed, even
    with a long dead time). Returns (w, G(jω), continuous phase [rad])."""
    w = default_grid(g)
    for _ in range(_REFINE_ROUNDS):
        val = g(w)
        ph = _phase_on(g, w)
        mag = np.abs(val)
        big = np.maximum(mag[1:], mag[:-1]) > 0.3
        bad = big & (np.abs(np.diff(ph)) > 0.2)
        if not np.any(bad) or w.size > _MAX_POINTS:
            return w, val, ph
        mids = np.sqrt(w[:-1][bad] * w[1:][bad])
        w = np.sort(np.concatenate([w, mids]))
    val = g(w)
    return w, val, _phase_on(g, w)


def bode(g: FrequencyResponse, w: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w [rad/s], |G(jω)| [ratio], phase [deg])``; the phase is continuous
    (exact dead time ``−ω·L``), starting from its ω → 0+ limit."""
    if w is None:
        w = default_grid(g)
    w = np.asarray(w, dtype=float).reshape(-1)
    if w.size == 0 or np.any(w <= 0) or np.any(np.diff(w) <= 0):
        raise ValueError('w: need strictly increasing frequencies > 0 [rad/s]')
    g._check_w(w)
    base = default_grid(g)
    union = np.union1d(base[base < w[0]], w)
    idx = np.searchsorted(union, w)
    return w, np.abs(g(w)), np.degrees(_phase_on(g, union)[idx])


# ----------------------------------------------------------- ultimate point
def _phase_scalar(g: FrequencyResponse, x: float, w: np.ndarray, ph: np.ndarray) -> float:
    """Continuous phase [rad] at ``x``: the rational part's angle on the branch
    nearest to its value interpolated from the grid (it varies slowly; the dead
    time part ``−x·L`` is exact, so no branch question there)."""
    ref = float(np.interp(x, w, ph + w * g.dead_time))
    a = float(np.angle(g.rational(g.point(np.asarray([x])))[0]))
    a += 2 * math.pi * round((ref - a) / (2 * math.pi))
    return a - x * g.dead_time


def _phase_crossings(g: FrequencyResponse, w: np.ndarray, ph: np.ndarray) -> list[float]:
    """All ω [rad/s] where the continuous phase crosses −180° − m·360°, ascending."""
    level = np.floor((ph + math.pi) / (2 * math.pi))
    out = []
    for i in np.flatnonzero(np.diff(level) != 0):
        target = -math.pi + 2 * math.pi * max(level[i], level[i + 1])

        def f(x: float) -> float:
            return _phase_scalar(g, x, w, ph) - target  # noqa: B023 - used in this iteration only
        fa, fb = f(w[i]), f(w[i + 1])
        if fa == 0.0:
            out.append(float(w[i]))
        elif fa * fb < 0:
            out.append(bracketed_root(f, w[i], w[i + 1], xtol=1e-14, rtol=1e-13))
    if g.discrete and w[-1] >= g.nyquist_frequency * (1 - 1e-12):
        # at π/Ts the response is real: a negative value is a crossing at the grid end
        off = (ph[-1] + math.pi) % (2 * math.pi)
        if min(off, 2 * math.pi - off) < 1e-7 and (not out or out[-1] < w[-1] * (1 - 1e-9)):
            out.append(float(w[-1]))
    return out


@dataclass(frozen=True)
class UltimatePoint:
    """Ultimate (critical) point: the lowest ω where the phase is −180°
    ([Precup2013] §3.2: punctul critic). ``ku`` = 1/|G(jωu)|, ``tu`` = 2π/ωu [s], ``wu`` [rad/s]."""

    ku: float
    tu: float
    wu: float

    def __iter__(self):
        return iter((self.ku, self.tu, self.wu))


def ultimate_point(g: FrequencyResponse) -> UltimatePoint:
    """``(ku, tu, wu)`` of ``g`` under proportional control: the lowest −180° phase
    crossing, bracketed on a refined grid then solved (``scalar_search.bracketed_root``). [Checks] §1:
    FOPDT 0.05/(10s+1)·e^(−3s) → ku = 117.80, tu = 10.824 s; IPDT k1/s·e^(−To·s)
    → ωu = π/(2·To), ku = π/(2·k1·To), tu = 4·To. Raises ``ValueError`` when the
    phase never reaches −180° (e.g. FOPDT without dead time) or starts there
    (negative static gain: use ``-1 * g``)."""
    w, _, ph = _refined(g)
    if ph[0] <= -math.pi + 1e-9:
        raise ValueError('g: the phase starts at or below -180 deg (negative gain or two '
                         'integrators); analyse -g (reverse action, negative kp) instead')
    crossings = [x for x in _phase_crossings(g, w, ph)
                 if math.isclose(_phase_scalar(g, x, w, ph), -math.pi,
                                 abs_tol=1e-6)]
    if not crossings:
        raise ValueError('g: the phase never reaches -180 deg on '
                         f'[{w[0]:.3g}, {w[-1]:.3g}] rad/s; no ultimate point')
    wu = crossings[0]
    return UltimatePoint(1.0 / float(abs(g(wu))), 2 * math.pi / wu, wu)


# ------------------------------------------------------------------ margins
@dataclass(frozen=True)
class Margins:
    """Stability margins of a loop ``L = C·G`` ([Ikonen]; [Precup2013] §3.4.3: rezerva de fază /
    de modul). ``gain_margin`` [ratio] = 1/|L| at the phase crossover (worst one,
    ``inf`` if the phase never reaches −180°); ``phase_margin`` [deg] = 180° + ∠L at
    the gain crossover (worst one; NaN if |L| never crosses 1), with the continuous
    phase from ω → 0+ (not wrapped: −200° stays −200°, it does not become +160°); ``wc`` [rad/s]
    gain crossover; ``w180`` [rad/s] phase crossover; ``delay_margin`` [s] = the
    extra dead time that destabilises, min over crossovers of PM[rad]/ωc;
    ``ms`` = max|S(jω)| and ``w_ms`` [rad/s] where it occurs; ``mt`` = max|T|;
    ``gain_crossovers`` / ``phase_crossovers``: every |L| = 1 and every
    −180° − m·360° crossing [rad/s], ascending."""

    gain_margin: float
    phase_margin: float
    wc: float
    w180: float
    delay_margin: float
    ms: float
    w_ms: float
    mt: float
    gain_crossovers: tuple[float, ...] = ()
    phase_crossovers: tuple[float, ...] = ()

    @property
    def gain_margin_db(self) -> float:
        return 20 * math.log10(self.gain_margin) if self.gain_margin > 0 else -math.inf

    def as_dict(self) -> dict[str, float]:
        """The scalar fields (not the crossover lists) and ``gain_margin_db``."""
        return {'gain_margin': self.gain_margin, 'gain_margin_db': self.gain_margin_db,
                'phase_margin': self.phase_margin, 'wc': self.wc, 'w180': self.w180,
                'delay_margin': self.delay_margin, 'ms': self.ms, 'w_ms': self.w_ms, 'mt': self.mt}


def _gain_crossovers(g: FrequencyResponse, w: np.ndarray, val: np.ndarray) -> list[float]:
    lm = np.log(np.abs(val))
    out = []
    for i in np.flatnonzero(np.sign(lm[1:]) != np.sign(lm[:-1])):
        def f(x: float) -> float:
            return float(np.log(abs(g(x))))
        fa, fb = f(w[i]), f(w[i + 1])
        if fa == 0.0:
            out.append(float(w[i]))
        elif fa * fb < 0:
            out.append(bracketed_root(f, w[i], w[i + 1], xtol=1e-14, rtol=1e-13))
    return out


def _peak(fn: Callable[[np.ndarray], np.ndarray], w: np.ndarray) -> tuple[float, float]:
    """max |fn(ω)| over the grid, refined by a bounded scalar search around the peak."""
    mag = np.abs(fn(w))
    i = int(np.argmax(mag))
    if i in (0, w.size - 1):
        return float(mag[i]), float(w[i])
    lo, hi = math.log(w[i - 1]), math.log(w[i + 1])
    x, peak = bounded_max(lambda x: np.abs(fn(np.exp(x))), lo, hi, xatol=1e-12)
    if peak > mag[i]:
        return peak, math.exp(x)
    return float(mag[i]), float(w[i])


def margins(loop: FrequencyResponse) -> Margins:
    """Gain margin, phase margin, crossovers, delay margin and ``Ms = max|S|``,
    ``Mt = max|T|`` of the loop ``L`` (e.g. ``pid_feedback(...) * fopdt(...)``).
    Dead time lowers the phase by ω·L, so PM drops by ωc·L ([DeadTimeNotes] §1.1,
    eq. 6.4–6.5); for pure I control of a pure delay ωc = 1/Ti and
    PM = 90° − L/Ti rad ([DeadTimeNotes] eq. 6.13). Ms is the inverse of the shortest
    distance from L(jω) to −1 ([Ikonen]: stabiilisuusmarginaali)."""
    return _margins_on(loop, *_refined(loop))


def _margins_on(loop: FrequencyResponse, w: np.ndarray, val: np.ndarray, ph: np.ndarray) -> Margins:
    wcs = _gain_crossovers(loop, w, val)
    pms = []
    for x in wcs:
        pms.append(math.pi + _phase_scalar(loop, x, w, ph))
    if pms:
        j = int(np.argmin(pms))
        pm_deg, wc = math.degrees(pms[j]), wcs[j]
        dms = [p / x for p, x in zip(pms, wcs) if p > 0]
        dm = min(dms) if len(dms) == len(pms) else 0.0
    else:
        pm_deg, wc, dm = math.nan, math.nan, math.inf
    w180s = _phase_crossings(loop, w, ph)
    if w180s:
        gms = [1.0 / float(abs(loop(x))) for x in w180s]
        k = int(np.argmin(gms))
        gm, w180 = gms[k], w180s[k]
    else:
        gm, w180 = math.inf, math.nan
    ms, w_ms = _peak(lambda x: 1.0 / (1.0 + loop(x)), w)
    mt, _ = _peak(lambda x: loop(x) / (1.0 + loop(x)), w)
    return Margins(gm, pm_deg, wc, w180, dm, ms, w_ms, mt, tuple(wcs), tuple(w180s))


# ------------------------------------------------------------- Nyquist count
def closed_loop_poles_unstable(loop: FrequencyResponse) -> int:
    """Number of closed-loop poles of ``1/(1 + L)`` in Re s ≥ 0 (|z| ≥ 1) by the
    Nyquist criterion with the exact dead time: ``Z = P − Δarg(1 + L)/2π`` along
    the Nyquist contour (indented at s = 0 / z = 1 around the integrators),
    ``P`` = ``loop.unstable_poles``. Continuous loops must be strictly proper
    enough that |L| < 0.5 at the top of the grid (else ``ValueError``). Open-loop
    poles on the imaginary axis other than s = 0 (z = 1), and closed-loop poles
    exactly on it (a loop at the stability limit), are outside its scope."""
    w, val, _ = _refined(loop)
    return _nyquist_count_on(loop, w, val)


def _nyquist_count_on(loop: FrequencyResponse, w: np.ndarray, val: np.ndarray) -> int:
    theta = np.linspace(-math.pi / 2, math.pi / 2, 401)
    eps = w[0] * 1e-2
    if loop.discrete:
        indent = 1.0 + eps * loop.sample_time * np.exp(1j * theta)
        parts = [loop.at(indent), val, np.conj(val[::-1])]
    else:
        if abs(val[-1]) >= 0.5:
            raise ValueError('loop: |L| does not fall below 0.5 at high frequency; '
                             'the Nyquist count needs a strictly proper loop')
        arc = w[-1] * np.exp(-1j * theta)          # from +jR clockwise to −jR
        parts = [loop.at(eps * np.exp(1j * theta)), val, loop.at(arc), np.conj(val[::-1])]
    one = 1.0 + np.concatenate(parts)
    one = np.append(one, one[0])
    turns = float(np.sum(np.diff(np.unwrap(np.angle(one))))) / (2 * math.pi)
    return int(round(loop.unstable_poles - turns))


def closed_loop_stable(loop: FrequencyResponse) -> bool:
    """True when the loop closed with unit negative feedback is stable
    (:func:`closed_loop_poles_unstable` == 0)."""
    return closed_loop_poles_unstable(loop) == 0


# ----------------------------------------------------------- gang of four
def sensitivity(loop: FrequencyResponse, w: np.ndarray) -> np.ndarray:
    """``S(jω) = 1/(1 + L(jω))`` ([Ikonen] §1.4)."""
    return 1.0 / (1.0 + loop(w))


def complementary_sensitivity(loop: FrequencyResponse, w: np.ndarray) -> np.ndarray:
    """``T(jω) = L/(1 + L)`` ([Ikonen] §1.4)."""
    lv = loop(w)
    return lv / (1.0 + lv)


def gang_of_four(controller: FrequencyResponse, plant: FrequencyResponse,
                 w: np.ndarray) -> dict[str, np.ndarray]:
    """[Ikonen] §1.4 "neljän kopla": complex arrays over ``w`` [rad/s] of
    ``S = 1/(1+PC)`` (output ← output disturbance), ``T = PC/(1+PC)`` (output ←
    measurement noise / 1-DOF setpoint), ``PS = P/(1+PC)`` (output ← load
    disturbance at the plant input, [Viteckova] Fig. 1), ``CS = C/(1+PC)`` (control ←
    noise / 1-DOF setpoint)."""
    p, c = plant(w), controller(w)
    s = 1.0 / (1.0 + p * c)
    return {'S': s, 'T': p * c * s, 'PS': p * s, 'CS': c * s}


# ------------------------------------------------------------ tuning report
def tuning_report(plant: FrequencyResponse | Any, kp: float, ti: float | None = math.inf,
                  td: float | None = 0.0, b: float | None = 1.0, c: float | None = 1.0,
                  n: float = 10.0) -> dict[str, float | bool]:
    """Frequency-domain report of a 2-DOF PID tuning ([Viteckova] eq. 19) on ``plant``
    (a :class:`FrequencyResponse`, or a plant, plant configuration or identified
    model that :func:`plant_response` accepts; ``None`` for ti/td/b/c as returned by
    ``tune()`` means no integral / no derivative / weight 1). A discrete plant
    (``ipdt_zoh``/``fopdt_zoh``) is paired with the discrete ``Pid2Dof`` law at
    its sample time. Keys: ``phase_margin`` [deg], ``gain_margin`` [ratio],
    ``gain_margin_db`` [dB], ``ms``, ``mt``, ``wc`` [rad/s], ``w180`` [rad/s],
    ``delay_margin`` [s], ``stable`` (Nyquist), ``setpoint_peak`` = max|Y/R|
    with the setpoint weights (1 = no amplification)."""
    if not isinstance(plant, FrequencyResponse):
        plant = plant_response(plant)
    ti = math.inf if ti is None else ti
    td = 0.0 if td is None else td
    b = 1.0 if b is None else b
    c = 1.0 if c is None else c
    if plant.discrete:
        h = plant.sample_time
        ctrl = pid_feedback_discrete(kp, ti, td, n, sample_time=h)
        ref = pid_setpoint_discrete(kp, ti, td, n, b, c, sample_time=h)
    else:
        ctrl = pid_feedback(kp, ti, td, n)
        ref = pid_setpoint(kp, ti, td, n, b, c)
    return controller_report(ctrl, plant, ref)


def controller_report(ctrl: FrequencyResponse, plant: FrequencyResponse,
                      ref: FrequencyResponse | None = None,
                      characteristic: FrequencyResponse | None = None) -> dict[str, float | bool]:
    """Frequency-domain report of the loop ``L = ctrl·plant`` for any controller response
    ``ctrl`` = −U/Y (same keys as :func:`tuning_report`); ``ref`` = U/R (default ``ctrl``:
    one degree of freedom) for ``setpoint_peak``; ``stable`` is the Nyquist count on
    ``characteristic`` when given (a loop whose closed-loop poles are those of ``L``, e.g. a
    Smith predictor's delay-free ``C·Gm0``), else on ``L``."""
    ref = ctrl if ref is None else ref
    loop = ctrl * plant
    w, val, ph = _refined(loop)
    peak, _ = _peak(lambda x: ref(x) * plant(x) / (1.0 + loop(x)), w)
    m = _margins_on(loop, w, val, ph)
    out: dict[str, float | bool] = dict(m.as_dict())
    if characteristic is None:
        out['stable'] = _nyquist_count_on(loop, w, val) == 0
    else:
        out['stable'] = closed_loop_poles_unstable(characteristic) == 0
    wrapped = not 0.0 <= float(out['phase_margin']) < 360.0
    if out['stable'] and m.gain_crossovers and (characteristic is not None or wrapped):
        # L may have open-loop unstable poles (a Smith predictor's equivalent controller, an
        # FSA law) or cross |L| = 1 where the dead time has turned its phase past −360°: the
        # phase a delay may still remove at each crossover is 180° + ∠L modulo 360°.
        pms = [(math.pi + _phase_scalar(loop, x, w, ph)) % (2 * math.pi)
               for x in m.gain_crossovers]
        j = int(np.argmin(pms))
        out['phase_margin'], out['wc'] = math.degrees(pms[j]), m.gain_crossovers[j]
        out['delay_margin'] = min(p / x for p, x in zip(pms, m.gain_crossovers))
    out['setpoint_peak'] = peak
    return out


def report_from_gains(plant: FrequencyResponse | Any, gains: Mapping[str, float | None],
                      n: float = 10.0) -> dict[str, float | bool]:
    """:func:`tuning_report` for a ``tune()`` result dict (keys kp, ti, td, b, c)."""
    kp = gains['kp']
    assert kp is not None                      # a tune() result always has a gain
    return tuning_report(plant, kp, gains.get('ti'), gains.get('td'),
                         gains.get('b'), gains.get('c'), n)
