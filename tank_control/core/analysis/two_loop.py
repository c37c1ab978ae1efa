"""Loop margins of the two-loop PI of [Michalski2021] §2–3 on the mixing tank linearised at its operating
point, with the exact delays ([Michalski2021] §1; [Precup2013] §3.7.1 eqs. 3.7.4–3.7.5).

Plant: [Michalski2021] §1 linearised (``mixing_tank.jacobian``), x = [V, T], the level h = V/(2·C·h_op)
to first order, T_out(t) = T(t − τ), F_C(t) = F_Cin(t − τ_C):

    G(s) = [[h/F_H, h/F_Cin], [T_out/F_H, T_out/F_Cin]]     (continuous, e^(−τ·s) exact)

Controller: :class:`~tank_control.core.control.multiloop.TwoLoopPiConfig` — each loop the
parallel PI ``kp + ki/s``, the decoupler ``u = W·v``, W = [[1, D12], [D21, 1]] (identity
without decoupling). The dynamic D21 of [Michalski2021] eq. 2 has its pole (z = −0.003432) on its zero
(z = −0.003428), so it is its static gain 2.69 to 4e-6 at every frequency and enters as that.
The decoupled plant ``Q = G·W``; loop i with loop j open sees ``Q_ii``, with loop j closed the
equivalent SISO process of [Precup2013] eq. 3.7.4 (negative feedback):

    Q_i = Q_ii − Q_ij·Q_ji·C_j/(1 + C_j·Q_jj)

The controller's sample-and-hold ([Michalski2021]: Ts = 1 s) is left out: it costs ω_c·Ts/2 of phase,
< 0.2° at these crossovers (< 0.006 rad/s). Units: cm, °C, cm³/s, s, rad/s, degrees.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.control.multiloop import D21Filter, TwoLoopPiConfig, document_config
from tank_control.core.plants.mixing_tank import OPERATING_POINT, MixingTankConfig, jacobian

LOOPS = ('h', 'T_out')
"""The loops: h ← F_H (index 0) and T_out ← F_Cin (index 1), [Michalski2021]'s pairing."""


@dataclass(frozen=True)
class LinearisedTank:
    """[Michalski2021] §1 linearised at an operating point: ``a`` (2×2) and ``b`` (2×2, columns F_H, F_C)
    of dx/dt for x = [V, T] [cm³, °C], ``h_per_volume`` = 1/(2·C·h_op) [1/cm²], the delays
    ``tau_cold`` (on F_Cin) and ``tau_out`` (on T_out) [s]."""

    a: np.ndarray
    b: np.ndarray
    h_per_volume: float
    tau_cold: float
    tau_out: float

    @classmethod
    def from_config(cls, config: Any = None) -> LinearisedTank:
        """From a ``MixingTankConfig`` (its operating point, C, α and delays); default: [Michalski2021]'s,
        at the exact steady state T_op = 2115/63 °C."""
        cfg = config if config is not None else MixingTankConfig(T_op=OPERATING_POINT.T)
        a, b = jacobian(cfg)
        return cls(a, b[:, :2].copy(), 1.0 / (2.0 * cfg.C * cfg.h_op), float(cfg.tau_cold),
                   float(cfg.tau_out))

    def with_delays(self, tau_cold: float, tau_out: float) -> LinearisedTank:
        """The same plant with other delays [s]."""
        return replace(self, tau_cold=float(tau_cold), tau_out=float(tau_out))

    def at(self, s: np.ndarray) -> np.ndarray:
        """G(s) for complex ``s`` of shape (n,): array (n, 2, 2), rows h, T_out, columns
        F_H, F_Cin."""
        s = np.asarray(s, dtype=complex).reshape(-1)
        (a11, a12), (a21, a22) = self.a
        det = (s - a11) * (s - a22) - a12 * a21
        inv = np.empty((s.size, 2, 2), dtype=complex)         # (sI − A)^(−1)
        inv[:, 0, 0], inv[:, 0, 1] = (s - a22) / det, a12 / det
        inv[:, 1, 0], inv[:, 1, 1] = a21 / det, (s - a11) / det
        g = inv @ self.b
        g[:, 0, :] *= self.h_per_volume
        g[:, 1, :] *= np.exp(-self.tau_out * s)[:, None]
        g[:, :, 1] *= np.exp(-self.tau_cold * s)[:, None]
        return g

    def corners(self) -> tuple[float, ...]:
        """Characteristic frequencies [rad/s]: the poles and 1/delay."""
        poles = tuple(abs(float(x)) for x in np.linalg.eigvals(self.a) if abs(x) > 0)
        return poles + tuple(1.0 / t for t in (self.tau_cold, self.tau_out) if t > 0)


def decoupler(config: TwoLoopPiConfig) -> np.ndarray:
    """W with u = W·v: [[1, D12], [D21, 1]] with decoupling (D21: its static gain), else I."""
    if config.decoupling == 'none':
        return np.eye(2)
    d21 = D21Filter.dc_gain() if config.decoupling == 'dynamic' else config.d21
    return np.array([[1.0, config.d12], [d21, 1.0]])


def _pi(kp: float, ki: float, s: np.ndarray) -> np.ndarray:
    return kp + ki / s


class TwoLoopAnalysis:
    """Frequency analysis of :class:`TwoLoopPiConfig` on a :class:`LinearisedTank`."""

    def __init__(self, plant: LinearisedTank, config: TwoLoopPiConfig) -> None:
        self.plant, self.config = plant, config
        self._w = decoupler(config)
        self._gains = ((config.kp_h, config.ki_h), (config.kp_T, config.ki_T))

    def decoupled_plant(self, s: np.ndarray) -> np.ndarray:
        """Q(s) = G(s)·W (n, 2, 2): output i ← PI output v_j."""
        return self.plant.at(s) @ self._w

    def controller(self, i: int, s: np.ndarray) -> np.ndarray:
        kp, ki = self._gains[i]
        return _pi(kp, ki, np.asarray(s, dtype=complex).reshape(-1))

    def equivalent_plant(self, i: int, s: np.ndarray, other_closed: bool = True) -> np.ndarray:
        """The process loop ``i`` (0: h, 1: T_out) controls: Q_ii, or with the other loop
        closed Q_ii − Q_ij·Q_ji·C_j/(1 + C_j·Q_jj) ([Precup2013] eq. 3.7.4)."""
        q = self.decoupled_plant(s)
        j = 1 - i
        if not other_closed:
            return q[:, i, i]
        c_j = self.controller(j, s)
        return q[:, i, i] - q[:, i, j] * q[:, j, i] * c_j / (1.0 + c_j * q[:, j, j])

    def loop(self, i: int, other_closed: bool = True) -> fr.FrequencyResponse:
        """The open loop L_i = C_i·(equivalent plant) as a :class:`FrequencyResponse`, its
        unstable poles (those of the other loop closed alone) counted for Nyquist."""
        kp, ki = self._gains[i]
        unstable = 0
        if other_closed:
            unstable = fr.closed_loop_poles_unstable(self.loop(1 - i, other_closed=False))
        corners = self.plant.corners() + ((abs(ki / kp),) if kp and ki else ())
        def rational(s: np.ndarray) -> np.ndarray:
            value = self.controller(i, s) * self.equivalent_plant(i, s, other_closed)
            return value.reshape(np.shape(s))
        return fr.FrequencyResponse(rational, 0.0, 0.0, 1 if ki else 0, unstable, corners)

    def margins(self, i: int, other_closed: bool = True) -> fr.Margins:
        """:func:`frequency.margins` of :meth:`loop`."""
        return fr.margins(self.loop(i, other_closed))

    def stable(self) -> bool:
        """Both loops closed. det(I + K·Q) = (1 + C_2·Q_22)·(1 + L_1) with L_1 the equivalent
        loop 1 (Q itself stable): its zeros in Re s ≥ 0 are those the Nyquist count of L_1
        gives, L_1's unstable poles being the zeros of 1 + C_2·Q_22 (:meth:`loop`)."""
        return fr.closed_loop_poles_unstable(self.loop(0, other_closed=True)) == 0

    def report(self) -> dict[str, dict[str, float]]:
        """Margins of each loop, alone (other open) and with the other closed, keyed
        ``'h'``, ``'h|T_out closed'``, ``'T_out'``, ``'T_out|h closed'`` (``Margins.as_dict``)."""
        out = {}
        for i, name in enumerate(LOOPS):
            out[name] = self.margins(i, other_closed=False).as_dict()
            out[f'{name}|{LOOPS[1 - i]} closed'] = self.margins(i).as_dict()
        return out


def document_analysis(decoupling: str = 'dynamic', tau_cold: float | None = None,
                      tau_out: float | None = None, **gains: Any) -> TwoLoopAnalysis:
    """[Michalski2021]'s loop (§2.1 gains with ``decoupling='none'``, §3.1 otherwise; ``gains``: other
    ``TwoLoopPiConfig`` values) on [Michalski2021]'s operating point, delays 180/120 s unless given."""
    plant = LinearisedTank.from_config()
    plant = plant.with_delays(plant.tau_cold if tau_cold is None else tau_cold,
                              plant.tau_out if tau_out is None else tau_out)
    return TwoLoopAnalysis(plant, document_config(decoupling, **gains))

