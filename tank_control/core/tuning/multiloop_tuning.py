"""Multivariable PI tuning of a 2×2 process ([Precup2013] §3.7, eqs. 3.7.1–3.7.10; [Precup2013] §3.7).

* :func:`equivalent_processes`: the equivalent SISO processes of a decentralised loop pair, each
  seen with the other loop closed ([Precup2013] eqs. 3.7.4, 3.7.5).
* :func:`place_point`: a PI/PID that moves the process point ``r_a·e^{j(−π+φ_a)}`` to the loop
  point ``r_b·e^{j(−π+φ_b)}`` ([Precup2013] eqs. 3.7.6–3.7.7, the Åström–Hägglund relations);
  :func:`zn_point` is the loop point of Ziegler–Nichols' PI (0.45·Ku, Ti = Tu/1.2) and
  :func:`multiloop_design` iterates the placement over both loops on a model ([Precup2013] §3.7.1).
* :func:`mimo_pi_least_squares`: the m×m PI matrices that fit ``H_P·H_R = H_w·(I − H_w)⁻¹`` on a
  set of frequencies ([Precup2013] eqs. 3.7.8–3.7.10), fully or in the two-loop structure
  ``H_R = D·diag(kp_i + ki_i/s)`` with a fixed decoupler ``D``.
* :func:`tank_frequency_response`: ``H_P(jω)`` of the mixing tank linearised at its operating
  point with its delays ([Michalski2021] eqs. 4–6), outputs ``[h, T_out]`` [cm, °C], inputs
  ``[F_H, F_Cin]`` [cm³/s]; :func:`decoupler_response` the two-loop PI's decoupler.

Frequencies in rad/s, times in s; controllers in the parallel form ``kp + ki/s (+ kd·s)`` acting
on ``e = r − y`` (negative feedback), ``ki = kp/Ti``.
"""
from __future__ import annotations

import cmath
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.control.multiloop import D21_DEN, D21_NUM

Response = Callable[[float], np.ndarray]
"""ω [rad/s] → the 2×2 complex frequency response matrix."""


@dataclass(frozen=True)
class PiGains:
    """A parallel PI(D) ``kp + ki/s + kd·s`` (``ki = kp/Ti``, ``kd = kp·Td``)."""

    kp: float
    ki: float
    kd: float = 0.0

    def response(self, omega: float) -> complex:
        return self.kp + self.ki / (1j * omega) + 1j * omega * self.kd

    @property
    def ti(self) -> float:
        """Integral time Ti = kp/ki [s] (inf without integral action)."""
        return self.kp / self.ki if self.ki != 0.0 else math.inf


# ---------------------------------------------------------------- [Precup2013] eqs. 3.7.4–3.7.5
def equivalent_processes(h: np.ndarray, c1: complex, c2: complex) -> tuple[complex, complex]:
    """``(H_P1, H_P2)`` at one frequency: loop 1's process ``u1 → y1`` with loop 2 closed by
    ``c2 = H_R2(jω)`` ([Precup2013] eq. 3.7.4) and loop 2's ``u2 → y2`` with loop 1 closed by
    ``c1 = H_R1(jω)`` (eq. 3.7.5, the output corrected from y1 to y2). ``c = 0`` is an open
    loop: then the equivalent process is the diagonal element."""
    h11, h12, h21, h22 = complex(h[0, 0]), complex(h[0, 1]), complex(h[1, 0]), complex(h[1, 1])
    hp1 = h11 - h12 * h21 * c2 / (1.0 + h22 * c2)
    hp2 = h22 - h21 * h12 * c1 / (1.0 + h11 * c1)
    return hp1, hp2


# ---------------------------------------------------------------- [Precup2013] eqs. 3.7.6–3.7.7
def place_point(r_a: float, phi_a: float, r_b: float, phi_b: float, omega: float,
                ti_td_ratio: float | None = None) -> PiGains:
    """The PI (or PID) that maps the process point ``H_P(jω) = r_a·e^{j(−π+φ_a)}`` (eq. 3.7.6)
    on the loop point ``H_0(jω) = r_b·e^{j(−π+φ_b)}`` (eq. 3.7.7); angles in rad.

    ``kR = r_b·cos(φ_b − φ_a)/r_a`` and ``ω·Td − 1/(ω·Ti) = tan(φ_b − φ_a)``; a PI (``Td = 0``)
    needs φ_b < φ_a (a PI lags); a PID closes the relation with ``Ti = ti_td_ratio·Td``
    (the background's 4). A negative process gain (r_a < 0 by convention, i.e. the point on
    the positive real axis) gives a negative kR."""
    for name, value in (('r_a', r_a), ('r_b', r_b), ('omega', omega)):
        if not (math.isfinite(value) and value != 0.0):
            raise ValueError(f'place_point: {name} = {value!r} must be finite and non-zero')
    if not r_b > 0.0 or not omega > 0.0:
        raise ValueError('place_point: r_b and omega must be positive')
    dphi = phi_b - phi_a
    if not -0.5 * math.pi < dphi < 0.5 * math.pi:
        raise ValueError(f'place_point: φ_b − φ_a = {math.degrees(dphi):.3g}° must lie in '
                         '(−90°, 90°) for a positive kR')
    kr = r_b * math.cos(dphi) / r_a
    tan = math.tan(dphi)
    if ti_td_ratio is None:
        if not tan < 0.0:
            raise ValueError(f'place_point: a PI needs φ_b < φ_a (it lags); got φ_b − φ_a = '
                             f'{math.degrees(dphi):.3g}°')
        ti = -1.0 / (omega * tan)
        return PiGains(kr, kr / ti)
    if not ti_td_ratio > 0.0:
        raise ValueError(f'place_point: ti_td_ratio = {ti_td_ratio!r} must be > 0')
    # ω·Td − 1/(ω·ratio·Td) = tan  →  ratio·ω²·Td² − ratio·ω·tan·Td − 1 = 0
    a, b = ti_td_ratio * omega ** 2, -ti_td_ratio * omega * tan
    td = (-b + math.sqrt(b * b + 4.0 * a)) / (2.0 * a)
    ti = ti_td_ratio * td
    return PiGains(kr, kr / ti, kr * td)


def zn_point() -> tuple[float, float]:
    """``(r_b, φ_b)`` [-, rad] of the Ziegler–Nichols PI (kR = 0.45·Ku, Ti = Tu/1.2) at the
    ultimate point, where ``r_a = 1/Ku``, ``φ_a = 0``: ``r_b = 0.45·|1 + 1.2/(2πj)|``,
    ``φ_b = −atan(1.2/(2π))`` (−10.8°)."""
    c = 0.45 * (1.0 + 1.2 / (2j * math.pi))
    return abs(c), cmath.phase(c)


def ultimate_point(response: Callable[[float], complex], omega_lo: float,
                   omega_hi: float, points: int = 400) -> tuple[float, complex]:
    """``(ω_u, H(jω_u))`` of the lowest frequency in [omega_lo, omega_hi] where the phase of
    ``response`` (negative gain: of ``−response``) crosses −180°; ValueError if none."""
    w = np.geomspace(omega_lo, omega_hi, points)
    g = np.array([response(x) for x in w])
    sign = 1.0 if g[0].real >= 0.0 else -1.0      # static gain sign (phase 0 or ±π at ω_lo)
    phase = np.unwrap(np.angle(sign * g))
    below = np.flatnonzero(phase <= -math.pi)
    if below.size == 0:
        raise ValueError('ultimate_point: the phase does not reach −180° in '
                         f'[{omega_lo:g}, {omega_hi:g}] rad/s')
    k = int(below[0])
    lo, hi = (w[k - 1], w[k]) if k > 0 else (w[0], w[0])
    for _ in range(60):                             # bisection on the unwrapped phase
        mid = math.sqrt(lo * hi)
        p = _phase_near(sign * response(mid), phase[max(k - 1, 0)])
        lo, hi = (mid, hi) if p > -math.pi else (lo, mid)
    wu = math.sqrt(lo * hi)
    return wu, response(wu)


def _phase_near(value: complex, ref: float) -> float:
    p = cmath.phase(value)
    return p + 2.0 * math.pi * round((ref - p) / (2.0 * math.pi))


@dataclass(frozen=True)
class MultiloopDesign:
    """Result of :func:`multiloop_design`: the two PIs, and per loop the ultimate frequency
    [rad/s] and gain of its equivalent process at its last placement."""

    loops: tuple[PiGains, PiGains]
    omega: tuple[float, float]
    ku: tuple[float, float]
    placements: int


def multiloop_design(process: Response, r_b: float, phi_b: float, omega_lo: float,
                     omega_hi: float, placements: int = 3) -> MultiloopDesign:
    """[Precup2013] §3.7.1 on a model: loop 1 is placed on its open-loop process (loop 2 open), loop 2
    on its equivalent process with loop 1 closed (eq. 3.7.5), then loop 1 again with loop 2
    closed (eq. 3.7.4), alternating, ``placements`` placements in all (3: the sequence of the
    sequential relay test); each at the ultimate point of the
    equivalent process, ``r_a = 1/Ku``, φ_a = 0 (eq. 3.7.6), to the loop point (r_b, φ_b)
    (eq. 3.7.7). A negative process gain gives negative gains."""
    c = [PiGains(0.0, 0.0), PiGains(0.0, 0.0)]
    omega, ku = [0.0, 0.0], [0.0, 0.0]
    if placements < 1:
        raise ValueError(f'multiloop_design: placements = {placements} must be >= 1')
    order = [k % 2 for k in range(placements)]
    for i in order:
        other = c[1 - i]

        def equivalent(w: float, i: int = i, other: PiGains = other) -> complex:
            h = process(w)
            cr = other.response(w)
            return equivalent_processes(h, cr, cr)[i]

        try:
            wu, g = ultimate_point(equivalent, omega_lo, omega_hi)
        except ValueError as exc:
            raise ValueError(f'loop {i + 1}: its equivalent process has no ultimate point '
                             f'({exc})') from None
        r_a = -abs(g) if g.real > 0 else abs(g)    # the point on the positive axis: gain < 0
        c[i] = place_point(r_a, 0.0, r_b, phi_b, wu)
        omega[i], ku[i] = wu, 1.0 / abs(g)
    return MultiloopDesign((c[0], c[1]), (omega[0], omega[1]), (ku[0], ku[1]), len(order))


# ---------------------------------------------------------------- [Precup2013] eqs. 3.7.8–3.7.10
def target_loop(omega: float, omega0: Sequence[float], xi: Sequence[float],
                dead_time: Sequence[float]) -> np.ndarray:
    """``H_w·(I − H_w)⁻¹`` at ω ([Precup2013] eqs. 3.7.9, 3.7.10): the open loop whose closed loop is
    the decoupled ``diag(ω0²·e^{−s·Tm}/(s² + 2ξ·ω0·s + ω0²))``."""
    s = 1j * omega
    hw = np.array([w0 ** 2 * cmath.exp(-s * tm) / (s * s + 2.0 * z * w0 * s + w0 ** 2)
                   for w0, z, tm in zip(omega0, xi, dead_time)])
    return np.diag(hw / (1.0 - hw))


@dataclass(frozen=True)
class LeastSquaresPi:
    """Result of :func:`mimo_pi_least_squares`: ``kp``, ``ki`` (and ``kd``) m×m, the relative
    residual ‖H_P·H_R − L_w‖/‖L_w‖ over the fit (weighted), and the frequencies used."""

    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    residual: float
    omegas: tuple[float, ...]

    def response(self, omega: float) -> np.ndarray:
        return self.kp + self.ki / (1j * omega) + 1j * omega * self.kd


def mimo_pi_least_squares(process: Response, omegas: Sequence[float], omega0: Sequence[float],
                          xi: Sequence[float], dead_time: Sequence[float],
                          derivative: bool = False, decoupler: Response | None = None,
                          weights: Sequence[float] | None = None) -> LeastSquaresPi:
    """Least-squares solution of [Precup2013] eq. 3.7.10, ``H_P(jω)·[I, I/(jω), jω·I]·[kp; ki; kd] =
    L_w(jω)``, stacked over ``omegas`` (real and imaginary parts, each frequency's equations
    scaled by ``weights`` (default 1/(1 + ‖L_w‖), so that the integrator-dominated low
    frequencies do not swamp the rest).

    Without ``decoupler`` the unknowns are the full m×m matrices (eq. 3.7.8). With a decoupler
    ``D(jω)`` the controller is ``D·diag(kp_i + ki_i/s (+ kd_i·s))`` — the two-loop PI with its
    decoupler — and the unknowns are the diagonal gains; ``kp``, ``ki``, ``kd`` are then
    returned as diagonal matrices."""
    omegas = tuple(float(w) for w in omegas)
    if not omegas or any(not (math.isfinite(w) and w > 0) for w in omegas):
        raise ValueError('mimo_pi_least_squares: omegas must be positive finite frequencies')
    m = len(omega0)
    terms = 3 if derivative else 2
    rows: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    for k, w in enumerate(omegas):
        hp = np.asarray(process(w), dtype=complex)
        lw = target_loop(w, omega0, xi, dead_time)
        scale = (weights[k] if weights is not None
                 else 1.0 / (1.0 + float(np.linalg.norm(lw))))
        basis = [1.0, 1.0 / (1j * w), 1j * w][:terms]
        if decoupler is None:
            # vec(H_P·K) = (I ⊗ H_P)·vec(K) (column-major): unknowns K_t[:, j] per term t
            for j in range(m):               # column j of H_P·H_R = H_P·H_R[:, j]
                row = np.zeros((m, terms * m * m), dtype=complex)
                for t, f in enumerate(basis):
                    block = t * m * m + j * m
                    row[:, block:block + m] = hp * f
                rows.append(row * scale)
                rhs.append(lw[:, j] * scale)
        else:
            hd = hp @ np.asarray(decoupler(w), dtype=complex)
            # (H_P·D·diag(c))[:, j] = (H_P·D)[:, j]·c_j
            for j in range(m):
                row = np.zeros((m, terms * m), dtype=complex)
                for t, f in enumerate(basis):
                    row[:, t * m + j] = hd[:, j] * f
                rows.append(row * scale)
                rhs.append(lw[:, j] * scale)
    a = np.vstack(rows)
    b = np.concatenate(rhs)
    a_real = np.vstack([a.real, a.imag])
    b_real = np.concatenate([b.real, b.imag])
    x, *_ = np.linalg.lstsq(a_real, b_real, rcond=None)
    residual = float(np.linalg.norm(a_real @ x - b_real) / max(float(np.linalg.norm(b_real)), 1e-300))
    if decoupler is None:
        mats = [x[t * m * m:(t + 1) * m * m].reshape(m, m, order='F') for t in range(terms)]
    else:
        mats = [np.diag(x[t * m:(t + 1) * m]) for t in range(terms)]
    kd = mats[2] if derivative else np.zeros((m, m))
    return LeastSquaresPi(mats[0], mats[1], kd, residual, omegas)


# ---------------------------------------------------------------- the mixing tank
def tank_frequency_response(cfg: Any, omega: float) -> np.ndarray:
    """``H_P(jω)`` of the mixing tank linearised at the operating point of ``cfg`` (a
    ``MixingTankConfig``/``LinearTankConfig``: ``C, alpha, F_*, T_*, h_op, T_op, tau_cold,
    tau_out``), with its delays: ``[h, T_out] ← [F_H, F_Cin]``, h = V/(2·C·h_op) ([Michalski2021] eqs. 4–6;
    ``analysis.two_loop.LinearisedTank``). Units: cm and °C per cm³/s."""
    from tank_control.core.analysis.two_loop import LinearisedTank
    return LinearisedTank.from_config(cfg).at(np.array([1j * omega]))[0]


def d21_filter_response(omega: float, sample_time: float) -> complex:
    """The dynamic decoupler D21 of [Michalski2021] eq. 2 at ``z = e^{jω·Ts}``."""
    z = cmath.exp(1j * omega * sample_time)
    return (D21_NUM[0] * z + D21_NUM[1]) / (D21_DEN[0] * z + D21_DEN[1])


def decoupler_response(decoupling: str, d12: float, d21: float, sample_time: float,
                       omega: float) -> np.ndarray:
    """``D(jω)`` of the two-loop PI (``F_H = v_h + D12·v_T``, ``F_Cin = D21·v_h + v_T``):
    the identity for decoupling ``none``, the static ``[[1, d12], [d21, 1]]``, or D21 the
    filter of [Michalski2021] eq. 2 (``dynamic``)."""
    if decoupling == 'none':
        return np.eye(2, dtype=complex)
    g21 = d21_filter_response(omega, sample_time) if decoupling == 'dynamic' else d21
    return np.array([[1.0, d12], [g21, 1.0]], dtype=complex)
