"""MPCS prediction model: the linearised tank ([Michalski2021] eqs. 4–7) with exact input/output dead times.

Unlike [Michalski2021] §4 the dead times are in the model: the input delay on ``F_Cin`` enters the
prediction as known past inputs, the output delay on ``T_out`` as a register in the estimator
(:mod:`mpcs_estimator`). Deviation variables around an operating point; the volume deviation
is rescaled by ``dh/dV = 1/(2·C·h0)`` so the first state is the level deviation in cm and C is
the identity ([Michalski2021] eq. 7 divided the volume by 100). Units: h [cm], T [°C], flows [cm³/s], s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from tank_control.core.scipy_lazy import expm

from tank_control.core.plants.mixing_tank import TankOperatingPoint

# Column order of the document's B matrix ([Michalski2021] eq. 5).
TANK_INPUTS = ('F_H', 'F_C', 'F_D', 'T_H', 'T_C', 'T_D')


def equilibrium_inputs(op: TankOperatingPoint, h: float, temperature: float
                       ) -> tuple[float, float] | None:
    """``(F_H, F_C)`` [cm³/s] holding the tank at level ``h`` [cm] and ``temperature``
    [°C] with the disturbance inflow of ``op`` ([Michalski2021] §1 at steady state):

        F_H + F_C = alpha·√h − F_D,   F_H·T_H + F_C·T_C = alpha·√h·T − F_D·T_D.

    ``None`` if the point needs a negative flow (unreachable) or T_H = T_C.
    """
    if h <= 0.0 or op.T_H == op.T_C:
        return None
    q = op.alpha * math.sqrt(h)
    f_h = (q * temperature - op.F_D * op.T_D - op.T_C * (q - op.F_D)) / (op.T_H - op.T_C)
    f_c = q - op.F_D - f_h
    if f_h < 0.0 or f_c < 0.0:
        return None
    return f_h, f_c


def linearize_mixing_tank(op: TankOperatingPoint, ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation of the tank linearised at ``op``.

    State ``x = [V, T]`` [cm³, °C], inputs ``u = [F_H, F_C, F_D, T_H, T_C, T_D]``
    ([Michalski2021] eqs. 4–6; [Michalski2021] §1 gives A11 = 0.99658, A22 = 0.98638 at Ts = 1 s).
    Returns ``(A, B)``; ``C = I``, ``D = 0`` (delays excluded, as in [Michalski2021] eq. 6).
    """
    if op.inflow <= 0.0:
        raise ValueError(f'operating point: total inflow {op.inflow:g} must be > 0')
    v0, t0, q = op.V, op.T, op.inflow
    h0 = op.h
    # dV/dt = ΣF − alpha·sqrt(V/C):  ∂/∂V = −alpha/(2√h0) · 1/(2·C·h0)
    a = np.array([[-op.alpha / (2.0 * math.sqrt(h0)) / (2.0 * op.C * h0), 0.0],
                  [0.0, -q / v0]])      # ∂(dT/dt)/∂V = 0 at equilibrium
    b = np.array([[1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
                  [(op.T_H - t0) / v0, (op.T_C - t0) / v0, (op.T_D - t0) / v0,
                   op.F_H / v0, op.F_C / v0, op.F_D / v0]])
    m = np.zeros((8, 8))
    m[:2, :2] = a
    m[:2, 2:] = b
    e = expm(m * ts)
    return e[:2, :2], e[:2, 2:]


@dataclass
class DelayedModel:
    """``x(k+1) = A x + B_u u_eff + B_d d``, ``y_i(k) = (C x)(k − output_delays[i])``.

    ``u_eff_m(k) = u_m(k − input_delays[m])``. All signals are deviations from
    ``u0``/``d0``/``y0`` (physical units); delays are in samples.
    """

    a: np.ndarray
    b_u: np.ndarray
    b_d: np.ndarray
    c: np.ndarray
    input_delays: tuple[int, ...]
    output_delays: tuple[int, ...]
    u0: np.ndarray
    d0: np.ndarray
    y0: np.ndarray
    sample_time: float = 1.0
    x_scale: np.ndarray = field(default_factory=lambda: np.ones(0))

    def __post_init__(self) -> None:
        n = self.a.shape[0]
        for name, mat, shape in (('A', self.a, (n, n)), ('B_u', self.b_u, (n, len(self.u0))),
                                 ('B_d', self.b_d, (n, len(self.d0))),
                                 ('C', self.c, (len(self.y0), n))):
            if mat.shape != shape:
                raise ValueError(f'model: {name} has shape {mat.shape}, expected {shape}')
        if len(self.input_delays) != self.n_u or len(self.output_delays) != self.n_y:
            raise ValueError('model: one delay per input and per output is required')
        if min(self.input_delays + self.output_delays, default=0) < 0:
            raise ValueError('model: delays must be >= 0 samples')
        if np.max(np.abs(np.linalg.eigvals(self.a))) >= 1.0:
            raise ValueError('model: A must be stable (|eig| < 1) for the steady-state terms')

    @property
    def n_x(self) -> int:
        return self.a.shape[0]

    @property
    def n_u(self) -> int:
        return self.b_u.shape[1]

    @property
    def n_d(self) -> int:
        return self.b_d.shape[1]

    @property
    def n_y(self) -> int:
        return self.c.shape[0]

    def steady_gain(self) -> np.ndarray:
        """Static gain from ``u`` to ``y``: ``C (I − A)⁻¹ B_u`` (delays do not change it)."""
        return self.c @ np.linalg.solve(np.eye(self.n_x) - self.a, self.b_u)


def delay_samples(delay: float, ts: float, name: str) -> int:
    """A dead time [s] as an integer number of samples (must be a multiple of ``ts``)."""
    k = round(delay / ts)
    if abs(k * ts - delay) > 1e-9 * max(1.0, delay) or k < 0:
        raise ValueError(f'{name}: dead time {delay:g} s must be a non-negative multiple of '
                         f'the sample time {ts:g} s')
    return int(k)


def tank_model(op: TankOperatingPoint, ts: float = 1.0,
               ab: tuple[np.ndarray, np.ndarray] | None = None) -> DelayedModel:
    """The tank's MPCS model: manipulated ``[F_H, F_Cin]``, measured ``[F_D, T_D]``.

    ``ab``: ``(A, B)`` of ``x = [V, T]`` with the 6 document inputs (e.g. from a
    plant's ``linearize(ts)``); default :func:`linearize_mixing_tank`. The volume
    state is rescaled to level units (``δh ≈ δV/(2·C·h0)``) so that ``C = I``
    and outputs are ``[h, T_out]``; ``T_H``, ``T_C`` are treated as parameters
    (their slow changes are absorbed by the disturbance estimator).
    """
    a, b = linearize_mixing_tank(op, ts) if ab is None else (np.asarray(ab[0], float),
                                                             np.asarray(ab[1], float))
    s = np.array([1.0 / (2.0 * op.C * op.h), 1.0])    # dh/dV, 1
    a_s = (s[:, None] * a) / s[None, :]
    b_s = s[:, None] * b
    return DelayedModel(
        a=a_s, b_u=b_s[:, [0, 1]], b_d=b_s[:, [2, 5]], c=np.eye(2),
        input_delays=(0, delay_samples(op.tau_c, ts, 'tau_c')),
        output_delays=(0, delay_samples(op.tau, ts, 'tau')),
        u0=np.array([op.F_H, op.F_C]), d0=np.array([op.F_D, op.T_D]),
        y0=np.array([op.h, op.T]), sample_time=ts, x_scale=s)
