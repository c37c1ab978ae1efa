"""Offset-free state and disturbance estimation for MPCS over the delayed model ([Michalski2021] §4).

Augmented state ``ξ = [x, w, r_1, …]``: model state ``x`` (level [cm], temperature [°C]
deviations), integrating disturbances ``w`` (``'input'``: added to the state equation;
``'output'``: added to the measured outputs), and per delayed output a shift register of its
last ``d_i`` model values (``T_out(k) = T(k − 120)``). Steady-state Kalman gain from the filter
Riccati equation, once per design. Why and how: docs/mpcs.md ("Offset-free estimation").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tank_control.core.scipy_lazy import solve_discrete_are

from tank_control.core.control.mpcs_model import DelayedModel

DISTURBANCE_MODELS = ('input', 'output')


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise intensities (relative to a unit measurement-noise variance)."""

    disturbance_model: str = 'input'
    disturbance_noise: float = 1e-4   # variance of the random-walk increments of w
    state_noise: float = 1e-4         # variance of the state noise on x
    measurement_noise: float = 1.0    # variance of the measurement noise


class AugmentedSystem:
    """The matrices of the augmented (disturbance + output-delay register) system."""

    def __init__(self, model: DelayedModel, disturbance_model: str) -> None:
        if disturbance_model not in DISTURBANCE_MODELS:
            raise ValueError(f'mpcs.disturbance_model: {disturbance_model!r} is not one of '
                             f'{", ".join(DISTURBANCE_MODELS)}')
        self.model = model
        self.kind = disturbance_model
        n, ny = model.n_x, model.n_y
        self.n_w = n if disturbance_model == 'input' else ny
        delays = model.output_delays
        self.reg_start = []            # index in ξ of register i (or -1 if no delay)
        idx = n + self.n_w
        for d in delays:
            self.reg_start.append(idx if d > 0 else -1)
            idx += d
        self.n = idx
        a = np.zeros((idx, idx))
        a[:n, :n] = model.a
        a[n:n + self.n_w, n:n + self.n_w] = np.eye(self.n_w)
        if disturbance_model == 'input':
            a[:n, n:n + self.n_w] = np.eye(n)
        c = np.zeros((ny, idx))
        for i, d in enumerate(delays):
            if d == 0:
                c[i, :n] = model.c[i]
            else:
                s = self.reg_start[i]
                a[s, :n] = model.c[i]                    # r_i[0]⁺ = (C x)_i
                for j in range(1, d):
                    a[s + j, s + j - 1] = 1.0            # r_i[j]⁺ = r_i[j−1]
                c[i, s + d - 1] = 1.0                    # y_i = r_i[d−1] = (Cx)_i(k−d)
            if disturbance_model == 'output':
                c[i, n + i] = 1.0
        self.a, self.c = a, c
        self.b_u = np.zeros((idx, model.n_u))
        self.b_u[:n] = model.b_u
        self.b_d = np.zeros((idx, model.n_d))
        self.b_d[:n] = model.b_d

    def equilibrium(self, y: np.ndarray, u_eff: np.ndarray, d: np.ndarray) -> np.ndarray:
        """An augmented state in steady state with ``u_eff``, ``d`` that reproduces ``y``.

        Used for a bumpless start: the disturbance states take up whatever the
        linear model cannot explain, so the first prediction is flat.
        """
        m = self.model
        n = m.n_x
        xi = np.zeros(self.n)
        if self.kind == 'input':
            x = np.linalg.lstsq(m.c, y, rcond=None)[0]
            w = (np.eye(n) - m.a) @ x - m.b_u @ u_eff - m.b_d @ d
        else:
            x = np.linalg.solve(np.eye(n) - m.a, m.b_u @ u_eff + m.b_d @ d)
            w = y - m.c @ x
        xi[:n] = x
        xi[n:n + self.n_w] = w
        cx = m.c @ x
        for i, d_i in enumerate(m.output_delays):
            if d_i > 0:
                xi[self.reg_start[i]:self.reg_start[i] + d_i] = cx[i]
        return xi


def filter_riccati(a: np.ndarray, c: np.ndarray, q: np.ndarray, r: np.ndarray,
                   tol: float = 1e-12, max_iter: int = 60) -> np.ndarray:
    """Stabilising solution ``P`` of the filter Riccati equation
    ``P = A P Aᵀ − A P Cᵀ (C P Cᵀ + R)⁻¹ C P Aᵀ + Q``.

    Structure-preserving doubling (quadratic convergence, a handful of n×n
    solves per iteration), much faster than scipy's generalized-Schur solver on
    the augmented tank model with the nodes' single-threaded BLAS
    (``bench/bench_riccati.py``, bench/RESULTS.md), so a redesign at run time
    stays inside one sample. Falls back to ``scipy`` if not converged.
    """
    n = a.shape[0]
    eye = np.eye(n)
    a_k = a.T.copy()
    g_k = c.T @ np.linalg.solve(r, c)
    h_k = q.copy()
    for _ in range(max_iter):
        w = eye + g_k @ h_k
        v1 = np.linalg.solve(w, a_k)
        v2 = np.linalg.solve(w, g_k)
        g_k = g_k + a_k @ v2 @ a_k.T
        h_new = h_k + v1.T @ h_k @ a_k
        a_k = a_k @ v1
        done = np.linalg.norm(h_new - h_k, 1) <= tol * max(float(np.linalg.norm(h_new, 1)), 1e-300)
        h_k = h_new
        if done and np.all(np.isfinite(h_k)):
            return 0.5 * (h_k + h_k.T)
    return solve_discrete_are(a.T, c.T, q, r)


class KalmanEstimator:
    """Steady-state Kalman filter on :class:`AugmentedSystem` (current-estimate form).

    Per sample: ``correct(y)`` gives ``ξ̂(k|k)``; after the controller has chosen
    ``u(k)``, ``predict(u_eff, d)`` gives ``ξ̂(k+1|k)``.
    """

    def __init__(self, model: DelayedModel, config: EstimatorConfig) -> None:
        self.config = config
        self.sys = AugmentedSystem(model, config.disturbance_model)
        s = self.sys
        q = np.zeros(s.n)
        q[:model.n_x] = config.state_noise
        q[model.n_x:model.n_x + s.n_w] = config.disturbance_noise
        r = config.measurement_noise * np.eye(model.n_y)
        p = filter_riccati(s.a, s.c, np.diag(q), r)
        self.gain = p @ s.c.T @ np.linalg.inv(s.c @ p @ s.c.T + r)
        self.xi = np.zeros(s.n)
        self.innovation = np.zeros(model.n_y)

    def reset(self, y: np.ndarray, u_eff: np.ndarray, d: np.ndarray) -> None:
        """Start at the equilibrium that explains ``y`` (deviations)."""
        self.xi = self.sys.equilibrium(y, u_eff, d)
        self.innovation = np.zeros(len(y))

    def correct(self, y: np.ndarray) -> np.ndarray:
        """Measurement update with ``y(k)`` (deviations); returns ``ξ̂(k|k)``."""
        self.innovation = y - self.sys.c @ self.xi
        self.xi = self.xi + self.gain @ self.innovation
        return self.xi

    def predict(self, u_eff: np.ndarray, d: np.ndarray) -> None:
        """Time update with the inputs acting over [k, k+1) (deviations)."""
        s = self.sys
        self.xi = s.a @ self.xi + s.b_u @ u_eff + s.b_d @ d


def take_over(old: KalmanEstimator, new: KalmanEstimator, u_eff: np.ndarray,
              d: np.ndarray | None) -> bool:
    """Carry the estimate of ``old`` over to ``new`` (another operating point).

    Model states, whose output matrix is the identity, and register entries are
    mapped through their physical values (``y0 + x``); the disturbance is chosen
    so that both models predict the same next state for the inputs acting now
    (``u_eff``, ``d``, physical units; ``d = None``: no feed-forward, each model at
    its own ``d0``) — a mid-transient re-linearisation keeps the transient. Returns False
    (nothing changed) when the structures differ.
    """
    mo, mn = old.sys.model, new.sys.model
    same = (old.sys.kind == new.sys.kind and old.sys.n == new.sys.n
            and mo.output_delays == mn.output_delays and mo.n_x == mn.n_x == mo.n_y
            and np.array_equal(mo.c, np.eye(mo.n_x)) and np.array_equal(mn.c, np.eye(mn.n_x)))
    if not same:
        return False
    n, shift = mo.n_x, mo.y0 - mn.y0
    xi_o, xi = old.xi, old.xi.copy()
    xi[:n] = xi_o[:n] + shift
    for i, d_i in enumerate(mo.output_delays):
        if d_i > 0:
            s = old.sys.reg_start[i]
            xi[s:s + d_i] = xi_o[s:s + d_i] + shift[i]
    if old.sys.kind == 'input':
        w_o = xi_o[n:2 * n]
        dd_o = np.zeros(mo.n_d) if d is None else d - mo.d0
        dd_n = np.zeros(mn.n_d) if d is None else d - mn.d0
        x_next = mo.a @ xi_o[:n] + mo.b_u @ (u_eff - mo.u0) + mo.b_d @ dd_o + w_o + shift
        xi[n:2 * n] = x_next - mn.a @ xi[:n] - mn.b_u @ (u_eff - mn.u0) - mn.b_d @ dd_n
    new.xi = xi
    new.innovation = old.innovation.copy()
    return True
